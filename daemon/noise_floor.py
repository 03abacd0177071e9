"""A sensor's noise floor, learned from the wagon at commissioning (daemon/health.py's module
docstring says why it names a noisy sensor): per channel the smallest density, over every band up
to Nyquist, of what the other two channels cannot explain, and its ratio to theirs.

    fit = learn_noise_floor(commissioning_windows)      # -> the [health] fields of the fragment
    noisy = floor_noisy_channels(window, settings)      # the channels noisy in this window
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import WindowIndicators

if TYPE_CHECKING:  # health.py imports this module: the settings are only a type here
    from bogiemon.daemon.health import HealthSettings



def noise_floors(matrix: NDArray[np.complex128], bands_hz: Sequence[float]) -> NDArray[np.float64] | None:
    """Per channel, its noise floor: over every band, the smallest power spectral density of the
    part of the channel the other two cannot explain (1 / (S^-1)_cc, the Schur complement), in
    (m/s^2)^2/Hz. White noise of density n on a channel adds exactly n x the band's width to that
    part in every band (the other channels' cross-spectra do not change), so its floor is at least
    n; a healthy channel's floor is where the frame and its sensor give least. Bands without power
    on every channel (beyond Nyquist, a dead channel) are skipped; None when no band is left.

    matrix: the window's (n_bands, 3, 3) band cross-spectra; bands_hz: their n_bands + 1 edges.
    """
    widths = np.diff(np.asarray(bands_hz, dtype=np.float64))
    floors = np.full(3, np.inf)
    for s, width in zip(matrix, widths, strict=True):
        power = np.real(np.diagonal(s))
        if not np.all(power > 0):
            continue
        with np.errstate(all="ignore"):
            try:
                unexplained = 1.0 / np.real(np.diagonal(np.linalg.inv(s)))
            except np.linalg.LinAlgError:
                unexplained = power  # two channels alike in the band: nothing to tell apart there
        unexplained = np.where(np.isfinite(unexplained) & (unexplained > 0), np.minimum(unexplained, power), power)
        floors = np.minimum(floors, unexplained / width)
    return floors if bool(np.all(np.isfinite(floors))) else None


def floor_ratios(floors: NDArray[np.float64]) -> NDArray[np.float64]:
    """Each channel's floor over the geometric mean of the other two channels' floors: a common rise
    (rough track, high speed) leaves it, noise of one sensor raises that sensor's alone."""
    log = np.log(np.maximum(floors, np.finfo(float).tiny))
    return np.exp(log - (log.sum() - log) / 2.0)


def floor_noisy_channels(window: WindowIndicators, settings: HealthSettings) -> list[int]:
    """The channels whose noise floor lies noise_floor_margin times above both the smallest floor
    commissioning saw of it and the largest ratio to the other two (module docstring); [] when not
    in force."""
    if not settings.noise_floor_psd or window.spectra is None:
        return []
    floors = noise_floors(window.spectra.matrix, window.spectra.bands_hz)
    if floors is None:
        return []
    ratios = floor_ratios(floors)
    margin = settings.noise_floor_margin
    return [
        c for c in range(3)
        if floors[c] > margin * settings.noise_floor_psd[c] and ratios[c] > margin * settings.noise_floor_ratio[c]
    ]  # fmt: skip


@dataclass(frozen=True)
class NoiseFloorFit:
    """What a wagon's healthy windows showed of its sensors' noise floors: per channel the smallest
    floor, (m/s^2)^2/Hz, and the largest ratio of it to the other two channels'."""

    psd: tuple[float, float, float]
    ratio: tuple[float, float, float]
    windows: int

    def health_fields(self) -> dict[str, Any]:
        """The [health] fields that put this check in force (for the calibration fragment)."""
        return {"noise_floor_psd": [float(f"{v:.4g}") for v in self.psd], "noise_floor_ratio": [round(v, 4) for v in self.ratio]}


def learn_noise_floor(windows: Iterable[WindowIndicators]) -> NoiseFloorFit | None:
    """The noise floors of a wagon's healthy windows (the judgeable windows of its commissioning
    runs, sensors sound); None without a window that has one."""
    rows = []
    for window in windows:
        if window.spectra is None:
            continue
        floors = noise_floors(window.spectra.matrix, window.spectra.bands_hz)
        if floors is not None:
            rows.append((floors, floor_ratios(floors)))
    if not rows:
        return None
    psd = np.min([f for f, _ in rows], axis=0)
    ratio = np.max([r for _, r in rows], axis=0)
    return NoiseFloorFit((float(psd[0]), float(psd[1]), float(psd[2])), (float(ratio[0]), float(ratio[1]), float(ratio[2])), len(rows))


def merge_noise_floors(fits: Sequence[NoiseFloorFit | None]) -> NoiseFloorFit | None:
    """One fit from several commissioning sets (each load state's): what learn_noise_floor gives on
    their windows together (the smallest floor, the largest ratio)."""
    present = [f for f in fits if f is not None]
    if not present:
        return None
    psd = np.min([f.psd for f in present], axis=0)
    ratio = np.max([f.ratio for f in present], axis=0)
    return NoiseFloorFit((float(psd[0]), float(psd[1]), float(psd[2])), (float(ratio[0]), float(ratio[1]), float(ratio[2])), sum(f.windows for f in present))
