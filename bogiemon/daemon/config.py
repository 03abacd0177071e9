"""The configuration file: one pydantic model tree, loaded from TOML, every bad field named.

This is the edge where text from a file becomes typed values; the rest of bogiemon receives plain
dataclasses built from it (BogieGeometry, ProcessingSettings, ...). Units are in field names. The
sections are in daemon/config_sections.py, config_decision.py, config_sources.py and
config_delivery.py, each field with its description; here they are put together, checked as a whole (what
`run` builds is built at validation), and read from files with their includes.
"""

from __future__ import annotations

import codecs
import difflib
import hashlib
import json
import math
import tomllib
from collections.abc import Callable, Sequence
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, Field, ValidationError, model_validator

from bogiemon.daemon.config_decision import DecisionConfig
from bogiemon.daemon.config_delivery import CanAlarmsConfig, MqttConfig, RecorderConfig
from bogiemon.daemon.config_duty import DutyConfig
from bogiemon.daemon.config_sections import (  # the sections, importable from here as before
    ConfigError,
    GeometryConfig,
    HealthConfig,
    PipelineConfig,
    ProcessingConfig,
    Section,
    SensorsConfig,
    StateConfig,
    WagonConfig,
    core_settings,
)
from bogiemon.daemon.config_sources import (
    SOURCE_KINDS,
    CanSourceConfig,
    ReplaySourceConfig,
    SerialSourceConfig,
    SimulatedSourceConfig,
    SourceConfig,
)
from bogiemon.judgement.decision import DecisionSettings, Threshold
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.models import Baseline, Levels, LoadDiscriminant, LoadModel, LoadSignature, shipped_models
from bogiemon.judgement.vocabulary import LoadSetting, LoadState, Method
from bogiemon.detection import BogieGeometry, ProcessingSettings
from bogiemon.drivers.files import FileKind, read_untrusted

if TYPE_CHECKING:
    from bogiemon.daemon.duty import DutySettings
    from bogiemon.daemon.recorder import RecorderSettings
    from bogiemon.judgement.verdict import MonitorSettings

# The whole tree is read from here: the sections live in daemon/config_*.py.
__all__ = [
    "BogiemonConfig",
    "CanAlarmsConfig",
    "CanSourceConfig",
    "ConfigError",
    "DecisionConfig",
    "DutyConfig",
    "GeometryConfig",
    "HealthConfig",
    "MqttConfig",
    "PipelineConfig",
    "ProcessingConfig",
    "RecorderConfig",
    "ReplaySourceConfig",
    "SensorsConfig",
    "SerialSourceConfig",
    "SimulatedSourceConfig",
    "SourceConfig",
    "StateConfig",
    "WagonConfig",
    "default_config_text",
    "load_config",
    "load_config_and_files",
    "parse_config",
    "validate_config",
]

DEFAULT_CONFIG_NAME = "bogiemon.toml"
# A config is a page of hand-written TOML (the shipped one is 15 KiB): a file larger than this is
# not one, and reading it whole (a log named by mistake, /dev/zero) must not exhaust memory.
MAX_CONFIG_BYTES = 1 << 20
CONFIG_FILE = FileKind(
    name="config file",
    description="a config is a TOML text file",
    max_bytes=MAX_CONFIG_BYTES,
    too_large="a config is a page of TOML: is this the right file?",
)


class BogiemonConfig(Section):
    """The whole configuration."""

    include: list[str] = Field(default_factory=list, description=(
        "Further files merged over this one, in order, relative to this file's folder: e.g. the "
        "calibration written by `bogiemon calibrate` (include = [\"calibration.toml\"]). An included file "
        "cannot include others; each must be a regular UTF-8 file of at most 1 MiB (as this one)."
    ))  # fmt: skip
    # Includes resolve inside the including file's folder unless this says otherwise (load_config).
    allow_absolute_includes: bool = Field(False, description=(
        "Included files must lie in this file's folder or below it ('..' and symlinks resolved): true "
        "also allows absolute paths and files elsewhere (only this file can set it, not an included one)."
    ))  # fmt: skip
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
    recorder: RecorderConfig = RecorderConfig()
    duty: DutyConfig = DutyConfig()

    @model_validator(mode="after")
    def _duty_measures_a_window(self) -> BogiemonConfig:
        d = self.duty
        if d.enabled and d.measure_min * 60.0 < self.processing.window_s + self.processing.hop_s:
            raise ValueError(
                f"duty.measure_min ({d.measure_min:g} min) must hold more than one analysis window and a hop "
                f"(processing.window_s + hop_s = {self.processing.window_s + self.processing.hop_s:g} s): a shorter "
                "measurement is never judged"
            )
        return self

    @model_validator(mode="after")
    def _mqtt_needs_the_wagon(self) -> BogiemonConfig:
        if self.mqtt.enabled and not self.wagon.id:
            raise ValueError("mqtt.enabled needs the wagon's id in its topics: set [wagon] id")
        return self

    @model_validator(mode="after")
    def _ring_holds_a_block(self) -> BogiemonConfig:
        # The ring refuses a block larger than itself (a ValueError in the source thread).
        if self.pipeline.ring_capacity_s < self.source.max_block_s:
            raise ValueError(
                f"pipeline.ring_capacity_s ({self.pipeline.ring_capacity_s:g}) must hold one block of "
                f"source.max_block_s ({self.source.max_block_s:g})"
            )
        return self

    def build_problems(self) -> list[str]:
        """Whatever `run` builds from the config, built once: each failure as one line (empty: it starts).

        validate_config calls it, so that what check-config accepts the service starts, and a
        reload applies, with the same settings objects (the sources' files aside: a DBC or a
        recording is opened at start and named then).
        """
        problems = []
        builders: list[tuple[str, Callable[[], object]]] = [
            ("processing", self.processing_settings),
            ("geometry and sensors", self.bogie_geometry),
            ("health", self.health_settings),
            ("decision", self.decision_settings),
            ("decision", self.check_models),
            ("decision.load", self.load_model),
        ]
        for section, build in builders:
            try:
                build()
            except ConfigError as exc:
                problems.append(str(exc))
            except ValueError as exc:  # a settings class's own check that the model above lacks
                problems.append(f"{section}: {exc}")
        return problems

    def credential_warnings(self) -> list[str]:
        """One line per [mqtt] credential or key file that others can read, and for a password in clear."""
        m = self.mqtt
        warnings = []
        for field in ("tls_key_file", "username_file", "password_file"):
            path = getattr(m, field)
            if not path:
                continue
            # Only with [mqtt] files: the delivery package imports the monitor and the daemon's log.
            from bogiemon.daemon.delivery.connection import readable_by_others

            problem = readable_by_others(path)
            if problem is not None:
                warnings.append(f"mqtt.{field}: {problem}")
        if m.password_file and not m.tls:
            warnings.append("mqtt: allow_plaintext = true: the password crosses the network in clear (tls = false)")
        return warnings

    def health_settings(self) -> HealthSettings:
        h = self.health
        fields = h.model_dump(exclude={"clear_after_windows"})
        return HealthSettings(
            **{**fields, "layout_checks": tuple(h.layout_checks), "noise_floor_psd": tuple(h.noise_floor_psd), "noise_floor_ratio": tuple(h.noise_floor_ratio)}
        )

    def decision_settings(self) -> DecisionSettings:
        d = self.decision
        thresholds: dict[LoadState, dict[str, Threshold]] = {
            load: {name: Threshold(warning=t.warning, alarm=t.alarm, center=t.center) for name, t in per.items()}
            for load, per in d.thresholds.items()
        }
        return DecisionSettings(thresholds, d.confirm_k, d.confirm_n, d.clear_after_windows, d.method, self.fused_baselines())

    def fused_baselines(self) -> dict[LoadState, Baseline]:
        """Per load: the wagon's calibrated baseline if the config has one, else the fleet's."""
        models = shipped_models(self.decision.models_dir).fused
        out = {}
        for load, model in models.items():
            own = self.decision.fused.get(load)
            levels = Levels(own.warning, own.alarm, own.trend_warning, own.trend_alarm) if own is not None else None
            out[load] = model.calibrated(own.center, levels, np.asarray(own.covariance, dtype=np.float64) if own.covariance else None) if own is not None and levels is not None else model.population()
        return out

    def check_models(self) -> None:
        """The fused method needs the windows its shipped model was fitted on; ConfigError if not."""
        if self.decision.method is not Method.FUSED:
            return
        model = shipped_models(self.decision.models_dir).fused[LoadState.FULL]
        if not model.fits(self.processing_settings()):
            raise ConfigError(
                f"decision.method 'fused': its model (config/fused_model.toml) was fitted on windows of "
                f"{model.window_s:g} s every {model.hop_s:g} s, the config has {self.processing.window_s:g} s every "
                f"{self.processing.hop_s:g} s: use those, or decision.method = \"thresholds\""
            )

    def load_model(self) -> LoadModel:
        return shipped_models(self.decision.models_dir).load

    def load_signatures(self) -> tuple[LoadSignature, ...]:
        """The load states this wagon was commissioned in (empty: the shipped load model decides)."""
        return tuple(
            LoadSignature(
                load, np.asarray(st.center, dtype=np.float64), np.asarray(st.scale, dtype=np.float64), st.limit, st.lowest_excitation_mps2,
                math.inf if st.highest_excitation_mps2 is None else st.highest_excitation_mps2,
            )
            for load, st in sorted(self.decision.load_states.items())
        )

    def load_discriminant(self) -> LoadDiscriminant | None:
        """The wagon's own line between its two commissioned load states, if it has one."""
        d = self.decision.load_discriminant
        if d is None:
            return None
        return LoadDiscriminant(np.asarray(d.weights, dtype=np.float64), d.offset, d.margin, d.separation)

    def bogie_geometry(self) -> BogieGeometry:
        return BogieGeometry(
            wheelbase_m=self.geometry.wheelbase_m,
            sensor_spacing_m=self.geometry.sensor_spacing_m,
            corners=(self.sensors.a1, self.sensors.a2, self.sensors.a3),
        )

    def processing_settings(self, fs_hz: float | None = None) -> ProcessingSettings:
        """The detection core's settings; fs_hz overrides the configured rate (e.g. a recording's).

        ConfigError, naming the [processing] keys, when the core cannot run them at that rate.
        """
        p = self.processing
        rate_hz = p.fs_hz if fs_hz is None else float(fs_hz)
        where = "processing" if fs_hz is None else f"processing at a sample rate of {rate_hz:.6g} Hz"
        try:
            return core_settings(p, rate_hz)
        except ValueError as exc:  # the core's own check of window_s, hop_s, max_lag_s, fs_hz and the filters
            raise ConfigError(f"{where}: {exc}") from None

    def monitor_settings(self, load: str | None = None, fs_hz: float | None = None) -> MonitorSettings:
        """What the monitor needs from the config; `load` overrides decision.load (e.g. --load),
        fs_hz the configured rate (e.g. a recording's)."""
        from bogiemon.judgement.verdict import MonitorSettings  # the judgement: only when built

        load = LoadSetting(load or self.decision.load)
        self.check_models()
        return MonitorSettings(
            processing=self.processing_settings(fs_hz),
            geometry=self.bogie_geometry(),
            health=self.health_settings(),
            decision=self.decision_settings(),
            load=load,
            config_hash=self.digest(),
            sensor_clear_after_windows=self.health.clear_after_windows,
            load_model=self.load_model() if load is LoadSetting.AUTO else None,
            load_states=self.load_signatures(),
            load_discriminant=self.load_discriminant() if load is LoadSetting.AUTO else None,
            not_judged_after_s=3600.0 * self.decision.not_judged_after_h,
        )

    def duty_settings(self) -> DutySettings | None:
        """The duty cycle's settings (daemon/duty.py); None when [duty] is not enabled."""
        from bogiemon.daemon.duty import DutySettings  # only when enabled

        d = self.duty
        if not d.enabled:
            return None
        return DutySettings(
            measure_s=d.measure_min * 60.0,
            cycle_s=d.every_min * 60.0,
            standing_after_s=d.standing_after_s,
            probe_every_s=d.probe_every_s,
            probe_s=d.probe_s,
            standstill_rms_mps2=self.health.standstill_rms_mps2,
        )

    def recorder_settings(self) -> RecorderSettings | None:
        """What the recorder needs: its section, the windows and confirmation whose samples a
        snapshot holds, and the event store's reserve (with room for the MQTT outbox full of status
        messages when MQTT sends them); None when [recorder] is not enabled."""
        from bogiemon.daemon.recorder import RecorderSettings  # only when enabled
        from bogiemon.daemon.recorder_space import event_store_reserve_bytes

        r, m = self.recorder, self.mqtt
        if not r.enabled:
            return None
        status_outbox_messages = m.outbox_max_messages if m.enabled and m.status_period_s > 0 else 0
        return RecorderSettings(
            directory=r.directory,
            lead_in_s=r.lead_in_s,
            periodic_every_h=r.periodic_every_h,
            periodic_s=r.periodic_s,
            max_total_bytes=r.max_total_bytes,
            format=r.format,
            reserve_bytes=event_store_reserve_bytes(status_outbox_messages),
            window_s=self.processing.window_s,
            hop_s=self.processing.hop_s,
            confirm_n=self.decision.confirm_n,
            max_block_s=self.source.max_block_s,
        )

    def digest(self) -> str:
        """A short, stable hash of the resolved config, recorded with everything it produced."""
        text = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def default_config_text() -> str:
    """The shipped, commented default config (config/bogiemon.toml)."""
    return resources.files("bogiemon.config").joinpath(DEFAULT_CONFIG_NAME).read_text(encoding="utf-8")


def load_config(
    path: str | Path | None = None, *, log_warnings: bool = True, extra_includes: Sequence[str | Path] = ()
) -> BogiemonConfig:
    """Load and validate a config file; None loads the shipped default. Raises ConfigError.

    Files named in the top-level `include` list (relative to the including file) are merged
    over it in order, table by table: how `bogiemon calibrate`'s thresholds reach the daemon.
    An include must stay inside the including file's folder, `..` and symlinks resolved, unless
    the file sets `allow_absolute_includes = true`. extra_includes are merged last, as if the
    file listed them (the back office's convention of a calibration.toml beside a wagon's
    config: the caller chose them, so they are not held to the folder). With log_warnings,
    credential files others can read are logged as warnings (check-config prints them instead).
    """
    return load_config_and_files(path, log_warnings=log_warnings, extra_includes=extra_includes)[0]


def load_config_and_files(
    path: str | Path | None = None, *, log_warnings: bool = True, extra_includes: Sequence[str | Path] = ()
) -> tuple[BogiemonConfig, tuple[Path, ...]]:
    """load_config, and the files it read: the config file, then its includes in order (none for
    the shipped default)."""
    if path is None:
        return parse_config(default_config_text(), source="default config"), ()
    path = Path(path)
    data = _read_toml(path)
    names = data.get("include", [])
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise ConfigError(f"{path}: include: expected a list of file names, e.g. include = [\"calibration.toml\"], got {_short(names)}")
    allow_outside = data.get("allow_absolute_includes", False)
    if not isinstance(allow_outside, bool):
        raise ConfigError(f"{path}: allow_absolute_includes: expected true or false, got {_short(allow_outside)}")
    fragment_paths = [_include_path(path, name, allow_outside) for name in names] + [Path(p) for p in extra_includes]
    for fragment_path in fragment_paths:
        fragment = _read_toml(fragment_path)
        for key in ("include", "allow_absolute_includes"):
            if key in fragment:
                raise ConfigError(f"{fragment_path}: an included file cannot set {key}: only the file that includes it")
        try:
            data = _merge(data, fragment)
        except RecursionError:
            raise ConfigError(f"{fragment_path}: its tables are nested too deeply to merge") from None
    config = validate_config(data, source=str(path))
    warnings = config.credential_warnings() if log_warnings else []
    if warnings:
        # structlog (and the asyncio it imports) only when there is something to log: a command
        # that merely reads the config starts a tenth of a second sooner.
        from bogiemon.daemon.logs import get_logger

        log = get_logger(component="config")
        for warning in warnings:
            log.warning(warning, config=str(path))
    return config, (path, *fragment_paths)


def parse_config(text: str, source: str) -> BogiemonConfig:
    """Validate config text (no includes: they need the file's folder). Raises ConfigError."""
    return validate_config(_parse_toml(text, source), source)


def _include_path(path: Path, name: str, allow_outside: bool) -> Path:
    """Where `include` entry name of the file at path points; ConfigError when it must not go there."""
    where = f"{path}: include {_short(name)}"
    if not name or "\0" in name:
        raise ConfigError(f"{where}: not a file name")
    target = path.parent / name  # an absolute name replaces the folder
    if allow_outside:
        return target
    if Path(name).is_absolute():
        raise ConfigError(f"{where}: an absolute path; name a file in the config's folder relative to it, or set allow_absolute_includes = true")
    try:
        folder, resolved = path.parent.resolve(), target.resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop
        raise ConfigError(f"{where}: cannot resolve it: {exc}") from None
    if not resolved.is_relative_to(folder):
        raise ConfigError(
            f"{where}: leads out of the config's folder {folder} (to {resolved}, '..' and symlinks resolved); "
            "keep included files beside it, or set allow_absolute_includes = true"
        )
    return target


def _read_toml(path: Path) -> dict[str, Any]:
    return _parse_toml(_read_text(path), str(path))


def _read_text(path: Path) -> str:
    """A config file's text: a regular file of at most MAX_CONFIG_BYTES (drivers/files.py), UTF-8;
    a UTF-8 byte-order mark (an editor's) is read past, one of UTF-16 or UTF-32 named."""
    raw = read_untrusted(path, CONFIG_FILE, ConfigError)
    for mark, encoding in ((codecs.BOM_UTF32_LE, "UTF-32"), (codecs.BOM_UTF32_BE, "UTF-32"), (codecs.BOM_UTF16_LE, "UTF-16"), (codecs.BOM_UTF16_BE, "UTF-16")):
        if raw.startswith(mark):
            raise ConfigError(f"{path}: a {encoding} text file (it begins with a {encoding} byte-order mark); save it as UTF-8, a config is TOML")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte {exc.start}); a config is TOML") from None


def _parse_toml(text: str, source: str) -> dict[str, Any]:
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{source}: invalid TOML: {exc}") from None
    except RecursionError:
        raise ConfigError(f"{source}: invalid TOML: arrays or tables nested too deeply") from None


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
    """The config tree from parsed TOML, and everything the service builds from it. Raises
    ConfigError naming the source and every bad field, one per line."""
    problems = _nul_problems(data)
    if problems:
        raise ConfigError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))
    try:
        config = BogiemonConfig.model_validate(data)
    except ValidationError as exc:
        problems = [_describe(err) for err in exc.errors()]
        raise ConfigError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems)) from None
    except RecursionError:
        raise ConfigError(f"{source}: tables nested too deeply") from None
    problems = config.build_problems()
    if problems:
        raise ConfigError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems))
    return config


def _nul_problems(data: dict[str, Any]) -> list[str]:
    """A NUL in any string: no file, device or channel name can hold one (open() raises ValueError)."""
    problems = []
    stack: list[tuple[str, Any]] = [("", data)]
    while stack:  # a loop, not recursion: TOML nests as deep as its author likes
        where, value = stack.pop()
        if isinstance(value, str):
            if "\0" in value:
                problems.append(f"{where}: a NUL character (\\u0000) cannot be in a name or a path (got {_short(value)})")
        elif isinstance(value, dict):
            stack += [(f"{where}.{key}" if where else str(key), item) for key, item in value.items()]
        elif isinstance(value, list):
            stack += [(f"{where}.{i}", item) for i, item in enumerate(value)]
    return sorted(problems)


def _short(value: Any, limit: int = 80) -> str:
    """repr(value), cut to a line's worth: hostile input must not make a message of megabytes."""
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _describe(err: Any) -> str:
    """One line per pydantic error: the dotted path, what is wrong, and a suggestion for typos."""
    loc = [str(part) for part in err["loc"]]
    source_model = None
    if len(loc) > 1 and loc[0] == "source" and loc[1] in SOURCE_KINDS:  # drop the [source] union's tag
        source_model = SOURCE_KINDS[loc.pop(1)]
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
        return f"{where}: {message}, got {_short(err['input'])}"
    if "input" in err and not isinstance(err["input"], dict):
        return f"{where}: {message} (got {_short(err['input'])})"
    return f"{where}: {message}"
