"""Sensor health and gating: decide whether a window may be judged at all, and why not.

A stuck or dead channel creates exactly the asymmetry the indicators look for, so every window
is checked here first. A window is judged only when the wagon runs steadily with enough
excitation and every sensor looks healthy; otherwise it is gated (standstill, a stop or start
inside it, weak excitation) or the sensors are at fault (a SENSOR_FAULT, never a suspension alarm).

THE GATES. Standstill: every channel quiet. Non-stationary: the window holds a hop near
standstill, or its quietest hop's RMS is below min_hop_rms_ratio of its loudest (the median
channel's per-hop RMS, detection/channel_stats.py). A running frame's RMS grows with speed as
about v^a, a = 1.2 to 2 on both simulated wagon models (lab/robust/health_check.py prints it), so
a ratio of 0.25 between two hops of one window is a speed change by a factor 0.25^(-1/a) = 2 to
3.2 within two minutes: braking to a stop, standing, or starting. Running hops differ far less:
the ratio stayed above 0.34 on every window of the simulated fleets, whose speed drifts within
50-110 km/h, and above 0.6 at a steady 10-30 km/h. The couplings of such a
window mix running with standing, and the dry-friction dampers stick at low speed: not judged.
Weak excitation: moving, but the median channel's RMS is too small to judge the suspension.

THE SENSORS, by physics alone (any wagon, commissioned or not): the sensor's own fault bits,
flat, stuck, clipping, gross noise (a channel's RMS over the others', or beyond what a frame gives),
dropouts, gravity's sign (a vertical accelerometer reads about +9.81 m/s^2 of mean; one reading
about -9.81 while another reads +9.81 is upside down), and white noise seen in the coherence:
- Two of the three sensors sit on one rail (the same side, leading and trailing). At 0.5-1 Hz,
  below the frame's own modes, the frame follows the carbody and the rail's long waves, and the two
  ends of the rail move alike: each of the two is a linear function of the other, the third sensor
  adding what the carbody's roll brings from the other rail. So each one's multiple coherence with
  the other two (the share of its power they explain) is near 1: at least 0.81 on every healthy
  window of the simulated fleets of both models where the premise below holds (lab/robust/
  health_check.py prints it). That holds while the waves are long against the wheelbase, which the
  pair's cross-spectrum measures itself: its phase is about the wheelbase's share of a wavelength
  (2 pi f 2l / v); within pi/4 (waves of 8 wheelbases and more; a pure delay puts that at 40-50 km/h,
  the frame's own response lowers the phase, so on the simulated wagons it holds from 25-35 km/h)
  the check applies, beyond it (walking pace) it says nothing.
  White noise of power N on one of them, where the frame gives S, lowers that sensor's multiple
  coherence to S / (S + N); below noise_coherence = 0.75 the noise is at least a third of the
  frame's motion in the band (SNR below 3, 4.8 dB). Noise is independent of everything, so it adds
  to the sensor's power what it adds to its unexplained power, and it lowers the sensor's coherence
  with both others while its partner keeps its own: the sensor named is the one of the pair whose
  coherence with the third fell, and only when its power exceeds its partner's by at least half of
  its unexplained power (a swap, or the track at walking pace, lowers a coherence without adding
  power). White noise fills this band first, where the frame moves least, long before the
  couplings of 2-64 Hz feel it; where the frame's own motion in the band is many times the noise
  (rough track, high speed), the noise is not seen.
- The third sensor is alone on its rail: its low-band motion (the cross level) has no second
  witness, so white noise on it cannot be told from the track in the coherence. Beside the RMS
  ratio it keeps the low-band power check: its power at 0.5-1 Hz over the median of the three
  (noise_low_band_ratio: a prior from the simulated fleet, at most 2.7 there, see [health]).
  Its noise enters bounce and roll alike, a coupling of its own: the noise floor below closes it.

THE NOISE FLOOR, learned from the wagon. A sensor's own white noise (a failing element, a poor cable
screen, a loose mounting) of density n adds exactly n x the band's width, in every band, to the part
of its channel the other two channels cannot explain (1 / (S^-1)_cc of the band's cross-spectral
matrix: the cross-spectra do not change). A channel's noise floor is the smallest density of that
part over the bands from 0.5 Hz to Nyquist (noise_floors): where the frame gives least, above
64 Hz past its motion and into the anti-alias filters' roll-off, or where the other two sensors
explain it best. White noise lifts the floor in every band, so to at least n, long before it shows
in the couplings of 2-64 Hz (0.4 m/s^2 RMS at 500 Hz puts three quarters of its power above 64 Hz).
Commissioning learns, per channel, the largest ratio of its floor to the other two channels' (their
geometric mean) and the smallest floor its healthy windows showed (learn_noise_floor); a channel
later noise_floor_margin times above both is noisy: alone (a rough track or a high speed lifts every
channel's floor, leaving the ratios) and well above the quietest it ever is (at walking pace every
floor sinks to its sensor's own, whose ratios need not be the running frame's). On the simulated
fleets of both wagon models the floor sits in the top half octave below Nyquist (181-250 Hz at
500 Hz), in the anti-alias roll-off, where 0.4 m/s^2 of white noise lifts it 20 to 1000 times and
healthy running on other tracks and speeds stays within the commissioning's ratios. Uncommissioned,
it is not in force. A frame whose own vibration fills every band up to Nyquist hides the noise: the
check then says nothing (never a false fault), and the coherence checks above remain.

THE STRUCTURE, learned from the wagon. A sensor mounted upside down or two cables swapped give
healthy-looking channels whose bounce, pitch and roll are wrong, and strong couplings: fault-like.
The rigid frame's structure in the band cross-spectra (detection/features.py: layout_statistics)
tells them apart: "low", at 0.5-2 Hz each channel correlates positively with another (an inverted
one negatively); "diagonal", at 16-64 Hz the two diagonal corners move in opposition; "other",
the other pairs less so; "quadrature", at 0.5-4 Hz bounce and pitch are in quadrature (the rear
axle meets the track 2l/v after the front one), bounce and roll much less. Which of these hold, and
how clearly, depends on the wagon: commissioning learns them (learn_structure, on the wagon's
healthy windows) and writes the checks in force and their thresholds under [health]. An
uncommissioned wagon has none in force: no structure-based fault. With checks in force, a layout
that fails one while another assignment of the channels to the corners (with or without sign
flips) passes all of them names the channels it moves "swapped" and those it flips "inverted".
"""

from __future__ import annotations

import dataclasses
import enum
import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.daemon.events import DEFAULT_SEVERITY, Event, EventKind
from bogiemon.daemon.noise_floor import floor_noisy_channels
from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import LayoutStatistics, layout_statistics
from bogiemon.drivers.base import SensorStatus

CHANNELS = ("a1", "a2", "a3")


class SensorProblem(enum.Enum):
    FLAT = "flat"  # no dynamic signal while the others move: dead, disconnected or frozen
    STUCK = "stuck"  # the converter repeats its last value
    CLIPPING = "clipping"  # samples at the converter's full scale
    NOISY = "noisy"  # more signal than the other channels or a bogie frame give, or noise that breaks the coherence
    OVER_RANGE = "over_range"  # the sensor's own over-range bit
    SENSOR_FAULT_BIT = "sensor_fault_bit"  # the sensor's own fault bit
    DROPOUTS = "dropouts"  # the source loses samples too often
    INVERTED = "inverted"  # reads upside down (mounted so, or its sign wired so)
    SWAPPED = "swapped"  # its signal belongs to another corner than the config names


class Gate(enum.Enum):
    STANDSTILL = "standstill"  # every channel quiet: the wagon stands
    # The excitation changes too much within the window: a stop, a start or a standstill inside it.
    NON_STATIONARY = "non_stationary"
    WEAK_EXCITATION = "weak_excitation"  # moving, but too little excitation to judge


# The structure checks of layout_margin, by the names the config uses.
LAYOUT_CHECKS: tuple[str, ...] = ("low", "diagonal", "other", "quadrature")
# The coherence noise check (module docstring): its band, 0.5-1 Hz (detection.spectra.BANDS_HZ);
# the largest phase of the same-rail pair's cross-spectrum there for which it applies (waves at
# least 8 wheelbases long); and the share of the noisy sensor's unexplained power its excess
# power over its partner's must reach (white noise adds both alike: 1, less the partner's scatter).
NOISE_BAND = 0
LONG_WAVE_PHASE_RAD = np.pi / 4
NOISE_POWER_SHARE = 0.5


@dataclass(frozen=True)
class HealthSettings:
    standstill_rms_mps2: float = 0.05  # every channel below this: the wagon stands
    min_excitation_rms_mps2: float = 0.3  # median channel RMS needed to judge the suspension
    # The quietest hop's RMS over the loudest's (median channel) below this: a stop or start inside.
    min_hop_rms_ratio: float = 0.25
    flat_rms_mps2: float = 0.02  # a channel below this while another moves is flat
    stuck_repeat_fraction: float = 0.2  # share of samples equal to the previous one
    # One value held this long while the wagon moves: a converter that froze within the window.
    # Healthy, noiseless 16 g / 16-bit sensors hold one value under 0.2 s even at 10 km/h in tare.
    stuck_run_s: float = 1.0
    clip_level_mps2: float = 155.0  # |a| at or above this is clipping (16 g full scale = 156.9)
    clipped_fraction: float = 1e-4  # share of clipped samples that makes a channel unusable
    noise_ratio: float = 2.0  # a channel's RMS over the median of the three
    noise_low_band_ratio: float = 3.2  # a channel's power at 0.5-1 Hz over the median of the three
    # A same-rail sensor's 0.5-1 Hz multiple coherence with the other two below this: noisy (SNR < 3).
    noise_coherence: float = 0.75
    max_rms_mps2: float = 50.0  # no bogie frame in service gives this much RMS
    max_gaps_per_hour: int = 6  # more gaps than this in the last hour: dropouts
    gravity_mps2: float = 9.81  # a channel's mean below -half of it, another's above +half: inverted
    # The checks that assume a real frame's spectra (coherence and low-band noise, the layout).
    structure_checks: bool = True
    # The layout checks in force (LAYOUT_CHECKS), learned at commissioning; none on an uncommissioned wagon.
    layout_checks: tuple[str, ...] = ()
    layout_low_coherence: float = -0.2  # "low": each channel's 0.5-2 Hz coherency with another above this
    layout_diagonal_coherence: float = -0.3  # "diagonal": the diagonal pair's 16-64 Hz coherency below this
    layout_other_margin: float = 0.0  # "other": the other pairs' 16-64 Hz coherency above the diagonal's by this
    layout_quadrature_margin: float = 0.0  # "quadrature": bounce-pitch above bounce-roll quadrature by this
    # The noise floor, learned at commissioning (learn_noise_floor): per channel the smallest floor
    # its healthy windows showed, (m/s^2)^2/Hz, and the largest ratio of it to the other two
    # channels' (their geometric mean); empty on a wagon not commissioned: not in force.
    noise_floor_psd: tuple[float, ...] = ()
    noise_floor_ratio: tuple[float, ...] = ()
    noise_floor_margin: float = 4.0  # a floor this many times both of those is a noisy sensor

    def __post_init__(self) -> None:
        unknown = sorted(set(self.layout_checks) - set(LAYOUT_CHECKS))
        if unknown:
            raise ValueError(f"unknown layout checks {unknown}: use some of {list(LAYOUT_CHECKS)}")
        if len(self.noise_floor_psd) != len(self.noise_floor_ratio) or len(self.noise_floor_psd) not in (0, 3):
            raise ValueError("noise_floor_psd and noise_floor_ratio need one value per channel (three each), or none")


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


# --------------------------------------------------------------------------------------------
# The layout: the rigid frame's structure, checked with what commissioning learned


def layout_check_values(stats: LayoutStatistics) -> dict[str, float]:
    """Each check's statistic, signed so that the configured layout of a healthy frame gives it large."""
    return {
        "low": min(stats.low_coherence),
        "diagonal": -stats.diagonal_coherence,
        "other": stats.other_coherence - stats.diagonal_coherence,
        "quadrature": stats.quadrature_bp - stats.quadrature_br,
    }


def layout_thresholds(settings: HealthSettings) -> dict[str, float]:
    """Each check's threshold on layout_check_values' scale (it passes above it)."""
    return {
        "low": settings.layout_low_coherence,
        "diagonal": -settings.layout_diagonal_coherence,
        "other": settings.layout_other_margin,
        "quadrature": settings.layout_quadrature_margin,
    }


def layout_margin(stats: LayoutStatistics, settings: HealthSettings) -> float:
    """How clearly one assignment of the channels passes the checks in force (< 0: it fails one;
    +inf when none is in force)."""
    values, thresholds = layout_check_values(stats), layout_thresholds(settings)
    return min((values[c] - thresholds[c] for c in settings.layout_checks), default=float("inf"))


# Every assignment of the three channels to the configured corners, with signs; a sign flip of all
# three is the same structure, so the first channel keeps its sign (gravity tells that one apart).
_HYPOTHESES = tuple(
    (perm, signs) for perm in itertools.permutations(range(3)) for signs in itertools.product((1.0, -1.0), repeat=3) if signs[0] > 0
)
_TIE = 1e-9  # margins this close are one: the checks in force cannot tell those hypotheses apart


def _changes(perm: tuple[int, ...], signs: tuple[float, ...]) -> int:
    return sum(p != i for i, p in enumerate(perm)) + min(sum(s < 0 for s in signs), sum(s > 0 for s in signs))


def layout_problems(window: WindowIndicators, geometry: BogieGeometry, settings: HealthSettings) -> dict[str, list[SensorProblem]]:
    """Channels whose data do not fit the configured corners: {"a2": [SWAPPED], ...}; {} when they fit.

    Only the checks in force (settings.layout_checks) count: none, no layout problems. Reported
    only when the configured layout fails one and another assignment passes all; of assignments
    the checks cannot tell apart, the one that changes the fewest channels.
    """
    if not settings.layout_checks:
        return {}
    assert window.spectra is not None
    matrix = window.spectra.matrix()
    if layout_margin(layout_statistics(matrix, geometry), settings) >= 0:
        return {}
    passing = []
    for perm, signs in _HYPOTHESES:
        if perm == (0, 1, 2) and signs == (1.0, 1.0, 1.0):
            continue
        margin = layout_margin(layout_statistics(matrix, geometry, perm, signs), settings)
        if margin > 0:
            passing.append((margin, perm, signs))
    if not passing:
        return {}
    best_margin = max(m for m, _, _ in passing)
    _, perm, signs = min((p for p in passing if p[0] >= best_margin - _TIE), key=lambda p: _changes(p[1], p[2]))
    if sum(s < 0 for s in signs) > 1:  # the same structure with every sign flipped: fewer inverted
        signs = tuple(-s for s in signs)
    out: dict[str, list[SensorProblem]] = {}
    for corner_index, (channel, sign) in enumerate(zip(perm, signs, strict=True)):
        if channel != corner_index:
            out.setdefault(CHANNELS[channel], []).append(SensorProblem.SWAPPED)
        if sign < 0:
            out.setdefault(CHANNELS[channel], []).append(SensorProblem.INVERTED)
    return out


# What commissioning needs to put a check in force: its statistic at least this on every healthy
# window (coherencies and their differences: 0.2 is far outside an estimate's scatter over a
# 120 s window, and a sign flip or a swap moves the statistic by about twice its healthy value).
MIN_STRUCTURE_MARGIN = 0.2


@dataclass(frozen=True)
class StructureFit:
    """The frame structure a wagon's healthy windows showed: the checks that hold, with thresholds.

    smallest[c] is the smallest value of check c's statistic (layout_check_values) over the
    windows; a check holds when that is at least MIN_STRUCTURE_MARGIN, and its threshold is half
    of it: a swap or a sign flip takes the statistic to about minus its healthy value, while a
    healthy window later, on other tracks and speeds, keeps half the margin the commissioning saw.
    """

    checks: tuple[str, ...]  # in force, in LAYOUT_CHECKS order
    thresholds: dict[str, float]  # check -> threshold on layout_check_values' scale, for those in force
    smallest: dict[str, float]  # check -> its smallest value over the windows (every check)
    windows: int

    def health_fields(self) -> dict[str, Any]:
        """The [health] fields that put this structure in force (for the calibration fragment)."""
        out: dict[str, Any] = {"layout_checks": list(self.checks)}
        for check, threshold in self.thresholds.items():
            name, value = _THRESHOLD_FIELDS[check]
            out[name] = round(value(threshold), 4)
        return out

    def applied_to(self, settings: HealthSettings) -> HealthSettings:
        """The settings with this structure in force, as its health_fields in the config give them."""
        fields = self.health_fields()
        return dataclasses.replace(settings, **{**fields, "layout_checks": tuple(fields["layout_checks"])})


# Check -> (its HealthSettings field, from the threshold on layout_check_values' scale to the field's).
_THRESHOLD_FIELDS = {
    "low": ("layout_low_coherence", lambda t: t),
    "diagonal": ("layout_diagonal_coherence", lambda t: -t),
    "other": ("layout_other_margin", lambda t: t),
    "quadrature": ("layout_quadrature_margin", lambda t: t),
}


def structure_of(smallest: dict[str, float], windows: int) -> StructureFit:
    """The checks in force, and their thresholds, given each check's smallest healthy value."""
    checks = tuple(c for c in LAYOUT_CHECKS if windows and smallest[c] >= MIN_STRUCTURE_MARGIN)
    return StructureFit(checks=checks, thresholds={c: smallest[c] / 2 for c in checks}, smallest=smallest, windows=windows)


def merge_structures(fits: Sequence[StructureFit]) -> StructureFit:
    """One structure from the fits of several commissioning sets (each load state's): exactly what
    learn_structure gives on their windows together (a check holds only if it holds in all)."""
    fits = [f for f in fits if f.windows]
    smallest = {c: min((f.smallest[c] for f in fits), default=float("nan")) for c in LAYOUT_CHECKS}
    return structure_of(smallest, sum(f.windows for f in fits))


def learn_structure(windows: Iterable[WindowIndicators], geometry: BogieGeometry) -> StructureFit:
    """The structure checks that hold on a wagon's healthy windows, and their thresholds.

    Give it the judgeable windows of the commissioning runs (healthy wagon, sensors as
    configured); windows without spectra are skipped. No windows: no check in force.
    """
    values: dict[str, list[float]] = {c: [] for c in LAYOUT_CHECKS}
    n = 0
    for window in windows:
        if window.spectra is None:
            continue
        n += 1
        for check, value in layout_check_values(layout_statistics(window.spectra.matrix(), geometry)).items():
            values[check].append(value)
    return structure_of({c: float(np.min(v)) if v else float("nan") for c, v in values.items()}, n)


# --------------------------------------------------------------------------------------------
# Noise seen in the coherence of the two sensors on one rail


def same_rail_pair(geometry: BogieGeometry) -> tuple[int, int, int]:
    """(i, k, j): channels i and k sit on one rail (same side), j alone on the other."""
    c = geometry.corners
    for i, k in ((0, 1), (0, 2), (1, 2)):
        if c[i].y_sign == c[k].y_sign:
            return i, k, 3 - i - k
    raise AssertionError("three corners of a rectangle always put two on one side")  # pragma: no cover


@dataclass(frozen=True)
class RailPairCoherence:
    """What the coherence noise check looks at in one window's 0.5-1 Hz band."""

    phase_rad: float  # |phase| of the same-rail pair's cross-spectrum: their spacing's share of a wavelength
    power: tuple[float, float, float]  # of each channel, (m/s^2)^2
    unexplained: tuple[float, float, float]  # of each channel's power, what the other two cannot explain
    coherence2: NDArray[np.float64]  # (3, 3) magnitude-squared coherence of each pair

    @property
    def multiple(self) -> tuple[float, float, float]:
        """Each channel's multiple coherence with the other two: the share of its power they explain."""
        m = [1.0 - u / p for u, p in zip(self.unexplained, self.power, strict=True)]
        return (m[0], m[1], m[2])


def rail_pair_coherence(matrix: NDArray[np.complex128], geometry: BogieGeometry) -> RailPairCoherence | None:
    """The 0.5-1 Hz coherence of a window's band cross-spectra; None when a channel has no power
    there (a dead one: the flat check's) or two are identical (nothing of either is unexplained)."""
    i, k, _ = same_rail_pair(geometry)
    s = matrix[NOISE_BAND]
    power = np.real(np.diagonal(s))
    if not np.all(power > 0):
        return None
    try:
        unexplained = 1.0 / np.real(np.diagonal(np.linalg.inv(s)))
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(unexplained)):
        return None
    return RailPairCoherence(
        phase_rad=float(abs(np.angle(s[i, k]))),
        power=(float(power[0]), float(power[1]), float(power[2])),
        unexplained=(float(unexplained[0]), float(unexplained[1]), float(unexplained[2])),
        coherence2=np.abs(s) ** 2 / np.outer(power, power),
    )


def coherence_noisy_channel(matrix: NDArray[np.complex128], geometry: BogieGeometry, settings: HealthSettings) -> int | None:
    """The channel of the same-rail pair whose white noise breaks the frame's 0.5-1 Hz coherence, or None.

    matrix: the window's (n_bands, 3, 3) band cross-spectra (the module docstring says why).
    """
    c = rail_pair_coherence(matrix, geometry)
    if c is None or c.phase_rad > LONG_WAVE_PHASE_RAD:
        return None  # no power to judge, or waves too short for the premise
    i, k, j = same_rail_pair(geometry)
    noisy, partner = (i, k) if c.coherence2[i, j] < c.coherence2[k, j] else (k, i)
    if not c.multiple[noisy] < settings.noise_coherence:
        return None
    return noisy if c.power[noisy] - c.power[partner] >= NOISE_POWER_SHARE * c.unexplained[noisy] else None


# --------------------------------------------------------------------------------------------
# The verdict


def window_gate(window: WindowIndicators, settings: HealthSettings) -> Gate | None:
    """Why the window cannot be judged whatever the sensors (None: it can)."""
    rms = np.asarray(window.rms_mps2)
    if np.all(rms < settings.standstill_rms_mps2):
        return Gate.STANDSTILL
    # The median channel: one faulty sensor (noisy, dead) moves neither of them.
    hop_min = float(np.median(window.channels.hop_rms_min_mps2))
    hop_max = float(np.median(window.channels.hop_rms_max_mps2))
    if hop_min < settings.standstill_rms_mps2 or hop_min < settings.min_hop_rms_ratio * hop_max:  # NaN (not measured): neither
        return Gate.NON_STATIONARY
    if float(np.median(rms)) < settings.min_excitation_rms_mps2:
        return Gate.WEAK_EXCITATION
    return None


def assess_window(
    window: WindowIndicators,
    settings: HealthSettings,
    status: tuple[SensorStatus, SensorStatus, SensorStatus] = (SensorStatus.OK,) * 3,
    gaps_last_hour: int = 0,
    geometry: BogieGeometry | None = None,
) -> WindowHealth:
    """The verdict on one window; with the sensors' geometry also the coherence and layout checks."""
    rms = np.array(window.rms_mps2)
    stats = window.channels
    problems: dict[str, list[SensorProblem]] = {}

    def flag(channel: str, problem: SensorProblem) -> None:
        problems.setdefault(channel, []).append(problem)

    gate = window_gate(window, settings)
    standstill = gate is Gate.STANDSTILL
    # A hop of the window stood still: its quantised samples repeat like a frozen converter's.
    stood = bool(np.median(stats.hop_rms_min_mps2) < settings.standstill_rms_mps2)
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
            if not stood and (stats.repeat_fraction[c] >= settings.stuck_repeat_fraction or stats.longest_run_s[c] >= settings.stuck_run_s):
                flag(name, SensorProblem.STUCK)
    if gaps_last_hour > settings.max_gaps_per_hour:
        flag("source", SensorProblem.DROPOUTS)
    means = np.array(stats.mean_mps2)
    upright = bool(np.any(means > settings.gravity_mps2 / 2))
    for c, name in enumerate(CHANNELS):
        if upright and means[c] < -settings.gravity_mps2 / 2:
            flag(name, SensorProblem.INVERTED)

    # The frame's structure needs a steadily moving wagon; a channel already at fault would mislead
    # it. A layout that does not fit explains a broken coherence too, so it is looked at first.
    if gate is None and not problems and settings.structure_checks and geometry is not None and window.spectra is not None:
        for name, found in layout_problems(window, geometry, settings).items():
            for problem in found:
                flag(name, problem)
        noisy = None if problems else coherence_noisy_channel(window.spectra.matrix(), geometry, settings)
        if noisy is not None:
            flag(CHANNELS[noisy], SensorProblem.NOISY)
    # The noise floor needs no structure, only the commissioning's floors: any moving window whose
    # channels are otherwise sound (a dead or stuck one would make the others' ratios look noisy).
    if gate is not Gate.STANDSTILL and settings.structure_checks and not problems:
        for c in floor_noisy_channels(window, settings):
            flag(CHANNELS[c], SensorProblem.NOISY)
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
    that were not gated: at standstill a flat or stuck channel cannot be told from a quiet one,
    and the coherence and layout checks run only on windows of steady, excited running.
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
        if s.reported and health.gate is None:
            s.clean_windows += 1
            if s.clean_windows >= self.clear_after_windows:
                previous, s.reported, s.clean_windows = s.reported, {}, 0
                return [self._event(window, EventKind.SENSOR_CLEARED, {**details, "cleared": previous})]
        return []

    def _event(self, window: WindowIndicators, kind: EventKind, details: dict[str, object]) -> Event:
        return Event(time_s=window.end_s, kind=kind, severity=DEFAULT_SEVERITY[kind], config_hash=self.config_hash, details=details)
