"""The sensors' structure: does the data have the rigid frame's structure the configured corners
imply, and which assignment of the channels to the corners (with signs) fits it if not.

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
import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import LayoutStatistics, layout_statistics
from bogiemon.judgement.settings import LAYOUT_CHECKS, HealthSettings


# The structure checks of layout_margin, by the names the config uses.


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


@dataclass(frozen=True)
class LayoutFit:
    """Where the channels' data fit, when not where the config puts them: channel perm[i] is at the
    configured corner i, with sign signs[i]."""

    perm: tuple[int, ...]
    signs: tuple[float, ...]

    def moved(self) -> list[int]:
        """The channels at another corner than configured."""
        return [channel for corner, channel in enumerate(self.perm) if channel != corner]

    def flipped(self) -> list[int]:
        """The channels whose sign is flipped."""
        return [channel for channel, sign in zip(self.perm, self.signs, strict=True) if sign < 0]


def layout_fit(matrix: NDArray[np.complex128], geometry: BogieGeometry, settings: HealthSettings) -> LayoutFit | None:
    """The assignment the data fit when the configured one fails a check in force; None when the
    configured layout fits (or no check is in force, or no other assignment passes them all).

    matrix: the window's (n_bands, 3, 3) band cross-spectra. Of assignments the checks cannot tell
    apart, the one that changes the fewest channels.
    """
    if not settings.layout_checks:
        return None
    if layout_margin(layout_statistics(matrix, geometry), settings) >= 0:
        return None
    passing = []
    for perm, signs in _HYPOTHESES:
        if perm == (0, 1, 2) and signs == (1.0, 1.0, 1.0):
            continue
        margin = layout_margin(layout_statistics(matrix, geometry, perm, signs), settings)
        if margin > 0:
            passing.append((margin, perm, signs))
    if not passing:
        return None
    best_margin = max(m for m, _, _ in passing)
    _, perm, signs = min((p for p in passing if p[0] >= best_margin - _TIE), key=lambda p: _changes(p[1], p[2]))
    if sum(s < 0 for s in signs) > 1:  # the same structure with every sign flipped: fewer inverted
        signs = tuple(-s for s in signs)
    return LayoutFit(perm, signs)


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
        for check, value in layout_check_values(layout_statistics(window.spectra.matrix, geometry)).items():
            values[check].append(value)
    return structure_of({c: float(np.min(v)) if v else float("nan") for c, v in values.items()}, n)


