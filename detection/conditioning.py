"""Signal conditioning: gravity/drift removal and the 10 Hz low-pass of indicator 3, streaming.

Why a high-pass rather than subtracting each window's mean: the mean of a 60 s window still
carries sensor drift and the slow part of the gravity projection, and it is not a streaming
operation (each window would need its own offset, so block products could not be shared between
overlapping windows). A causal 2nd-order Butterworth high-pass at 0.5 Hz removes the 9.81 m/s^2
offset and any drift slower than a few seconds, and passes the bogie frame's content (carbody
modes from ~1.5 Hz, primary suspension and wheelset modes from ~5 Hz up) within 3 % at 1 Hz.
The same filter runs on every channel, so in every cross-spectrum its phase cancels and only
|H(f)|^2 weights the correlations: no lag error is introduced. The filter's state starts at
steady state for the first sample, so the gravity step at start-up causes no transient.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal


def butter_sos(order: int, cutoff_hz: float, fs_hz: float, btype: str) -> NDArray[np.float64]:
    """Second-order sections of a digital Butterworth filter ('lowpass' or 'highpass')."""
    nyquist_hz = fs_hz / 2.0
    if not 0.0 < cutoff_hz < nyquist_hz:
        raise ValueError(f"cutoff {cutoff_hz} Hz must lie between 0 and Nyquist ({nyquist_hz} Hz)")
    if order < 1:
        raise ValueError(f"filter order must be >= 1, got {order}")
    return signal.butter(order, cutoff_hz, btype=btype, fs=fs_hz, output="sos")


class StreamingSOS:
    """A causal SOS filter over (n, channels) blocks whose state carries from block to block.

    Filtering a signal block by block gives the same samples as filtering it in one call; the
    sample axis is 0. With ``start_at_steady_state`` the state is initialised, on the first
    sample after construction or reset(), as if that sample had been applied forever (this is
    what removes the gravity step for a high-pass).
    """

    def __init__(self, sos: NDArray[np.float64], n_channels: int, start_at_steady_state: bool) -> None:
        self._sos = np.asarray(sos, dtype=np.float64)
        self._n_channels = n_channels
        self._start_at_steady_state = start_at_steady_state
        self._zi_unit = signal.sosfilt_zi(self._sos)  # (n_sections, 2) for a unit step
        self._zi: NDArray[np.float64] | None = None

    def reset(self) -> None:
        """Forget the state: the next sample starts a new, independent signal."""
        self._zi = None

    def process(self, block: NDArray[np.float64]) -> NDArray[np.float64]:
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self._n_channels:
            raise ValueError(f"expected an (n, {self._n_channels}) block, got shape {x.shape}")
        if x.shape[0] == 0:
            return x.copy()
        if self._zi is None:
            # zi has shape (n_sections, 2, n_channels) for filtering along axis 0.
            if self._start_at_steady_state:
                self._zi = self._zi_unit[:, :, None] * x[0][None, None, :]
            else:
                self._zi = np.zeros((self._sos.shape[0], 2, self._n_channels))
        y, self._zi = signal.sosfilt(self._sos, x, axis=0, zi=self._zi)
        return y
