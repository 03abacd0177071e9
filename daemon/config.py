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
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, field_validator, model_validator

from bogiemon.daemon.decision import INDICATOR_FIELDS, DecisionSettings, FusedSettings, Threshold
from bogiemon.daemon.health import HealthSettings
from bogiemon.daemon.models import Baseline, Levels, LoadModel, shipped_models
from bogiemon.detection import BogieGeometry, Corner, ProcessingSettings
from bogiemon.detection.features import COUPLING_NAMES

if TYPE_CHECKING:
    from bogiemon.daemon.monitor import MonitorSettings

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
    window_s: float = Field(120.0, gt=0)
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


LoadState = Literal["full", "tare"]
IndicatorName = Literal["i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm"]
assert set(IndicatorName.__args__) == set(INDICATOR_FIELDS)  # type: ignore[attr-defined]


class ThresholdConfig(_Section):
    center: float = 0.0
    warning: float = Field(gt=0)
    alarm: float = Field(gt=0)

    @model_validator(mode="after")
    def _ordered(self) -> ThresholdConfig:
        if self.warning > self.alarm:
            raise ValueError(f"warning ({self.warning}) must not exceed alarm ({self.alarm})")
        return self


# Thresholds when the config names none (the shipped file states the same values): derived for
# 120 s windows by the detection study (docs/study/defaults.md) with calibrate's rule from its
# healthy runs at 40 to 120 km/h on ERRI low and high level track; recalibrate for other windows.
DEFAULT_THRESHOLDS: dict[str, dict[str, ThresholdConfig]] = {
    "full": {"i4_norm": ThresholdConfig(center=-9.44e-05, warning=0.059, alarm=0.114)},
    "tare": {
        "i4_norm": ThresholdConfig(center=-0.000235, warning=0.0292, alarm=0.044),
        "i3_norm": ThresholdConfig(center=0.00121, warning=0.0408, alarm=0.0657),
    },
}


class FusedBaselineConfig(_Section):
    """A wagon's own healthy baseline of the fused score for one load, written by `bogiemon calibrate`."""

    features: list[str] = Field(default_factory=lambda: list(COUPLING_NAMES))
    center: list[float]
    warning: float = Field(gt=0)
    alarm: float = Field(gt=0)
    trend_warning: float = Field(gt=0)
    trend_alarm: float = Field(gt=0)
    windows: int = Field(0, ge=0)  # the calibration windows it was learned from (for people)

    @model_validator(mode="after")
    def _consistent(self) -> FusedBaselineConfig:
        if tuple(self.features) != COUPLING_NAMES:
            raise ValueError(f"features {self.features} are not this bogiemon's {list(COUPLING_NAMES)}: calibrate again")
        if len(self.center) != len(COUPLING_NAMES):
            raise ValueError(f"center needs {len(COUPLING_NAMES)} values, got {len(self.center)}")
        if self.warning > self.alarm or self.trend_warning > self.trend_alarm:
            raise ValueError(
                f"warning levels ({self.warning}, trend {self.trend_warning}) must not exceed the alarm levels ({self.alarm}, trend {self.trend_alarm})"
            )
        return self


class DecisionConfig(_Section):
    method: Literal["fused", "thresholds"] = "fused"
    load: Literal["auto", "full", "tare"] = "auto"
    confirm_k: int = Field(3, ge=1)
    confirm_n: int = Field(5, ge=1, le=100)
    clear_after_windows: int = Field(6, ge=1)
    thresholds: dict[LoadState, dict[IndicatorName, ThresholdConfig]] = Field(default_factory=lambda: DEFAULT_THRESHOLDS)
    # The wagon's calibrated baselines (none shipped: without one a load is judged against the
    # fleet's population baseline, config/fused_model.toml).
    fused: dict[LoadState, FusedBaselineConfig] = Field(default_factory=dict)

    @field_validator("thresholds", mode="before")
    @classmethod
    def _per_load_over_defaults(cls, value: Any) -> Any:
        """A load state named in the file replaces that state's default set; others keep theirs."""
        if isinstance(value, dict):
            return {**DEFAULT_THRESHOLDS, **value}
        return value

    @model_validator(mode="after")
    def _consistent(self) -> DecisionConfig:
        if self.confirm_k > self.confirm_n:
            raise ValueError(f"confirm_k ({self.confirm_k}) must not exceed confirm_n ({self.confirm_n})")
        loads = ("full", "tare") if self.load == "auto" else (self.load,)
        if self.method == "thresholds":
            for load in loads:
                if not self.thresholds.get(load):
                    raise ValueError(f"no thresholds for the load state '{load}': add [decision.thresholds.{load}.<indicator>]")
        return self


class HealthConfig(_Section):
    standstill_rms_mps2: float = Field(0.05, ge=0)
    min_excitation_rms_mps2: float = Field(0.3, ge=0)
    flat_rms_mps2: float = Field(0.02, ge=0)
    stuck_repeat_fraction: float = Field(0.2, gt=0, le=1)
    stuck_run_s: float = Field(1.0, gt=0)
    clip_level_mps2: float = Field(155.0, gt=0)
    clipped_fraction: float = Field(1e-4, gt=0, le=1)
    noise_ratio: float = Field(2.0, gt=1)
    noise_low_band_ratio: float = Field(3.2, gt=1)
    max_rms_mps2: float = Field(50.0, gt=0)
    max_gaps_per_hour: int = Field(6, ge=0)
    gravity_mps2: float = Field(9.81, gt=0)
    structure_checks: bool = True
    layout_low_coherence: float = Field(-0.2, ge=-1, le=0)
    layout_diagonal_coherence: float = Field(-0.3, ge=-1, le=0)
    clear_after_windows: int = Field(3, ge=1)


class StateConfig(_Section):
    directory: Path = Path("/var/lib/bogiemon")


class PipelineConfig(_Section):
    ring_capacity_s: float = Field(60.0, gt=0)


class _SourceSection(_Section):
    """Settings every source kind has."""

    max_block_s: float = Field(1.0, gt=0, le=10.0)


class _LiveSourceSection(_SourceSection):
    reconnect_backoff_min_s: float = Field(0.5, gt=0)
    reconnect_backoff_max_s: float = Field(30.0, gt=0)

    @model_validator(mode="after")
    def _backoff_order(self) -> _LiveSourceSection:
        if self.reconnect_backoff_min_s > self.reconnect_backoff_max_s:
            raise ValueError(
                f"reconnect_backoff_min_s ({self.reconnect_backoff_min_s}) must not exceed "
                f"reconnect_backoff_max_s ({self.reconnect_backoff_max_s})"
            )
        return self


class CanSourceConfig(_LiveSourceSection):
    kind: Literal["can"] = "can"
    interface: Literal["socketcan", "virtual"] = "socketcan"
    channel: str = Field("can0", min_length=1)
    layout: Literal["hub", "per-node"] = "hub"
    dbc_path: str = ""  # empty: the shipped config/bogiemon.dbc
    receive_buffer_bytes: int = Field(1_048_576, ge=4096)


class SerialSourceConfig(_LiveSourceSection):
    kind: Literal["serial"]
    port: str = Field("/dev/ttyUSB0", min_length=1)
    baudrate: int = Field(115200, gt=0)


class ReplaySourceConfig(_SourceSection):
    kind: Literal["replay"]
    path: str = Field(min_length=1)
    realtime: bool = True
    layout: Literal["hub", "per-node"] = "hub"
    dbc_path: str = ""


class SimulatedSourceConfig(_SourceSection):
    """The bundled simulator on an in-process virtual CAN bus: the demo and the end-to-end tests."""

    kind: Literal["simulated"]
    load: Literal["full", "tare"] = "full"
    speed_kmh: float = Field(80.0, gt=0, le=200)
    track: str = "erri-low"
    duration_s: float = Field(300.0, gt=0)
    seed: int = Field(0, ge=0)
    faults: list[str] = Field(default_factory=list)
    fault_at_s: float = Field(0.0, ge=0)
    rate: float = Field(8.0, gt=0)
    channel: str = Field("bogiemon-sim", min_length=1)
    layout: Literal["hub", "per-node"] = "hub"
    dbc_path: str = ""


def _source_kind(value: Any) -> str | None:
    """The [source] model's tag: its `kind`, "can" when a file leaves it out."""
    if isinstance(value, dict):
        return value.get("kind", "can")
    return getattr(value, "kind", None)


# [source] is one of four models, chosen by its `kind` field.
SourceConfig = Annotated[
    Annotated[CanSourceConfig, Tag("can")]
    | Annotated[SerialSourceConfig, Tag("serial")]
    | Annotated[ReplaySourceConfig, Tag("replay")]
    | Annotated[SimulatedSourceConfig, Tag("simulated")],
    Discriminator(
        _source_kind,
        custom_error_type="source_kind",
        custom_error_message="kind must be 'can', 'serial', 'replay' or 'simulated'",
    ),
]
_SOURCE_KINDS: dict[str, type[BaseModel]] = {
    "can": CanSourceConfig,
    "serial": SerialSourceConfig,
    "replay": ReplaySourceConfig,
    "simulated": SimulatedSourceConfig,
}


class WagonConfig(_Section):
    # A topic level in MQTT: no separators, wildcards or spaces.
    id: str = Field("", pattern=r"^[A-Za-z0-9._-]*$", max_length=64)


class MqttConfig(_Section):
    """Alarm delivery to the back office over MQTT (docs/mqtt.md): the outbox publisher."""

    enabled: bool = False
    host: str = Field("localhost", min_length=1)
    port: int = Field(8883, ge=1, le=65535)
    topic_prefix: str = Field("bogiemon", pattern=r"^[A-Za-z0-9._-]+(/[A-Za-z0-9._-]+)*$")
    client_id: str = Field("", pattern=r"^[A-Za-z0-9._-]*$", max_length=64)
    tls: bool = True
    tls_ca_file: str = ""
    tls_cert_file: str = ""
    tls_key_file: str = ""
    username_file: str = ""
    password_file: str = ""
    keepalive_s: int = Field(30, ge=5, le=3600)
    connect_timeout_s: float = Field(10.0, gt=0, le=120)
    status_period_s: float = Field(60.0, ge=0)
    max_rate_msgs_per_s: float = Field(10.0, gt=0)
    max_inflight: int = Field(10, ge=1, le=1000)
    outbox_max_messages: int = Field(10000, ge=10)
    reconnect_backoff_min_s: float = Field(1.0, gt=0)
    reconnect_backoff_max_s: float = Field(60.0, gt=0)

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        if bool(self.tls_cert_file) != bool(self.tls_key_file):
            raise ValueError("tls_cert_file and tls_key_file go together: set both for a client certificate, or neither")
        if self.tls_cert_file and not self.tls:
            raise ValueError("a client certificate (tls_cert_file) needs tls = true")
        if self.password_file and not self.username_file:
            raise ValueError("password_file needs username_file")
        if self.reconnect_backoff_min_s > self.reconnect_backoff_max_s:
            raise ValueError(
                f"reconnect_backoff_min_s ({self.reconnect_backoff_min_s}) must not exceed "
                f"reconnect_backoff_max_s ({self.reconnect_backoff_max_s})"
            )
        return self


class CanAlarmsConfig(_Section):
    """CONFIRMED and CLEARED alarms and a heartbeat as DBC frames on a CAN bus (docs/mqtt.md)."""

    enabled: bool = False
    interface: Literal["socketcan", "virtual"] = "socketcan"
    channel: str = Field("can0", min_length=1)
    dbc_path: str = ""
    heartbeat_period_s: float = Field(1.0, ge=0)


class BogiemonConfig(_Section):
    """The whole configuration."""

    include: list[str] = Field(default_factory=list)
    geometry: GeometryConfig = GeometryConfig()
    sensors: SensorsConfig = SensorsConfig()
    processing: ProcessingConfig = ProcessingConfig()
    health: HealthConfig = HealthConfig()
    decision: DecisionConfig = DecisionConfig()
    state: StateConfig = StateConfig()
    pipeline: PipelineConfig = PipelineConfig()
    source: SourceConfig = CanSourceConfig()
    wagon: WagonConfig = WagonConfig()
    mqtt: MqttConfig = MqttConfig()
    can_alarms: CanAlarmsConfig = CanAlarmsConfig()

    @model_validator(mode="after")
    def _mqtt_needs_the_wagon(self) -> BogiemonConfig:
        if self.mqtt.enabled and not self.wagon.id:
            raise ValueError("mqtt.enabled needs the wagon's id in its topics: set [wagon] id")
        return self

    def health_settings(self) -> HealthSettings:
        h = self.health
        return HealthSettings(**h.model_dump(exclude={"clear_after_windows"}))

    def decision_settings(self) -> DecisionSettings:
        d = self.decision
        thresholds = {
            load: {name: Threshold(warning=t.warning, alarm=t.alarm, center=t.center) for name, t in per.items()}
            for load, per in d.thresholds.items()
        }
        return DecisionSettings(thresholds, d.confirm_k, d.confirm_n, d.clear_after_windows, d.method, self.fused_settings())

    def fused_baselines(self) -> dict[str, Baseline]:
        """Per load: the wagon's calibrated baseline if the config has one, else the fleet's."""
        models = shipped_models().fused
        out = {}
        for load, model in models.items():
            own = self.decision.fused.get(load)  # type: ignore[call-overload]
            out[load] = model.calibrated(own.center, Levels(own.warning, own.alarm, own.trend_warning, own.trend_alarm)) if own is not None else model.population()
        return out

    def fused_settings(self) -> FusedSettings:
        return FusedSettings(self.fused_baselines(), shipped_models().signatures, self.bogie_geometry(), self.processing.hop_s)

    def check_models(self) -> None:
        """The fused method needs the windows its shipped model was fitted on; ConfigError if not."""
        if self.decision.method != "fused":
            return
        model = shipped_models().fused["full"]
        if not model.fits(self.processing_settings()):
            raise ConfigError(
                f"decision.method 'fused': its model (config/fused_model.toml) was fitted on windows of "
                f"{model.window_s:g} s every {model.hop_s:g} s, the config has {self.processing.window_s:g} s every "
                f"{self.processing.hop_s:g} s: use those, or decision.method = \"thresholds\""
            )

    def load_model(self) -> LoadModel:
        return shipped_models().load

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

    def monitor_settings(self, load: str | None = None, fs_hz: float | None = None) -> MonitorSettings:
        """What the monitor needs from the config; `load` overrides decision.load (e.g. --load),
        fs_hz the configured rate (e.g. a recording's)."""
        from bogiemon.daemon.monitor import MonitorSettings  # the monitor brings the store: only when built

        load = load or self.decision.load
        self.check_models()
        return MonitorSettings(
            processing=self.processing_settings(fs_hz),
            geometry=self.bogie_geometry(),
            health=self.health_settings(),
            decision=self.decision_settings(),
            load=load,
            config_hash=self.digest(),
            sensor_clear_after_windows=self.health.clear_after_windows,
            load_model=self.load_model() if load == "auto" else None,
        )

    def digest(self) -> str:
        """A short, stable hash of the resolved config, recorded with everything it produced."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def default_config_text() -> str:
    """The shipped, commented default config (config/bogiemon.toml)."""
    return resources.files("bogiemon.config").joinpath(DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")


def load_config(path: str | Path | None = None) -> BogiemonConfig:
    """Load and validate a config file; None loads the shipped default. Raises ConfigError.

    Files named in the top-level `include` list (relative to the including file) are merged
    over it in order, table by table: how `bogiemon calibrate`'s thresholds reach the daemon.
    """
    if path is None:
        return parse_config(default_config_text(), source="default config")
    path = Path(path)
    data = _read_toml(path)
    for name in data.get("include", []):
        if not isinstance(name, str):
            raise ConfigError(f"{path}: include: expected a list of file names, got {name!r}")
        fragment_path = path.parent / name
        fragment = _read_toml(fragment_path)
        if "include" in fragment:
            raise ConfigError(f"{fragment_path}: an included file cannot include others")
        data = _merge(data, fragment)
    return validate_config(data, source=str(path))


def parse_config(text: str, source: str) -> BogiemonConfig:
    return validate_config(_parse_toml(text, source), source)


def _read_toml(path: Path) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a UTF-8 text file; a config is TOML") from None
    return _parse_toml(text, str(path))


def _parse_toml(text: str, source: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: invalid TOML: {exc}") from None


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    """Tables merge key by key; any other value in `over` replaces the one in `base`."""
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def validate_config(data: dict[str, Any], source: str) -> BogiemonConfig:
    try:
        return BogiemonConfig.model_validate(data)
    except ValidationError as exc:
        problems = [_describe(err) for err in exc.errors()]
        raise ConfigError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems)) from None


def _describe(err: Any) -> str:
    """One line per pydantic error: the dotted path, what is wrong, and a suggestion for typos."""
    loc = [str(part) for part in err["loc"]]
    source_model = None
    if len(loc) > 1 and loc[0] == "source" and loc[1] in _SOURCE_KINDS:  # drop the [source] union's tag
        source_model = _SOURCE_KINDS[loc.pop(1)]
    where = ".".join(loc) or "(top level)"
    if err["type"] == "extra_forbidden":
        model: type[BaseModel] = BogiemonConfig
        for part in loc[:-1]:
            if part == "source" and source_model is not None:
                model = source_model
                continue
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
