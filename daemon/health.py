"""Sensor health and gating: decide whether a window may be judged at all, and why not.

A stuck or dead channel creates exactly the asymmetry the indicators look for, so every window
is checked here first. A window is judged only when the wagon runs with enough excitation and
every sensor looks healthy; otherwise it is gated (standstill, weak excitation) or the sensors
are at fault (a SENSOR_FAULT, never a suspension alarm).

A sensor mounted upside down or two cables swapped after maintenance give healthy-looking
channels whose bounce, pitch and roll are wrong, and strong couplings: fault-like. Two checks:
- Gravity: a vertical accelerometer reads about +9.81 m/s^2 of mean; one reading about -9.81
  while another reads +9.81 is upside down. (Recordings without gravity skip this check.)
- The rigid frame's structure in the window's band cross-spectra, for the configured corners
  (detection/features.py: layout_statistics): at 0.5-2 Hz every corner follows the carbody,
  so each channel correlates positively with the others (an inverted one negatively); at
  16-64 Hz the frame pitches and rolls about its centre, held by the centre bowl, so the two
  diagonal corners move in opposition (coherency near -1, the other pairs not); at 0.5-4 Hz
  bounce and pitch are in quadrature (the rear axle meets the track 2l/v after the front one),
  bounce and roll much less. When the configured layout fails these and another assignment of
  the channels to the corners (with or without a sign flip) passes all of them, the channels it
  moves are "swapped" and those it flips "inverted". The thresholds hold with margin on every
  healthy and faulty window of the simulated fleets (docs/robust/README.md).
"""

from __future__ import annotations

import enum
import itertools
from dataclasses import dataclass
from typing import Any

import numpy as np

from bogiemon.daemon.events import DEFAULT_SEVERITY, Event, EventKind
from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import LayoutStatistics, layout_statistics
from bogiemon.drivers.base import SensorStatus

CHANNELS = ("a1", "a2", "a3")


class SensorProblem(enum.Enum):
    FLAT = "flat"  # no dynamic signal while the others move: dead, disconnected or frozen
    STUCK = "stuck"  # the converter repeats its last value
    CLIPPING = "clipping"  # samples at the converter's full scale
    NOISY = "noisy"  # far more signal than the other channels, or than a bogie frame gives
    OVER_RANGE = "over_range"  # the sensor's own over-range bit
    SENSOR_FAULT_BIT = "sensor_fault_bit"  # the sensor's own fault bit
    DROPOUTS = "dropouts"  # the source loses samples too often
    INVERTED = "inverted"  # reads upside down (mounted so, or its sign wired so)
    SWAPPED = "swapped"  # its signal belongs to another corner than the config names


class Gate(enum.Enum):
    STANDSTILL = "standstill"  # every channel quiet: the wagon stands
    WEAK_EXCITATION = "weak_excitation"  # moving, but too little excitation to judge


@dataclass(frozen=True)
class HealthSettings:
    standstill_rms_mps2: float = 0.05  # every channel below this: the wagon stands
    min_excitation_rms_mps2: float = 0.3  # median channel RMS needed to judge the suspension
    flat_rms_mps2: float = 0.02  # a channel below this while another moves is flat
    stuck_repeat_fraction: float = 0.2  # share of samples equal to the previous one
    # One value held this long while the wagon moves: a converter that froze within the window.
    # Healthy, noiseless 16 g / 16-bit sensors hold one value under 0.2 s even at 10 km/h in tare.
    stuck_run_s: float = 1.0
    clip_level_mps2: float = 155.0  # |a| at or above this is clipping (16 g full scale = 156.9)
    clipped_fraction: float = 1e-4  # share of clipped samples that makes a channel unusable
    noise_ratio: float = 2.0  # a channel's RMS over the median of the three
    noise_low_band_ratio: float = 3.2  # a channel's power at 0.5-1 Hz over the median of the three
    max_rms_mps2: float = 50.0  # no bogie frame in service gives this much RMS
    max_gaps_per_hour: int = 6  # more gaps than this in the last hour: dropouts
    gravity_mps2: float = 9.81  # a channel's mean below -half of it, another's above +half: inverted
    structure_checks: bool = True  # the checks that assume a real frame's spectra: layout, low-band noise
    layout_low_coherence: float = -0.2  # a channel's 0.5-2 Hz coherency with both others below: inverted
    layout_diagonal_coherence: float = -0.3  # the diagonal pair's 16-64 Hz coherency must stay below


@dataclass(frozen=True)
class WindowHealth:
    """The health verdict for one window."""

    gate: Gate | None
    problems: dict[str, tuple[SensorProblem, ...]]  # channel (or "source") -> problems

    @property
    def sensors_ok(self) -> bool:
        return not self.problems

    @property
    def judgeable(self) -> bool:
        return self.gate is None and self.sensors_ok


def layout_margin(stats: LayoutStatistics, settings: HealthSettings) -> float:
    """How clearly one assignment of the channels passes the structure checks (< 0: it fails one)."""
    return min(
        min(stats.low_coherence) - settings.layout_low_coherence,
        settings.layout_diagonal_coherence - stats.diagonal_coherence,
        stats.other_coherence - stats.diagonal_coherence,
        stats.quadrature_bp - stats.quadrature_br,
    )


# Every assignment of the three channels to the configured corners, with signs; a sign flip of all
# three is the same structure, so the first channel keeps its sign (gravity tells that one apart).
_HYPOTHESES = tuple(
    (perm, signs) for perm in itertools.permutations(range(3)) for signs in itertools.product((1.0, -1.0), repeat=3) if signs[0] > 0
)


def layout_problems(window: WindowIndicators, geometry: BogieGeometry, settings: HealthSettings) -> dict[str, list[SensorProblem]]:
    """Channels whose data do not fit the configured corners: {"a2": [SWAPPED], ...}; {} when they fit.

    Reported only when the configured layout fails a check and another assignment passes all.
    """
    assert window.spectra is not None
    matrix = window.spectra.matrix()
    identity = layout_margin(layout_statistics(matrix, geometry), settings)
    if identity >= 0:
        return {}
    best, best_margin = None, 0.0
    for perm, signs in _HYPOTHESES:
        if perm == (0, 1, 2) and signs == (1.0, 1.0, 1.0):
            continue
        margin = layout_margin(layout_statistics(matrix, geometry, perm, signs), settings)
        if margin > best_margin:
            best, best_margin = (perm, signs), margin
    if best is None:
        return {}
    perm, signs = best
    if sum(s < 0 for s in signs) > 1:  # the same structure with every sign flipped: fewer inverted
        signs = tuple(-s for s in signs)
    out: dict[str, list[SensorProblem]] = {}
    for corner_index, (channel, sign) in enumerate(zip(perm, signs, strict=True)):
        if channel != corner_index:
            out.setdefault(CHANNELS[channel], []).append(SensorProblem.SWAPPED)
        if sign < 0:
            out.setdefault(CHANNELS[channel], []).append(SensorProblem.INVERTED)
    return out


def assess_window(
    window: WindowIndicators,
    settings: HealthSettings,
    status: tuple[SensorStatus, SensorStatus, SensorStatus] = (SensorStatus.OK,) * 3,
    gaps_last_hour: int = 0,
    geometry: BogieGeometry | None = None,
) -> WindowHealth:
    """The verdict on one window; with the sensors' geometry also the layout check."""
    rms = np.array(window.rms_mps2)
    stats = window.channels
    problems: dict[str, list[SensorProblem]] = {}

    def flag(channel: str, problem: SensorProblem) -> None:
        problems.setdefault(channel, []).append(problem)

    standstill = bool(np.all(rms < settings.standstill_rms_mps2))
    median_rms = float(np.median(rms))
    # Sensor noise is white: it fills the lowest band, where the frame moves least and every
    # corner alike (it follows the carbody), long before it shows in the channel's RMS.
    low_power = np.array(window.spectra.power[0]) if window.spectra is not None and settings.structure_checks else None
    low_median = float(np.median(low_power)) if low_power is not None else 0.0
    for c, name in enumerate(CHANNELS):
        if SensorStatus.SENSOR_FAULT in status[c]:
            flag(name, SensorProblem.SENSOR_FAULT_BIT)
        if SensorStatus.OVER_RANGE in status[c]:
            flag(name, SensorProblem.OVER_RANGE)
        if stats.clipped_fraction[c] >= settings.clipped_fraction:  # counted at clip_level_mps2 by the core
            flag(name, SensorProblem.CLIPPING)
        if rms[c] > settings.max_rms_mps2 or (median_rms > 0 and rms[c] > settings.noise_ratio * median_rms):
            flag(name, SensorProblem.NOISY)
        elif low_power is not None and low_median > 0 and low_power[c] > settings.noise_low_band_ratio * low_median:
            flag(name, SensorProblem.NOISY)
        if not standstill:  # a quiet channel is only suspicious while another one moves
            if rms[c] < settings.flat_rms_mps2:
                flag(name, SensorProblem.FLAT)
            if stats.repeat_fraction[c] >= settings.stuck_repeat_fraction or stats.longest_run_s[c] >= settings.stuck_run_s:
                flag(name, SensorProblem.STUCK)
    if gaps_last_hour > settings.max_gaps_per_hour:
        flag("source", SensorProblem.DROPOUTS)
    means = np.array(stats.mean_mps2)
    upright = bool(np.any(means > settings.gravity_mps2 / 2))
    for c, name in enumerate(CHANNELS):
        if upright and means[c] < -settings.gravity_mps2 / 2:
            flag(name, SensorProblem.INVERTED)

    gate = None
    if standstill:
        gate = Gate.STANDSTILL
    elif median_rms < settings.min_excitation_rms_mps2:
        gate = Gate.WEAK_EXCITATION
    # The structure needs a moving wagon; a channel already at fault would mislead it.
    if gate is None and not problems and settings.structure_checks and geometry is not None and window.spectra is not None:
        for name, found in layout_problems(window, geometry, settings).items():
            for problem in found:
                flag(name, problem)
    return WindowHealth(gate=gate, problems={k: tuple(v) for k, v in problems.items()})


@dataclass
class HealthState:
    reported: dict[str, list[str]]  # the problems of the last SENSOR_FAULT, empty when healthy
    clean_windows: int = 0

    def as_dict(self) -> dict[str, object]:
        return {"reported": self.reported, "clean_windows": self.clean_windows}

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> HealthState:
        if not data:
            return cls(reported={})
        return cls(reported={k: list(v) for k, v in data["reported"].items()}, clean_windows=int(data["clean_windows"]))


class HealthTracker:
    """Turns per-window health verdicts into SENSOR_FAULT and SENSOR_CLEARED events.

    A fault is reported when a problem appears that is not reported yet (a channel, or a new
    problem on one); while it lasts the reported set only grows, so a problem that comes and
    goes from window to window (a dead channel seen as flat, then flat and stuck) is one event,
    not one per change. It clears after clear_after_windows consecutive windows without problems
    in which the wagon moved (at standstill a flat or stuck channel cannot be told from a quiet
    one).
    """

    def __init__(self, config_hash: str, clear_after_windows: int = 3, state: HealthState | None = None) -> None:
        self.config_hash = config_hash
        self.clear_after_windows = clear_after_windows
        self.state = state or HealthState(reported={})

    @property
    def faulted(self) -> bool:
        """A SENSOR_FAULT is reported and not yet cleared."""
        return bool(self.state.reported)

    def update(self, window: WindowIndicators, health: WindowHealth) -> list[Event]:
        s = self.state
        current = {ch: sorted(p.value for p in problems) for ch, problems in health.problems.items()}
        details = {"window_start_s": window.start_s, "window_end_s": window.end_s, "rms_mps2": list(window.rms_mps2)}
        if current:
            s.clean_windows = 0
            grown = {ch: sorted(set(s.reported.get(ch, [])) | set(ps)) for ch, ps in {**s.reported, **current}.items()}
            if grown != s.reported:
                s.reported = grown
                return [self._event(window, EventKind.SENSOR_FAULT, {**details, "problems": current, "reported": grown})]
            return []
        if s.reported and health.gate is not Gate.STANDSTILL:
            s.clean_windows += 1
            if s.clean_windows >= self.clear_after_windows:
                previous, s.reported, s.clean_windows = s.reported, {}, 0
                return [self._event(window, EventKind.SENSOR_CLEARED, {**details, "cleared": previous})]
        return []

    def _event(self, window: WindowIndicators, kind: EventKind, details: dict[str, object]) -> Event:
        return Event(time_s=window.end_s, kind=kind, severity=DEFAULT_SEVERITY[kind], config_hash=self.config_hash, details=details)
