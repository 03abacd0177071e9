"""The config file's sections: one pydantic model per [section], every field bounded and documented
in config/bogiemon.toml. BogiemonConfig (daemon/config.py) puts them together and loads the file."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, field_validator, model_validator

from bogiemon.judgement.events import INDICATOR_FIELDS
from bogiemon.judgement.vocabulary import LoadSetting, LoadState, Method
from bogiemon.drivers.recording import NEEDS_PYARROW, RecordingFormat, parquet_available
from bogiemon.detection import Corner, ProcessingSettings
from bogiemon.detection.features import COUPLING_NAMES, LOAD_NAMES

MAX_FS_HZ = 10_000.0  # no accelerometer feed of a bogie runs faster


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the file and each bad field."""


class Section(BaseModel):
    # No field takes inf or nan: every number of the config is a duration, a rate, a level or a
    # count, and a non-finite one ends in OverflowError or NaN far from the file that caused it.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class GeometryConfig(Section):
    wheelbase_m: float = Field(1.80, gt=0.5, lt=5.0)
    sensor_spacing_m: float = Field(2.0, gt=0.5, lt=4.0)


class SensorsConfig(Section):
    a1: Corner = Corner.LEADING_LEFT
    a2: Corner = Corner.LEADING_RIGHT
    a3: Corner = Corner.TRAILING_LEFT

    @model_validator(mode="after")
    def _distinct(self) -> SensorsConfig:
        corners = [self.a1, self.a2, self.a3]
        if len(set(corners)) != 3:
            raise ValueError(f"the three sensors must sit at three different corners, got {[c.value for c in corners]}")
        return self


class ProcessingConfig(Section):
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


IndicatorName = Literal["i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm"]
assert set(IndicatorName.__args__) == set(INDICATOR_FIELDS)  # type: ignore[attr-defined]


class ThresholdConfig(Section):
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
DEFAULT_THRESHOLDS: dict[LoadState, dict[IndicatorName, ThresholdConfig]] = {
    LoadState.FULL: {"i4_norm": ThresholdConfig(center=-9.44e-05, warning=0.059, alarm=0.114)},
    LoadState.TARE: {
        "i4_norm": ThresholdConfig(center=-0.000235, warning=0.0292, alarm=0.044),
        "i3_norm": ThresholdConfig(center=0.00121, warning=0.0408, alarm=0.0657),
    },
}


class FusedBaselineConfig(Section):
    """A wagon's own healthy baseline of the fused score for one load, written by `bogiemon calibrate`."""

    features: list[str] = Field(default_factory=lambda: list(COUPLING_NAMES))
    center: list[float]
    warning: float = Field(gt=0)
    alarm: float = Field(gt=0)
    trend_warning: float = Field(gt=0)
    trend_alarm: float = Field(gt=0)
    windows: int = Field(0, ge=0, le=2**31)  # the calibration windows it was learned from (for people)
    # The wagon's own spread of the coupling vector, learned at commissioning (shrunk towards the
    # shipped one); empty: the shipped spread of config/fused_model.toml.
    covariance: list[list[float]] = Field(default_factory=list)

    @model_validator(mode="after")
    def _consistent(self) -> FusedBaselineConfig:
        if tuple(self.features) != COUPLING_NAMES:
            raise ValueError(f"features {self.features} are not this bogiemon's {list(COUPLING_NAMES)}: calibrate again")
        if len(self.center) != len(COUPLING_NAMES):
            raise ValueError(f"center needs {len(COUPLING_NAMES)} values, got {len(self.center)}")
        if self.covariance:
            n = len(COUPLING_NAMES)
            m = np.array(self.covariance, dtype=np.float64) if all(len(r) == n for r in self.covariance) else np.zeros((0, 0))
            if m.shape != (n, n) or not np.all(np.isfinite(m)) or not np.allclose(m, m.T, rtol=1e-9, atol=1e-12):
                raise ValueError(f"covariance must be a finite, symmetric {n} x {n} matrix: calibrate again")
            try:
                np.linalg.cholesky(m)
            except np.linalg.LinAlgError:
                raise ValueError("covariance is not positive definite: calibrate again") from None
        if self.warning > self.alarm or self.trend_warning > self.trend_alarm:
            raise ValueError(
                f"warning levels ({self.warning}, trend {self.trend_warning}) must not exceed the alarm levels ({self.alarm}, trend {self.trend_alarm})"
            )
        return self


class LoadStateConfig(Section):
    """A load state the wagon was commissioned in: the centre and spread of its windows' load
    vector (detection/features.py LOAD_FEATURES: each mode's log power share per band), and the
    distance (RMS of the z-scores) its windows reached, stated beside a window's own as evidence
    (never a gate: judgement/running.py). Written by `bogiemon calibrate`."""

    center: list[float]
    scale: list[float]
    limit: float = Field(gt=0)
    windows: int = Field(0, ge=0, le=2**31)
    # The gentlest and the roughest excitation (the median channel's RMS, m/s^2) of its
    # commissioning windows: running outside is judged with raised levels, far outside not at all
    # (judgement/running.py). Calibrations before them: 0 and none (no bound).
    lowest_excitation_mps2: float = Field(0.0, ge=0, le=1e6)
    highest_excitation_mps2: float | None = Field(None, gt=0, le=1e6)

    @model_validator(mode="after")
    def _consistent(self) -> LoadStateConfig:
        n = len(LOAD_NAMES)
        if len(self.center) != n or len(self.scale) != n:
            raise ValueError(f"center and scale need {n} values each (the load features), got {len(self.center)} and {len(self.scale)}")
        if not all(np.isfinite(self.center)) or not all(v > 0 and np.isfinite(v) for v in self.scale):
            raise ValueError("center must be finite and scale finite and positive: calibrate again")
        if self.highest_excitation_mps2 is not None and self.highest_excitation_mps2 < self.lowest_excitation_mps2:
            raise ValueError("highest_excitation_mps2 is below lowest_excitation_mps2: calibrate again")
        return self


class LoadDiscriminantConfig(Section):
    """The wagon's own line between its full and tare states (judgement/commissioning.py:
    fit_discriminant): value = weights . load vector + offset, full at or above margin, tare at or
    below -margin, between them not judged. Written by `bogiemon calibrate` with both loads."""

    weights: list[float]
    offset: float
    margin: float = Field(gt=0)
    separation: float = Field(gt=0)

    @model_validator(mode="after")
    def _consistent(self) -> LoadDiscriminantConfig:
        if len(self.weights) != len(LOAD_NAMES):
            raise ValueError(f"weights need {len(LOAD_NAMES)} values (the load features), got {len(self.weights)}")
        if not all(np.isfinite([*self.weights, self.offset, self.margin, self.separation])):
            raise ValueError("weights, offset, margin and separation must be finite: calibrate again")
        if self.separation < 2 * self.margin:
            raise ValueError(f"separation {self.separation:g} is less than twice the margin {self.margin:g}: the states would overlap")
        return self


class DecisionConfig(Section):
    method: Method = Method.FUSED
    load: LoadSetting = LoadSetting.AUTO
    confirm_k: int = Field(3, ge=1)
    confirm_n: int = Field(5, ge=1, le=100)
    clear_after_windows: int = Field(6, ge=1, le=100_000)
    not_judged_after_h: float = Field(2.0, gt=0, le=10_000)
    thresholds: dict[LoadState, dict[IndicatorName, ThresholdConfig]] = Field(default_factory=lambda: DEFAULT_THRESHOLDS)
    # The wagon's calibrated baselines (none shipped: without one a load is judged against the
    # fleet's population baseline, config/fused_model.toml).
    fused: dict[LoadState, FusedBaselineConfig] = Field(default_factory=dict)
    # The load states the wagon was commissioned in (written by `bogiemon calibrate`). With load
    # "auto" a window goes to the nearest of them, or is not judged when it is like none of them;
    # without any, the shipped load model decides (config/load_model.toml, a prior).
    load_states: dict[LoadState, LoadStateConfig] = Field(default_factory=dict)
    # With both states: which side of the wagon's own discriminant a window lies (written by
    # `bogiemon calibrate`; absent: the nearest state).
    load_discriminant: LoadDiscriminantConfig | None = None
    # The folder of the priors (load_model.toml, fused_model.toml); empty:
    # the ones shipped in bogiemon's config folder, fitted on its simulator.
    models_dir: str = ""

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
        fixed = self.load.fixed()
        loads = tuple(LoadState) if fixed is None else (fixed,)
        if self.method is Method.THRESHOLDS:
            for load in loads:
                if not self.thresholds.get(load):
                    raise ValueError(f"no thresholds for the load state '{load}': add [decision.thresholds.{load}.<indicator>]")
        return self


class HealthConfig(Section):
    standstill_rms_mps2: float = Field(0.05, ge=0)
    min_excitation_rms_mps2: float = Field(0.3, ge=0)
    min_hop_rms_ratio: float = Field(0.25, ge=0, lt=1)
    flat_rms_mps2: float = Field(0.02, ge=0)
    stuck_repeat_fraction: float = Field(0.2, gt=0, le=1)
    stuck_run_s: float = Field(1.0, gt=0)
    clip_level_mps2: float = Field(155.0, gt=0)
    clipped_fraction: float = Field(1e-4, gt=0, le=1)
    noise_ratio: float = Field(2.0, gt=1)
    noise_low_band_ratio: float = Field(3.2, gt=1)
    noise_coherence: float = Field(0.75, ge=0, lt=1)
    max_rms_mps2: float = Field(50.0, gt=0)
    max_gaps_per_hour: int = Field(6, ge=0, le=1_000_000)
    gravity_mps2: float = Field(9.81, gt=0)
    structure_checks: bool = True
    # Written by commissioning (judgement/health.py: learn_structure); none on an uncommissioned wagon.
    layout_checks: list[Literal["low", "diagonal", "other", "quadrature"]] = Field(default_factory=list)
    layout_low_coherence: float = Field(-0.2, ge=-1, le=1)
    layout_diagonal_coherence: float = Field(-0.3, ge=-1, le=1)
    layout_other_margin: float = Field(0.0, ge=-2, le=2)
    layout_quadrature_margin: float = Field(0.0, ge=-1, le=1)
    # Written by commissioning too (judgement/health.py: learn_noise_floor); none: the check is not in force.
    noise_floor_psd: list[Annotated[float, Field(gt=0, le=1e6)]] = Field(default_factory=list)
    noise_floor_ratio: list[Annotated[float, Field(gt=0, le=1e12)]] = Field(default_factory=list)
    noise_floor_margin: float = Field(1.8, gt=1, le=1e6)
    clear_after_windows: int = Field(3, ge=1, le=100_000)

    @field_validator("layout_checks")
    @classmethod
    def _each_check_once(cls, checks: list[str]) -> list[str]:
        if len(set(checks)) != len(checks):
            raise ValueError(f"each layout check at most once, got {checks}")
        return checks

    @model_validator(mode="after")
    def _floors_per_channel(self) -> HealthConfig:
        if len(self.noise_floor_psd) != len(self.noise_floor_ratio) or len(self.noise_floor_psd) not in (0, 3):
            raise ValueError(
                "noise_floor_psd and noise_floor_ratio need one value per channel (a1, a2, a3) each, or none: "
                f"got {len(self.noise_floor_psd)} and {len(self.noise_floor_ratio)}"
            )
        return self


class StateConfig(Section):
    directory: Path = Path("/var/lib/bogiemon")


class PipelineConfig(Section):
    # The ring is allocated whole at start: 600 s at the highest rate is 140 MiB.
    ring_capacity_s: float = Field(60.0, gt=0, le=600)


class _SourceSection(Section):
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
SOURCE_KINDS: dict[str, type[BaseModel]] = {
    "can": CanSourceConfig,
    "serial": SerialSourceConfig,
    "replay": ReplaySourceConfig,
    "simulated": SimulatedSourceConfig,
}


class WagonConfig(Section):
    # A topic level in MQTT: no separators, wildcards or spaces.
    id: str = Field("", pattern=r"^[A-Za-z0-9._-]*$", max_length=64)


class MqttConfig(Section):
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


class CanAlarmsConfig(Section):
    """CONFIRMED and CLEARED alarms and a heartbeat as DBC frames on a CAN bus (docs/mqtt.md)."""

    enabled: bool = False
    interface: Literal["socketcan", "virtual"] = "socketcan"
    channel: str = Field("can0", min_length=1)
    dbc_path: str = ""
    heartbeat_period_s: float = Field(1.0, ge=0, le=3600)


MIB = 1 << 20


class RecorderConfig(Section):
    """The raw samples around each alarm, and periodic samples, as .csv.gz for the back office
    (daemon/recorder.py, docs/recorder.md)."""

    enabled: bool = False
    directory: Path = Path("/var/lib/bogiemon/recordings")
    # Before the windows that raised an alarm (the ring that holds it never takes more than 64 MiB).
    lead_in_s: float = Field(60.0, ge=0, le=600)
    periodic_every_h: float = Field(0.0, ge=0, le=8760)  # 0: none; at most one a year
    # One periodic recording is held in memory until written: an hour at 500 Hz is 21 MiB.
    periodic_s: float = Field(300.0, gt=0, le=3600)
    max_total_bytes: int = Field(512 * MIB, ge=MIB, le=2**50)
    format: RecordingFormat = RecordingFormat.CSV_GZ

    @model_validator(mode="after")
    def _format_installed(self) -> RecorderConfig:
        if self.enabled and self.format is RecordingFormat.PARQUET and not parquet_available():
            raise ValueError(f"format = \"parquet\" {NEEDS_PYARROW}")
        return self

    @model_validator(mode="after")
    def _periodic_fits(self) -> RecorderConfig:
        if self.periodic_every_h > 0 and self.periodic_s > self.periodic_every_h * 3600:
            raise ValueError(
                f"periodic_s ({self.periodic_s:g}) must not exceed the period periodic_every_h "
                f"({self.periodic_every_h:g} h = {self.periodic_every_h * 3600:g} s)"
            )
        return self


class DutyConfig(Section):
    """A battery-fed unit's duty cycle (daemon/duty.py, docs/gateway.md)."""

    enabled: bool = False
    measure_min: float = Field(60.0, gt=0, le=1440)
    every_min: float = Field(60.0, gt=0, le=1440)
    standing_after_s: float = Field(60.0, gt=0, le=3600)
    probe_every_s: float = Field(60.0, gt=0, le=3600)
    probe_s: float = Field(2.0, gt=0, le=60)

    @model_validator(mode="after")
    def _measure_within_the_cycle(self) -> DutyConfig:
        if self.measure_min > self.every_min:
            raise ValueError(f"measure_min ({self.measure_min:g}) must not exceed every_min ({self.every_min:g})")
        return self
