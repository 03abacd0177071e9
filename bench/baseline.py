"""The naive baseline the streaming core is measured against: every window correlated from scratch.

It conditions the signals exactly as the core does, then at every hop runs scipy.signal.correlate
(FFT method) over the whole window for C_BR and C_PR: what a straightforward implementation does.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from bogiemon.detection import BogieGeometry, ProcessingSettings, to_modal
from bogiemon.detection.reference import condition_reference


def naive_indicators(
    accel_mps2: NDArray[np.float64], settings: ProcessingSettings, geometry: BogieGeometry
) -> NDArray[np.float64]:
    """(n_windows, 4) raw indicators I1..I4, recomputing each window's full correlation."""
    high, low = condition_reference(accel_mps2, settings)
    modal, modal_low = to_modal(high, geometry), to_modal(low, geometry)
    n, k = settings.window_n, settings.max_lag_n
    rows = []
    for s in range(0, high.shape[0] - n + 1, settings.hop_n):
        b, p, r = modal[s : s + n].T
        c_br = signal.correlate(b, r, mode="full", method="fft")[n - 1 - k : n + k] / n
        c_pr = signal.correlate(p, r, mode="full", method="fft")[n - 1 - k : n + k] / n
        i3 = np.dot(modal_low[s : s + n, 1], modal_low[s : s + n, 2]) / n
        rows.append((np.std(c_br), np.std(c_pr), i3, c_pr[k]))
    return np.array(rows)
