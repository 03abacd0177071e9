"""The config file's sections: one pydantic model per [section], every field bounded and described
(Field(description=...): the one text that config/bogiemon.toml's comments and the generated
docs/configuration.md repeat, both checked by tests). Here the wagon's sensors and the processing of
their samples; the decision in config_decision.py, the sources in config_sources.py, what leaves the
gateway in config_delivery.py. BogiemonConfig (daemon/config.py) puts them together."""

from __future__ import annotations

from pathlib import Path
from types import UnionType
from typing import Annotated, Any, Literal, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, Field, ValidationInfo, field_validator, model_validator

from bogiemon.detection import Corner, ProcessingSettings

MAX_FS_HZ = 10_000.0  # no accelerometer feed of a bogie runs faster


class ConfigError(ValueError):
    """A config file that cannot be used; the message names the file and each bad field."""


class Section(BaseModel):
    # No field takes inf or nan: every number of the config is a duration, a rate, a level or a
    # count, and a non-finite one ends in OverflowError or NaN far from the file that caused it.
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _as_written(cls, value: Any, info: ValidationInfo) -> Any:
        """A value of the type TOML wrote for it: pydantic would take true as 1, "5" as 5 and 1 as
        true, and a typo of the file's would run as a setting nobody wrote (numbers and switches)."""
        if info.field_name is not None:
            problem = _wrong_type(value, cls.model_fields[info.field_name].annotation)
            if problem is not None:
                raise ValueError(problem)
        return value


def _wrong_type(value: Any, annotation: Any) -> str | None:
    """Why value is not what annotation asks for among numbers and switches (lists of them too), or None."""
    kinds = _scalar_kinds(annotation)
    if kinds & {int, float} and bool not in kinds and isinstance(value, bool):
        return "expected a number, not true or false"
    if kinds & {int, float} and str not in kinds and isinstance(value, str):
        return "expected a number, not a string (no quotes around a number)"
    if int in kinds and not kinds & {float, str} and isinstance(value, float):
        return "expected a whole number"
    if kinds == {bool} and not isinstance(value, bool):
        return "expected true or false"
    item = _item_annotation(annotation)
    if item is not None and isinstance(value, list | tuple):
        for i, element in enumerate(value):
            problem = _wrong_type(element, item)
            if problem is not None:
                return f"item {i}: {problem}"
    return None


def _scalar_kinds(annotation: Any) -> set[type]:
    """The scalar types a field admits (int, float, bool, str), through unions and Annotated."""
    if annotation in (int, float, bool, str):
        return {annotation}
    if get_origin(annotation) is Annotated:
        return _scalar_kinds(get_args(annotation)[0])
    if get_origin(annotation) in (Union, UnionType):
        return set().union(*(_scalar_kinds(a) for a in get_args(annotation)))
    return set()


def _item_annotation(annotation: Any) -> Any:
    """The element type of a list or tuple field (tuple[X, ...] or a tuple of one kind), else None."""
    if get_origin(annotation) is Annotated:
        return _item_annotation(get_args(annotation)[0])
    args = [a for a in get_args(annotation) if a is not Ellipsis]
    if get_origin(annotation) in (list, tuple) and len(set(args)) == 1:
        return args[0]
    return None


class GeometryConfig(Section):
    """The bogie's dimensions that turn the three sensors' accelerations into bounce, pitch and roll."""

    wheelbase_m: float = Field(1.80, gt=0.5, lt=5.0, description="The bogie's wheelbase 2l in metres (the axle spacing; 1.80 m on a Y25).")
    sensor_spacing_m: float = Field(2.0, gt=0.5, lt=4.0, description="The lateral distance 2b in metres between the left and right axle-box sensors.")


class SensorsConfig(Section):
    """The physical corner of each accelerometer channel: "leading-left", "leading-right",
    "trailing-left" or "trailing-right". Leading is the axle at the bogie's end that leads in the
    reference direction of travel; left is seen looking that way. Three different corners."""

    a1: Corner = Field(Corner.LEADING_LEFT, description="Corner of sensor 1 (channel a1).")
    a2: Corner = Field(Corner.LEADING_RIGHT, description="Corner of sensor 2 (channel a2); the paper's layout puts it across the track from sensor 1.")
    a3: Corner = Field(Corner.TRAILING_LEFT, description="Corner of sensor 3 (channel a3); the paper's layout puts it along the rail from sensor 1.")

    @model_validator(mode="after")
    def _distinct(self) -> SensorsConfig:
        corners = [self.a1, self.a2, self.a3]
        if len(set(corners)) != 3:
            raise ValueError(f"the three sensors must sit at three different corners, got {[c.value for c in corners]}")
        return self


class ProcessingConfig(Section):
    """The detection core's windows and filters. What the core can run is one rule (detection's
    ProcessingSettings): window_s a whole number of hops, in seconds and in samples; max_lag_s
    shorter than the window; each of window_s, hop_s and max_lag_s at most 2^22 samples, and the
    cross-spectra a window holds (hops per window x (hop + lags)) at most 2^22 samples too; the
    high-pass below the low-pass."""

    fs_hz: float = Field(500.0, gt=0, le=MAX_FS_HZ, description=(
        "Sample rate of the live source in hertz, at most 10000 (a recording's own rate is inferred "
        "from its times; [processing] must work at that rate too)."
    ))  # fmt: skip
    window_s: float = Field(120.0, gt=0, le=3600, description=(
        "Length T of the analysis window in seconds: each window yields one set of indicators. 120 s "
        "separated faults from healthy runs best in the detection study (docs/study/defaults.md: more "
        "faulty windows at alarm level than 30 or 60 s with the same false-alarm rule); the default "
        "thresholds are for this length: recalibrate them if you change it. At most 3600 s; the fused "
        "method needs the 120 s its model was fitted on."
    ))  # fmt: skip
    hop_s: float = Field(10.0, gt=0, description=(
        "A new window starts every hop_s seconds; window_s must be a whole multiple of it, in seconds "
        "and in samples at fs_hz, and a hop at least 2 samples."
    ))  # fmt: skip
    max_lag_s: float = Field(10.0, ge=0, description="The cross-correlations are computed for lags -max_lag_s .. +max_lag_s (shorter than window_s).")
    highpass_hz: float = Field(0.5, gt=0, description=(
        "Corner frequency in hertz of the Butterworth high-pass that removes gravity and sensor drift. "
        "Both corner frequencies lie between fs_hz * 1e-6 and Nyquist (fs_hz / 2), the high-pass lowest."
    ))  # fmt: skip
    highpass_order: int = Field(2, ge=1, le=8, description="Order of that high-pass.")
    lowpass_hz: float = Field(10.0, gt=0, description="Corner frequency in hertz of indicator 3's Butterworth low-pass.")
    lowpass_order: int = Field(4, ge=1, le=12, description="Order of that low-pass.")

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


class HealthConfig(Section):
    """The sensor checks that come before any judgement (a stuck or dead channel makes exactly the
    asymmetry a fault makes), and the gating: no judgement while the wagon stands or the excitation
    is too weak. A SENSOR_FAULT names the channel and the problem; nothing is judged until it clears."""

    standstill_rms_mps2: float = Field(0.05, ge=0, description=(
        "Every channel's RMS (after the high-pass) below this, in m/s^2: the wagon stands; no judgment. "
        "A hop of the window whose RMS (median channel) is below it: the wagon stood within the window."
    ))  # fmt: skip
    min_excitation_rms_mps2: float = Field(0.3, ge=0, description="The median channel RMS must reach this, in m/s^2, for the suspension to be judged.")
    min_hop_rms_ratio: float = Field(0.25, ge=0, lt=1, description=(
        "A window whose quietest hop has less than this share of its loudest hop's RMS (median channel) "
        "holds a stop or a start: not judged (gate \"non_stationary\"). A running frame's RMS grows about "
        "as speed^a, a = 1.2 to 2 on both simulated wagon models, so 0.25 is the speed changing by a "
        "factor 2 to 3.2 within the window; running hops stayed above 0.34 of each other on the "
        "simulated fleets (speeds drifting within 50-110 km/h), above 0.6 at a steady 10-30 km/h."
    ))  # fmt: skip
    flat_rms_mps2: float = Field(0.02, ge=0, description="A channel with less RMS than this while another moves is flat: dead, disconnected or frozen.")
    stuck_repeat_fraction: float = Field(0.2, gt=0, le=1, description="A channel repeating its previous sample this often (share of samples) is stuck.")
    stuck_run_s: float = Field(1.0, gt=0, description=(
        "A channel holding one value this long, in seconds, while the wagon moves is stuck too: it "
        "froze within the window (a healthy 16 g / 16-bit sensor holds one value under 0.2 s, even "
        "at 10 km/h in tare). Neither stuck rule applies to a window in which the wagon stood."
    ))  # fmt: skip
    clip_level_mps2: float = Field(155.0, gt=0, description="Samples at or beyond this magnitude in m/s^2 count as clipped (16 g full scale = 156.9).")
    clipped_fraction: float = Field(1e-4, gt=0, le=1, description="This share of clipped samples in a window makes the channel unusable.")
    noise_ratio: float = Field(2.0, gt=1, description=(
        "A channel whose RMS exceeds this multiple of the median of the three is noisy. On the rigid "
        "frame the three differ little: at most 1.29 over the simulated fleet's 100 h of healthy running, "
        "1.66 with a broken spring at a sensor's corner (docs/robust/README.md)."
    ))  # fmt: skip
    noise_low_band_ratio: float = Field(3.2, gt=1, description=(
        "Or whose power at 0.5-1 Hz exceeds this multiple of the median of the three. It stays for the "
        "sensor alone on its rail, whose noise the coherence check (noise_coherence) cannot see (its "
        "low-band motion, the cross level, has no second witness). A prior from our simulator, not "
        "physics: at most 2.7 over the simulated fleet's healthy and faulty running, a loose sensor's "
        "white noise 3.7 and more. Looked at only while the wagon runs steadily: a stop pitches the "
        "frame at 0.5-1 Hz."
    ))  # fmt: skip
    noise_coherence: float = Field(0.75, ge=0, lt=1, description=(
        "The two sensors on one rail move alike at 0.5-1 Hz, where the frame follows the rail's long "
        "waves: the share of each one's power the other two sensors explain (its multiple coherence) is "
        "near 1 when healthy. White noise of power N on one, where the frame gives S, lowers it to "
        "S / (S + N). Below this the sensor is noisy (0.75: the noise is at least a third of the frame's "
        "motion in the band, SNR below 3), named when it also lost coherence with the third sensor and "
        "carries the extra power; not applied at walking pace, where the waves are too short."
    ))  # fmt: skip
    max_rms_mps2: float = Field(50.0, gt=0, description="Nor may any channel's RMS exceed this, in m/s^2 (no bogie frame in service gives this much).")
    max_gaps_per_hour: int = Field(6, ge=0, le=1_000_000, description="More gaps than this from the source in the last hour raise a dropouts sensor fault.")
    gravity_mps2: float = Field(9.81, gt=0, description=(
        "Gravity in m/s^2: a channel whose mean is below minus half of it while another's is above plus "
        "half is mounted upside down (inverted). Recordings without gravity skip this check."
    ))  # fmt: skip
    structure_checks: bool = Field(True, description=(
        "The checks that assume a real bogie frame's spectra: the coherence and low-band noise checks "
        "and the layout checks. Turn them off for synthetic test signals."
    ))  # fmt: skip
    layout_checks: list[Literal["low", "diagonal", "other", "quadrature"]] = Field(default_factory=list, description=(
        "The layout checks in force (judgement/health.py): which of \"low\", \"diagonal\", \"other\" and "
        "\"quadrature\" hold on this wagon, learned at commissioning (`bogiemon calibrate` writes them and "
        "their thresholds into the calibration). None on a wagon not commissioned: no sensor is then "
        "called swapped or inverted from the frame's structure (gravity's sign still tells inverted)."
    ))  # fmt: skip
    layout_low_coherence: float = Field(-0.2, ge=-1, le=1, description=(
        "\"low\": each channel's coherency with another at 0.5-2 Hz (where the whole frame follows the "
        "carbody) must stay above this; an inverted channel's turns negative."
    ))  # fmt: skip
    layout_diagonal_coherence: float = Field(-0.3, ge=-1, le=1, description=(
        "\"diagonal\": the two diagonal sensors' coherency at 16-64 Hz (where the frame pitches and rolls "
        "about its centre, so diagonal corners move in opposition) must stay below this."
    ))  # fmt: skip
    layout_other_margin: float = Field(0.0, ge=-2, le=2, description="\"other\": the other two pairs' coherency at 16-64 Hz must exceed the diagonal pair's by this.")
    layout_quadrature_margin: float = Field(0.0, ge=-1, le=1, description=(
        "\"quadrature\": bounce's quadrature with pitch at 0.5-4 Hz (the rear axle meets the track "
        "2l/v after the front one) must exceed its quadrature with roll by this."
    ))  # fmt: skip
    noise_floor_psd: list[Annotated[float, Field(gt=0, le=1e6)]] = Field(default_factory=list, description=(
        "The noise floor (judgement/noise_floor.py, docs/sensor-health.md): in each band of the top octave "
        "below Nyquist (128-250 Hz at 500 Hz), the power spectral density of what the other two sensors "
        "cannot explain. White noise on a sensor (a failing element, a poor cable screen, a loose "
        "mounting) lifts it in every band, and stands out most there, where any accelerometer's "
        "anti-alias filter leaves least of the frame. Commissioning writes, per channel a1, a2, a3, the "
        "smallest density its healthy windows showed there, in (m/s^2)^2/Hz."
    ))  # fmt: skip
    noise_floor_ratio: list[Annotated[float, Field(gt=0, le=1e12)]] = Field(default_factory=list, description=(
        "Commissioning writes, per channel a1, a2, a3, the largest ratio of its noise floor to the other "
        "two channels' in the same band (their geometric mean). Empty (a wagon not commissioned): the "
        "noise floor check is not in force."
    ))  # fmt: skip
    noise_floor_margin: float = Field(1.8, gt=1, le=1e6, description=(
        "A channel whose density and ratio exceed both of its commissioned values by this factor is noisy: "
        "its own (a rough track lifts every channel's density, leaving the ratio) and above the quietest "
        "the healthy wagon ever showed there. A prior from our simulator: 1.5 times the largest excess of "
        "any healthy window of the training wagons (1.17, both models, four sensor parts), where 0.4 "
        "m/s^2 of white noise on a sensor stood 2 to 70 000 times above (docs/sensor-health.md)."
    ))  # fmt: skip
    clear_after_windows: int = Field(3, ge=1, le=100_000, description="A sensor fault clears after this many consecutive healthy, judgeable windows of a moving wagon.")

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
    """What the service keeps across restarts."""

    directory: Path = Field(Path("/var/lib/bogiemon"), description=(
        "Where the event store (events.sqlite3, SQLite in WAL mode) and the alarm state live; "
        "`bogiemon run --state-dir` overrides it."
    ))  # fmt: skip


class PipelineConfig(Section):
    """Between the source thread and the detection core."""

    ring_capacity_s: float = Field(60.0, gt=0, le=600, description=(
        "Seconds of samples the ring between the source and the core holds before it drops (and counts); "
        "at least one block ([source] max_block_s), at most 600."
    ))  # fmt: skip


class WagonConfig(Section):
    """The wagon this gateway rides on."""

    # A topic level in MQTT: no separators, wildcards or spaces.
    id: str = Field("", pattern=r"^[A-Za-z0-9._-]*$", max_length=64, description=(
        "The wagon's id, e.g. its 12-digit vehicle number \"318045331234\": the MQTT topics carry it, so "
        "every wagon of a fleet needs its own. Letters, digits, '.', '_' and '-' only; needed by [mqtt]."
    ))  # fmt: skip
