"""Sensor health: decide whether a window's sensors can be trusted, and name what is wrong.

A stuck or dead channel creates exactly the asymmetry the indicators look for, so every window
is checked here first. A window is judged only when the wagon runs steadily with enough
excitation (judgement/gating.py) and every sensor looks healthy; otherwise it is gated or the sensors
are at fault (a SENSOR_FAULT, never a suspension alarm). The sensors' structure (an inverted or
swapped sensor, judgement/structure.py) and noise floor (judgement/noise_floor.py) are learned from the
wagon at commissioning; the tracker across windows is judgement/sensor_tracker.py.

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
  (noise_low_band_ratio: a prior from the simulated fleet, at most 2.7 there, see [health]), in
  windows of steady running only (a stop pitches the frame at 0.5-1 Hz).
  Its noise enters bounce and roll alike, a coupling of its own: the noise floor below closes it.


THE NOISE FLOOR, learned from the wagon (judgement/noise_floor.py says how and why,
docs/sensor-health.md what it was measured to find). A sensor's own white noise (a failing
element, a poor cable screen, a loose mounting) adds to the part of its channel the other two cannot
explain in every band up to Nyquist, long before it shows in the couplings of 2-64 Hz; it stands out
most in the top octave below Nyquist, where any accelerometer's anti-alias filter leaves least of
the frame. Commissioning learns per channel the smallest density and the largest ratio to the other
two channels' there; a channel later noise_floor_margin times above both is noisy. Uncommissioned,
it is not in force. Noise that enters before a part's filter that cuts low (a MEMS part at ODR/10)
is shaped like the frame's motion and is not seen there; the coherence checks above remain.

A SENSOR FAULT NEVER HIDES A SUSPENSION FAULT. A broken spring at a sensor's corner lets that corner
move in ways the other two sensors cannot explain, in the top octave too: the noise floor names that
sensor noisy although it is sound (on the simulated fleet, wagon 005's broken spring at a3's corner
was first reported as `SENSOR_FAULT a3 noisy`, and held back from judgement for a day). Noise seen by
the floor alone (WindowHealth.floor_only: no RMS, low-band, coherence or layout check saw it) is by
construction too faint to move the couplings the suspension is judged on: white noise adds the same
density at 2-64 Hz, where the frame moves orders of magnitude more than in the top octave, and noise
strong enough to matter there breaks the 0.5-1 Hz coherence or the RMS ratio first. Such a window is
judged on its couplings (HealthSettings.judge_through_floor_noise), and the sensor is reported
beside it; when the couplings moved as a one-corner fault moves them (the window at warning level or
above, its pitch-roll sign naming a diagonal pair: judgement/diagnosis.py), the SENSOR_FAULT event
says so too ("suspension"), so that neither is told alone. Every other sensor problem holds the
judgement back as before: a dead, stuck, clipping or grossly noisy channel couples the modes itself.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.gating import Gate, window_gate
from bogiemon.judgement.noise_floor import floor_noisy_channels
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.structure import layout_fit
from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.drivers.base import ALL_OK, SensorStatus

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


# The coherence noise check (module docstring): its band, 0.5-1 Hz (detection.spectra.BANDS_HZ);
# the largest phase of the same-rail pair's cross-spectrum there for which it applies (waves at
# least 8 wheelbases long); and the share of the noisy sensor's unexplained power its excess
# power over its partner's must reach (white noise adds both alike: 1, less the partner's scatter).
NOISE_BAND = 0
LONG_WAVE_PHASE_RAD = np.pi / 4
NOISE_POWER_SHARE = 0.5


@dataclass(frozen=True)
class WindowHealth:
    """The health verdict for one window."""

    gate: Gate | None
    problems: dict[str, tuple[SensorProblem, ...]]  # channel (or "source") -> problems
    # The channels named noisy by the noise floor alone: noise in the top octave that no other check
    # saw (module docstring, "A SENSOR FAULT NEVER HIDES A SUSPENSION FAULT").
    floor_only: tuple[str, ...] = ()

    @property
    def sensors_ok(self) -> bool:
        return not self.problems

    @property
    def couplings_readable(self) -> bool:
        """A sensor is flagged, but the suspension can be judged on the window's couplings: the
        wagon runs steadily and every problem is noise the floor alone saw."""
        return self.gate is None and bool(self.problems) and set(self.problems) == set(self.floor_only)

    @property
    def judgeable(self) -> bool:
        return self.gate is None and self.sensors_ok


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


def assess_window(
    window: WindowIndicators,
    settings: HealthSettings,
    status: tuple[SensorStatus, SensorStatus, SensorStatus] = ALL_OK,
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
    # corner alike (it follows the carbody), long before it shows in the channel's RMS. Only while
    # the wagon runs steadily: braking to a stop and starting again pitch the frame at 0.5-1 Hz, and
    # a healthy channel there rose 3.35 times the median (model B, a training wagon's stop).
    steady = gate is None and settings.structure_checks
    low_power = np.array(window.spectra.power[0]) if steady and window.spectra is not None else None
    low_median = float(np.median(low_power)) if low_power is not None else 0.0
    for c, name in enumerate(CHANNELS):
        if SensorStatus.SENSOR_FAULT in status[c]:
            flag(name, SensorProblem.SENSOR_FAULT_BIT)
        if SensorStatus.OVER_RANGE in status[c]:
            flag(name, SensorProblem.OVER_RANGE)
        if stats.clipped_fraction[c] >= settings.clipped_fraction:  # counted at clip_level_mps2 by the core
            flag(name, SensorProblem.CLIPPING)
        # Noise is a channel that moves more than the others: one below the standstill level does
        # not move at all (three constant channels of a standing wagon leave the high-pass only
        # rounding, whose ratios mean nothing), and at standstill the frame gives no band to compare.
        moving = rms[c] >= settings.standstill_rms_mps2 and not standstill
        if rms[c] > settings.max_rms_mps2 or (moving and median_rms > 0 and rms[c] > settings.noise_ratio * median_rms):
            flag(name, SensorProblem.NOISY)
        elif moving and low_power is not None and low_median > 0 and low_power[c] > settings.noise_low_band_ratio * low_median:
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
        fit = layout_fit(window.spectra.matrix, geometry, settings)
        if fit is not None:
            for channel in fit.moved():
                flag(CHANNELS[channel], SensorProblem.SWAPPED)
            for channel in fit.flipped():
                flag(CHANNELS[channel], SensorProblem.INVERTED)
        noisy = None if problems else coherence_noisy_channel(window.spectra.matrix, geometry, settings)
        if noisy is not None:
            flag(CHANNELS[noisy], SensorProblem.NOISY)
    # The noise floor needs no structure, only the commissioning's floors: any moving window whose
    # channels are otherwise sound (a dead or stuck one would make the others' ratios look noisy).
    floor_only: list[str] = []
    if gate is not Gate.STANDSTILL and settings.structure_checks and not problems:
        for c in floor_noisy_channels(window, settings):
            flag(CHANNELS[c], SensorProblem.NOISY)
            floor_only.append(CHANNELS[c])
    return WindowHealth(gate=gate, problems={k: tuple(v) for k, v in problems.items()}, floor_only=tuple(floor_only))
