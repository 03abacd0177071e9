"""The configuration file: one pydantic model tree, loaded from TOML, every bad field named.

This is the edge where text from a file becomes typed values; the rest of bogiemon receives plain
dataclasses built from it (BogieGeometry, ProcessingSettings, ...). Units are in field names.
"""

from __future__ import annotations

import difflib
import hashlib
import json
import os
import stat
import tomllib
from collections.abc import Callable
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, ValidationError, field_validator, model_validator

from bogiemon.daemon.decision import INDICATOR_FIELDS, DecisionSettings, FusedSettings, Threshold
from bogiemon.daemon.health import HealthSettings
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.models import Baseline, Levels, LoadModel, shipped_models
from bogiemon.detection import BogieGeometry, Corner, ProcessingSettings
from bogiemon.detection.features import COUPLING_NAMES

if TYPE_CHECKING:
    from bogiemon.daemon.monitor import MonitorSettings

DEFAULT_CONFIG_NAME = "bogiemon.toml"
# A config is a page of hand-written TOML (the shipped one is 15 KiB): a file larger than this is
# not one, and reading it whole (a log named by mistake, /dev/zero) must not exhaust memory.
MAX_CONFIG_BYTES = 1 << 20
MAX_FS_HZ = 10_000.0  # no accelerometer feed of a bogie runs faster


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the file and each bad field."""


class _Section(BaseModel):
    # No field takes inf or nan: every number of the config is a duration, a rate, a level or a
    # count, and a non-finite one ends in OverflowError or NaN far from the file that caused it.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


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
    fs_hz: float = Field(500.0, gt=0, le=MAX_FS_HZ)
    window_s: float = Field(120.0, gt=0, le=3600)
    hop_s: float = Field(10.0, gt=0)
    max_lag_s: float = Field(10.0, ge=0)
    highpass_hz: float = Field(0.5, gt=0)
    highpass_order: int = Field(2, ge=1, le=8)
    lowpass_hz: float = Field(10.0, gt=0)
    lowpass_order: int = Field(4, ge=1, le=12)

    @model_validator(mode="after")
    def _consistent(self) -> ProcessingConfig:
        core_settings(self, self.fs_hz)  # ValueError: pydantic names the section
        return self


def core_settings(p: ProcessingConfig, fs_hz: float) -> ProcessingSettings:
    """The detection core's settings for [processing] at fs_hz (the configured rate, or a
    recording's). ValueError where the core cannot run them: its own check (detection's
    ProcessingSettings, whose messages name these keys), the one rule of what it can run; and the
    config's own, the high-pass below the low-pass."""
    if p.highpass_hz >= p.lowpass_hz:
        raise ValueError(f"highpass_hz ({p.highpass_hz}) must be below lowpass_hz ({p.lowpass_hz})")
    return ProcessingSettings(
        fs_hz=fs_hz,
        window_s=p.window_s,
        hop_s=p.hop_s,
        max_lag_s=p.max_lag_s,
        highpass_hz=p.highpass_hz,
        highpass_order=p.highpass_order,
        lowpass_hz=p.lowpass_hz,
        lowpass_order=p.lowpass_order,
    )


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
    windows: int = Field(0, ge=0, le=2**31)  # the calibration windows it was learned from (for people)

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
    clear_after_windows: int = Field(6, ge=1, le=100_000)
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
    max_gaps_per_hour: int = Field(6, ge=0, le=1_000_000)
    gravity_mps2: float = Field(9.81, gt=0)
    structure_checks: bool = True
    layout_low_coherence: float = Field(-0.2, ge=-1, le=0)
    layout_diagonal_coherence: float = Field(-0.3, ge=-1, le=0)
    clear_after_windows: int = Field(3, ge=1, le=100_000)


class StateConfig(_Section):
    directory: Path = Path("/var/lib/bogiemon")


class PipelineConfig(_Section):
    # The ring is allocated whole at start: 600 s at the highest rate is 140 MiB.
    ring_capacity_s: float = Field(60.0, gt=0, le=600)


class _SourceSection(_Section):
    """Settings every source kind has."""

    max_block_s: float = Field(1.0, gt=0, le=10.0)


class _LiveSourceSection(_SourceSection):
    # Waits are bounded: a thread's wait() takes at most about 49 days, and a retry storm of
    # microsecond backoffs helps no one.
    reconnect_backoff_min_s: float = Field(0.5, ge=0.01, le=3600)
    reconnect_backoff_max_s: float = Field(30.0, ge=0.01, le=3600)

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
    receive_buffer_bytes: int = Field(1_048_576, ge=4096, le=2**31 - 1)  # SO_RCVBUF is a C int


class SerialSourceConfig(_LiveSourceSection):
    kind: Literal["serial"]
    port: str = Field("/dev/ttyUSB0", min_length=1)
    baudrate: int = Field(115200, gt=0, le=12_000_000)


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
    # The whole run is simulated at open and held in memory (an hour at 500 Hz: 40 MiB).
    duration_s: float = Field(300.0, gt=0, le=3600)
    seed: int = Field(0, ge=0, le=2**63 - 1)
    faults: list[str] = Field(default_factory=list)
    fault_at_s: float = Field(0.0, ge=0)
    rate: float = Field(8.0, ge=0.01, le=10_000)
    channel: str = Field("bogiemon-sim", min_length=1)
    layout: Literal["hub", "per-node"] = "hub"
    dbc_path: str = ""

    @model_validator(mode="after")
    def _a_scenario(self) -> SimulatedSourceConfig:
        # The simulator's own names and fault syntax (its two small modules, not the simulator).
        from bogiemon.simulator.errors import SimulationError
        from bogiemon.simulator.suspension import parse_fault
        from bogiemon.simulator.track import TRACKS

        if self.track not in TRACKS:
            raise ValueError(f"unknown track {self.track!r}: use one of {', '.join(TRACKS)}")
        for spec in self.faults:
            try:
                parse_fault(spec)
            except SimulationError as exc:
                raise ValueError(str(exc)) from None
        # As the simulator's Scenario checks them at open.
        if self.fault_at_s >= self.duration_s:
            raise ValueError(f"fault_at_s ({self.fault_at_s:g}) must lie before the end of the run, duration_s = {self.duration_s:g}")
        if self.fault_at_s > 0 and not self.faults:
            raise ValueError("fault_at_s needs a fault in faults")
        return self


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
    # A password over plain MQTT crosses the network readable by anyone on the path: only when
    # the config says so (a bench).
    allow_plaintext: bool = False
    keepalive_s: int = Field(30, ge=5, le=3600)
    connect_timeout_s: float = Field(10.0, gt=0, le=120)
    status_period_s: float = Field(60.0, ge=0, le=86400)
    max_rate_msgs_per_s: float = Field(10.0, ge=0.01, le=10_000)
    max_inflight: int = Field(10, ge=1, le=1000)
    outbox_max_messages: int = Field(10000, ge=10, le=10_000_000)
    reconnect_backoff_min_s: float = Field(1.0, ge=0.01, le=3600)
    reconnect_backoff_max_s: float = Field(60.0, ge=0.01, le=3600)

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        if bool(self.tls_cert_file) != bool(self.tls_key_file):
            raise ValueError("tls_cert_file and tls_key_file go together: set both for a client certificate, or neither")
        if self.tls_cert_file and not self.tls:
            raise ValueError("a client certificate (tls_cert_file) needs tls = true")
        if self.password_file and not self.username_file:
            raise ValueError("password_file needs username_file")
        if self.password_file and not self.tls and not self.allow_plaintext:
            raise ValueError(
                "password_file with tls = false would send the password in clear: set tls = true "
                "(and the broker's TLS port), or allow_plaintext = true on a bench"
            )
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
    heartbeat_period_s: float = Field(1.0, ge=0, le=3600)


class BogiemonConfig(_Section):
    """The whole configuration."""

    include: list[str] = Field(default_factory=list)
    # Includes resolve inside the including file's folder unless this says otherwise (load_config).
    allow_absolute_includes: bool = False
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
        from bogiemon.daemon.delivery.connection import readable_by_others  # only with [mqtt] files

        m = self.mqtt
        warnings = []
        for field in ("tls_key_file", "username_file", "password_file"):
            path = getattr(m, field)
            problem = readable_by_others(path) if path else None
            if problem is not None:
                warnings.append(f"mqtt.{field}: {problem}")
        if m.password_file and not m.tls:
            warnings.append("mqtt: allow_plaintext = true: the password crosses the network in clear (tls = false)")
        return warnings

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


def load_config(path: str | Path | None = None, *, log_warnings: bool = True) -> BogiemonConfig:
    """Load and validate a config file; None loads the shipped default. Raises ConfigError.

    Files named in the top-level `include` list (relative to the including file) are merged
    over it in order, table by table: how `bogiemon calibrate`'s thresholds reach the daemon.
    An include must stay inside the including file's folder, `..` and symlinks resolved, unless
    the file sets `allow_absolute_includes = true`. With log_warnings, credential files others
    can read are logged as warnings (check-config prints them instead).
    """
    if path is None:
        return parse_config(default_config_text(), source="default config")
    path = Path(path)
    data = _read_toml(path)
    names = data.get("include", [])
    if not isinstance(names, list) or not all(isinstance(name, str) for name in names):
        raise ConfigError(f"{path}: include: expected a list of file names, e.g. include = [\"calibration.toml\"], got {_short(names)}")
    allow_outside = data.get("allow_absolute_includes", False)
    if not isinstance(allow_outside, bool):
        raise ConfigError(f"{path}: allow_absolute_includes: expected true or false, got {_short(allow_outside)}")
    for name in names:
        fragment_path = _include_path(path, name, allow_outside)
        fragment = _read_toml(fragment_path)
        for key in ("include", "allow_absolute_includes"):
            if key in fragment:
                raise ConfigError(f"{fragment_path}: an included file cannot set {key}: only the file that includes it")
        try:
            data = _merge(data, fragment)
        except RecursionError:
            raise ConfigError(f"{fragment_path}: its tables are nested too deeply to merge") from None
    config = validate_config(data, source=str(path))
    if log_warnings:
        log = get_logger(component="config")
        for warning in config.credential_warnings():
            log.warning(warning, config=str(path))
    return config


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
    """A config file's text: a regular file of at most MAX_CONFIG_BYTES, UTF-8."""
    try:
        # O_NONBLOCK: a FIFO named by mistake must not block the open; it is refused below.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror or exc}") from None
    except ValueError:  # a NUL in the name
        raise ConfigError(f"{_short(str(path))}: not a file name") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            kind = "a folder" if stat.S_ISDIR(mode) else "not a regular file"
            raise ConfigError(f"{path}: {kind}; a config is a TOML text file")
        raw = _read_at_most(fd, MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read the config file: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError(f"{path}: larger than {MAX_CONFIG_BYTES // 1024} KiB; a config is a page of TOML: is this the right file?")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not a UTF-8 text file (byte {exc.start}); a config is TOML") from None


def _read_at_most(fd: int, limit: int) -> bytes:
    chunks, size = [], 0
    while size < limit:
        chunk = os.read(fd, min(limit - size, 1 << 16))
        if not chunk:
            break
        chunks.append(chunk)
        size += len(chunk)
    return b"".join(chunks)


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
        return f"{where}: {message}, got {_short(err['input'])}"
    if "input" in err and not isinstance(err["input"], dict):
        return f"{where}: {message} (got {_short(err['input'])})"
    return f"{where}: {message}"
