"""Each window pair's features, as arrays the sister study and the fitting read (issue 33).

FEATURES: judgement/sister.py's VOCABULARY: the fused score's couplings (detection/features.py
COUPLING_NAMES: pitch-roll and bounce-roll coherency, 2-64 Hz in octaves), the load state's log
band-power shares of each mode (LOAD_NAMES), the log amplitudes (log I1, log I2, log RMS of
bounce, pitch and roll) and the paper's indicators I1..I4, raw and normalised.
A `Table` holds, for every aligned window pair of some runs, both bogies' features and what the
run was (its wagon, load, the faulty bogie and whether the fault was present in the window).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import WindowFeatures
from bogiemon.judgement.sister import VOCABULARY
from bogiemon.judgement.sister import feature_vector as sister_vector
from bogiemon.lab.sister.plan import PairRun, aligned

FEATURES: tuple[str, ...] = VOCABULARY


def feature_vector(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64]:
    """FEATURES of one window (NaN throughout where one is not finite: a mode without power)."""
    features = WindowFeatures(window.spectra, geometry) if window.spectra is not None else None
    found = sister_vector(window, features, FEATURES)
    return found if found is not None else np.full(len(FEATURES), np.nan)


@dataclass(frozen=True)
class Table:
    """Window pairs of some runs: x (n, 2, F) each bogie's FEATURES (the wagon's bogie 1, 2);
    per pair its run's index in `runs`, wagon, load, faulty bogie (0: healthy run) and whether the
    window holds the fault (it ends after the onset: a window straddling it is faulty in part)."""

    runs: tuple[PairRun, ...]
    x: NDArray[np.float64]
    run: NDArray[np.int64]
    wagon: NDArray[np.int64]
    load: NDArray[np.str_]
    bogie: NDArray[np.int64]
    faulty: NDArray[np.bool_]
    end_s: NDArray[np.float64]  # each window's end, s from its run's start

    @property
    def d(self) -> NDArray[np.float64]:
        """Bogie 2's features minus bogie 1's."""
        return self.x[:, 1] - self.x[:, 0]

    def where(self, mask: NDArray[np.bool_]) -> Table:
        return Table(self.runs, self.x[mask], self.run[mask], self.wagon[mask], self.load[mask], self.bogie[mask], self.faulty[mask], self.end_s[mask])


def table_of(runs: Sequence[PairRun], geometry: BogieGeometry) -> Table:
    rows: list[NDArray[np.float64]] = []
    index, wagon, load, bogie, faulty, end = [], [], [], [], [], []
    for i, pair in enumerate(runs):
        r = pair.run
        for w1, w2 in aligned(pair):
            rows.append(np.stack([feature_vector(w1, geometry), feature_vector(w2, geometry)]))
            index.append(i)
            wagon.append(r.wagon)
            load.append(r.load)
            bogie.append(r.bogie)
            faulty.append(r.bogie > 0 and w1.end_s > r.onset_s)
            end.append(w1.end_s)
    x = np.array(rows) if rows else np.empty((0, 2, len(FEATURES)))
    return Table(
        tuple(runs), x, np.array(index, dtype=np.int64), np.array(wagon, dtype=np.int64), np.array(load, dtype=np.str_),
        np.array(bogie, dtype=np.int64), np.array(faulty, dtype=np.bool_), np.array(end, dtype=np.float64),
    )  # fmt: skip
