"""The configuration file: one pydantic model tree, loaded from TOML, every bad field named.

This is the edge where text from a file becomes typed values; the rest of bogiemon receives plain
dataclasses built from it (BogieGeometry, ProcessingSettings, ...). Units are in field names.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from bogiemon.detection import BogieGeometry, Corner, ProcessingSettings

DEFAULT_CONFIG_NAME = "bogiemon.toml"


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the file and each bad field."""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class GeometryConfig(_Section):
    wheelbase_m: float = Field(1.80, gt=0.5, lt=5.0)
    sensor_spacing_m: float = Field(2.0, gt=0.5, lt=4.0)


class SensorsConfig(_Section):
    a1: Corner = Corner.LEADING_LEFT
    a2: Corner = Corner.LEADING_RIGHT
    a3: Corner = Corner.TRAILING_LEFT

    @model_validator(mode="after")
    def _distinct(self) -> SensorsConfig:
        corners = [self.a1, self.a2, self.a3]
        if len(set(corners)) != 3:
            raise ValueError(f"the three sensors must sit at three different corners, got {[c.value for c in corners]}")
        return self


class ProcessingConfig(_Section):
    fs_hz: float = Field(500.0, gt=0)
    window_s: float = Field(60.0, gt=0)
    hop_s: float = Field(10.0, gt=0)
    max_lag_s: float = Field(10.0, ge=0)
    highpass_hz: float = Field(0.5, gt=0)
    highpass_order: int = Field(2, ge=1, le=8)
    lowpass_hz: float = Field(10.0, gt=0)
    lowpass_order: int = Field(4, ge=1, le=12)

    @model_validator(mode="after")
    def _consistent(self) -> ProcessingConfig:
        ratio = self.window_s / self.hop_s
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"window_s ({self.window_s}) must be a whole multiple of hop_s ({self.hop_s})")
        if self.max_lag_s >= self.window_s:
            raise ValueError(f"max_lag_s ({self.max_lag_s}) must be shorter than window_s ({self.window_s})")
        nyquist_hz = self.fs_hz / 2
        for name in ("highpass_hz", "lowpass_hz"):
            if getattr(self, name) >= nyquist_hz:
                raise ValueError(f"{name} ({getattr(self, name)}) must be below Nyquist, fs_hz / 2 = {nyquist_hz}")
        if self.highpass_hz >= self.lowpass_hz:
            raise ValueError(f"highpass_hz ({self.highpass_hz}) must be below lowpass_hz ({self.lowpass_hz})")
        return self


class BogiemonConfig(_Section):
    """The whole configuration. Sections later issues add (sources, thresholds, events) go here."""

    geometry: GeometryConfig = GeometryConfig()
    sensors: SensorsConfig = SensorsConfig()
    processing: ProcessingConfig = ProcessingConfig()

    def bogie_geometry(self) -> BogieGeometry:
        return BogieGeometry(
            wheelbase_m=self.geometry.wheelbase_m,
            sensor_spacing_m=self.geometry.sensor_spacing_m,
            corners=(self.sensors.a1, self.sensors.a2, self.sensors.a3),
        )

    def processing_settings(self, fs_hz: float | None = None) -> ProcessingSettings:
        """The detection core's settings; fs_hz overrides the configured rate (e.g. a recording's)."""
        p = self.processing
        return ProcessingSettings(
            fs_hz=p.fs_hz if fs_hz is None else fs_hz,
            window_s=p.window_s,
            hop_s=p.hop_s,
            max_lag_s=p.max_lag_s,
            highpass_hz=p.highpass_hz,
            highpass_order=p.highpass_order,
            lowpass_hz=p.lowpass_hz,
            lowpass_order=p.lowpass_order,
        )

    def digest(self) -> str:
        """A short, stable hash of the resolved config, recorded with everything it produced."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def default_config_text() -> str:
    """The shipped, commented default config (config/bogiemon.toml)."""
    return resources.files("bogiemon.config").joinpath(DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")


def load_config(path: str | Path | None = None) -> BogiemonConfig:
    """Load and validate a config file; None loads the shipped default. Raises ConfigError."""
    if path is None:
        return parse_config(default_config_text(), source="default config")
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file; a config is TOML") from None
    return parse_config(text, source=str(path))


def parse_config(text: str, source: str) -> BogiemonConfig:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: invalid TOML: {exc}") from None
    return validate_config(data, source)


def validate_config(data: dict[str, Any], source: str) -> BogiemonConfig:
    try:
        return BogiemonConfig.model_validate(data)
    except ValidationError as exc:
        problems = [_describe(err) for err in exc.errors()]
        raise ConfigError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems)) from None


def _describe(err: Any) -> str:
    """One line per pydantic error: the dotted path, what is wrong, and a suggestion for typos."""
    loc = [str(part) for part in err["loc"]]
    where = ".".join(loc) or "(top level)"
    if err["type"] == "extra_forbidden":
        model: type[BaseModel] = BogiemonConfig
        for part in loc[:-1]:
            annotation = model.model_fields[part].annotation
            if not (isinstance(annotation, type) and issubclass(annotation, BaseModel)):
                break
            model = annotation
        close = difflib.get_close_matches(loc[-1], list(model.model_fields), n=1)
        hint = f" (did you mean '{close[0]}'?)" if close else f" (known: {', '.join(model.model_fields)})"
        return f"{where}: unknown field{hint}"
    message = err["msg"].removeprefix("Value error, ")
    if err["type"] == "enum":
        return f"{where}: {message}, got {err['input']!r}"
    if "input" in err and not isinstance(err["input"], dict):
        return f"{where}: {message} (got {err['input']!r})"
    return f"{where}: {message}"
