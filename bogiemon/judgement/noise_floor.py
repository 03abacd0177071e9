"""A sensor's noise floor, learned from the wagon at commissioning (judgement/health.py's module
docstring says why it names a noisy sensor): per channel, in each band of the top octave below
Nyquist, the density of what the other two channels cannot explain and its ratio to theirs in the
same band.

    fit = learn_noise_floor(commissioning_windows)      # -> the [health] fields of the fragment
    noisy = floor_noisy_channels(window, settings)      # the channels noisy in this window

WHERE TO LOOK. White noise of density n on one channel adds exactly n x a band's width to the part
of that channel the other two cannot explain (1 / (S^-1)_cc of the band's cross-spectral matrix:
the cross-spectra do not change), in every band up to Nyquist when it enters after the sensor's
filter. Any accelerometer's anti-alias filter passes least of the frame in its top octave below
Nyquist, so that is where such noise stands out most against the frame, whatever the part. On the
simulated training wagons (lab/robust/health_check.py --noise-floor --fleet training; 2 wagons of
each model, four sensor parts, commissioned on drawn runs), 0.4 m/s^2 after the part lifted a
channel there, in each run, 6.6 to 70 000 times above what its commissioning saw, but only 2 to 3
times where the frame's own vibration, and what folds back from above Nyquist, fill it (model B at
full load through the wideband part, a filter near Nyquist); healthy running on other tracks and
speeds, and with stops, stayed within 1.17 times. A floor taken as the smallest density over all
bands lies wherever the part puts it instead: in the top octave with a steep filter, in the judged
bands when the frame fills the top, and the channels' floors then lie in
different bands, whose ratio is the frame's structure, not a sensor's noise.

THE TEST, in one band at a time: a channel's density and its ratio to the other two's (their
geometric mean) both noise_floor_margin times above what commissioning saw of them in the top
octave (the smallest density, the largest ratio). The margin is a prior fitted on those training
wagons: 1.5 times the largest excess their healthy running showed, 1.8 (docs/sensor-health.md has
the held-out figures). The ratio makes it the channel's own (a rough track or a high speed lifts
every channel's density alike); the density keeps it well above the
quietest the channel ever is (at walking pace every floor sinks to its sensor's own, whose ratios
need not be the running frame's). Both are learned per wagon, as its sensors are.

WHAT IT CANNOT SEE. Noise that enters before a part's filter is shaped like the frame's motion: a
part that cuts low (a MEMS part's digital filter at ODR/10) leaves none of it in the top octave,
and below, in the judged bands, it adds less to a channel's unexplained part than the frame's own
motion varies from window to window (lab/robust/health_check.py --noise-floor measures both).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import WindowIndicators
from bogiemon.judgement.settings import HealthSettings



def unexplained_densities(matrix: NDArray[np.complex128], bands_hz: Sequence[float]) -> NDArray[np.float64]:
    """(n_bands, 3): per band and channel, the power spectral density of the part of the channel
    the other two cannot explain (1 / (S^-1)_cc, the Schur complement, over the band's width), in
    (m/s^2)^2/Hz; NaN in a band without power on every channel (beyond Nyquist, a dead channel).

    matrix: the window's (n_bands, 3, 3) band cross-spectra; bands_hz: their n_bands + 1 edges.
    """
    widths = np.diff(np.asarray(bands_hz, dtype=np.float64))
    out = np.full((len(widths), 3), np.nan)
    for b, (s, width) in enumerate(zip(matrix, widths, strict=True)):
        power = np.real(np.diagonal(s))
        if not np.all(power > 0):
            continue
        with np.errstate(all="ignore"):
            try:
                unexplained = 1.0 / np.real(np.diagonal(np.linalg.inv(s)))
            except np.linalg.LinAlgError:
                unexplained = power  # two channels alike in the band: nothing to tell apart there
        out[b] = np.where(np.isfinite(unexplained) & (unexplained > 0), np.minimum(unexplained, power), power) / width
    return out


def top_octave(bands_hz: Sequence[float], present: NDArray[np.bool_]) -> NDArray[np.intp]:
    """The bands of the top octave below Nyquist: of the bands present (with power), those whose
    lower edge lies at or above half the upper edge of the highest one (at 500 Hz 128-181 and
    181-250 Hz; at a lower rate, or in records of the judged bands only, the octave below theirs)."""
    index = np.flatnonzero(present)
    if index.size == 0:
        return index
    edges = np.asarray(bands_hz, dtype=np.float64)
    return index[edges[index] >= edges[index[-1] + 1] / 2.0]


def ratios_to_others(densities: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each channel's density over the geometric mean of the other two channels' in the same band
    (the last axis is the channel): a common rise leaves it, noise of one sensor raises that one's."""
    log = np.log(np.maximum(densities, np.finfo(float).tiny))
    return np.exp(log - (log.sum(axis=-1, keepdims=True) - log) / 2.0)


@dataclass(frozen=True)
class TopOctave:
    """A window's noise floor: per band of its top octave and channel, the unexplained density,
    (m/s^2)^2/Hz, and its ratio to the other two channels' in that band."""

    bands: tuple[int, ...]  # indices into the window's bands
    density: NDArray[np.float64]  # (len(bands), 3)
    ratio: NDArray[np.float64]  # (len(bands), 3)


def floor_bands(matrix: NDArray[np.complex128], bands_hz: Sequence[float]) -> TopOctave | None:
    """The top octave's densities and ratios of a window's band cross-spectra; None when no band has
    power on every channel."""
    densities = unexplained_densities(matrix, bands_hz)
    bands = top_octave(bands_hz, ~np.isnan(densities[:, 0]))
    if bands.size == 0:
        return None
    density = densities[bands]
    return TopOctave(tuple(int(b) for b in bands), density, ratios_to_others(density))


def floor_excess(window: WindowIndicators, settings: HealthSettings) -> NDArray[np.float64] | None:
    """Per channel, how far its noise floor lies above what commissioning saw of it: over the bands
    of the top octave, the largest factor by which both its density exceeds the smallest density and
    its ratio to the other two the largest ratio learned (module docstring); a channel is noisy above
    noise_floor_margin. None when the check is not in force or the window has no floor."""
    if not settings.noise_floor_psd or window.spectra is None:
        return None
    floor = floor_bands(window.spectra.matrix, window.spectra.bands_hz)
    if floor is None:
        return None
    excess = np.minimum(floor.density / np.asarray(settings.noise_floor_psd), floor.ratio / np.asarray(settings.noise_floor_ratio))
    return excess.max(axis=0)


def floor_noisy_channels(window: WindowIndicators, settings: HealthSettings) -> list[int]:
    """The channels whose density and ratio in some band of the top octave both lie
    noise_floor_margin times above the smallest density and the largest ratio commissioning saw of
    them there (module docstring); [] when not in force."""
    excess = floor_excess(window, settings)
    if excess is None:
        return []
    return [c for c in range(3) if excess[c] > settings.noise_floor_margin]


@dataclass(frozen=True)
class NoiseFloorFit:
    """What a wagon's healthy windows showed of its sensors' noise floors in the top octave: per
    channel the smallest density, (m/s^2)^2/Hz, and the largest ratio of it to the other two
    channels' in the same band."""

    psd: tuple[float, float, float]
    ratio: tuple[float, float, float]
    windows: int

    def health_fields(self) -> dict[str, Any]:
        """The [health] fields that put this check in force (for the calibration fragment)."""
        return {"noise_floor_psd": [float(f"{v:.4g}") for v in self.psd], "noise_floor_ratio": [round(v, 4) for v in self.ratio]}


def _fit(psd: NDArray[np.float64], ratio: NDArray[np.float64], windows: int) -> NoiseFloorFit:
    return NoiseFloorFit((float(psd[0]), float(psd[1]), float(psd[2])), (float(ratio[0]), float(ratio[1]), float(ratio[2])), windows)


def learn_noise_floor(windows: Iterable[WindowIndicators]) -> NoiseFloorFit | None:
    """The noise floors of a wagon's healthy windows (the judgeable windows of its commissioning
    runs, sensors sound): over every window and band of the top octave; None without a window that
    has one."""
    floors = [f for w in windows if w.spectra is not None and (f := floor_bands(w.spectra.matrix, w.spectra.bands_hz)) is not None]
    if not floors:
        return None
    psd = np.min([f.density.min(axis=0) for f in floors], axis=0)
    ratio = np.max([f.ratio.max(axis=0) for f in floors], axis=0)
    return _fit(psd, ratio, len(floors))


def merge_noise_floors(fits: Sequence[NoiseFloorFit | None]) -> NoiseFloorFit | None:
    """One fit from several commissioning sets (each load state's): what learn_noise_floor gives on
    their windows together (the smallest density, the largest ratio)."""
    present = [f for f in fits if f is not None]
    if not present:
        return None
    return _fit(np.min([f.psd for f in present], axis=0), np.max([f.ratio for f in present], axis=0), sum(f.windows for f in present))
