"""From the kernel's accelerations to what an accelerometer delivers: anti-aliasing, decimation, errors.

The kernel writes the specific force at the sensors at the integration rate (gravity included:
a sensor at rest reads +g). A Chebyshev type II low-pass (order 10, 80 dB from the output's
Nyquist frequency up) runs at that rate and every `factor`-th sample is kept, so nothing above
the output's Nyquist frequency folds back. Its passband is flat to 0.01 dB up to
0.2 fs (100 Hz at 500 Hz), -0.4 dB at 0.3 fs, with a group delay of about 4.7 ms at low frequency. The
same filter runs on the three channels, so its phase cancels in every cross-correlation. Then the sensor's own errors are
added: a gain per channel (a calibration error; -1 is a sensor mounted upside down), a constant
bias per channel, white noise, and quantisation to a step (LSB).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

ANTI_ALIAS_ORDER = 10
ANTI_ALIAS_STOPBAND_DB = 80.0


def anti_alias_sos(fs_in_hz: float, fs_out_hz: float) -> NDArray[np.float64]:
    """Second-order sections of the decimation filter: stopband from fs_out / 2."""
    return signal.cheby2(ANTI_ALIAS_ORDER, ANTI_ALIAS_STOPBAND_DB, fs_out_hz / 2, fs=fs_in_hz, output="sos")


class Decimator:
    """Anti-aliasing low-pass and decimation by an integer factor, block by block (sample axis 0).

    The reference of what the kernel does inside its time loop (kernel.advance, tested against it).

    Blocks must hold whole multiples of `factor` samples; the first sample of every block is
    kept, so samples 0, factor, 2 factor, ... of the whole stream come out. The filter starts
    in steady state for the first sample (no transient from gravity).
    """

    def __init__(self, fs_in_hz: float, factor: int, n_channels: int) -> None:
        if factor < 1:
            raise ValueError(f"decimation factor must be >= 1, got {factor}")
        self.factor = factor
        self._sos = anti_alias_sos(fs_in_hz, fs_in_hz / factor) if factor > 1 else None
        self._n_channels = n_channels
        self._zi: NDArray[np.float64] | None = None

    def process(self, block: NDArray[np.float64]) -> NDArray[np.float64]:
        x = np.asarray(block, dtype=np.float64)
        if x.shape[0] % self.factor:
            raise ValueError(f"block of {x.shape[0]} samples is not a multiple of {self.factor}")
        if self._sos is None:
            return x.copy()
        if self._zi is None:
            self._zi = signal.sosfilt_zi(self._sos)[:, :, None] * x[0][None, None, :]
        y, self._zi = signal.sosfilt(self._sos, x, axis=0, zi=self._zi)
        return y[:: self.factor]


@dataclass(frozen=True)
class SensorModel:
    """Errors of the accelerometers. m/s^2; zero everywhere is an ideal sensor."""

    noise_mps2: float = 0.0  # standard deviation of white noise per output sample
    bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)  # constant offset per channel
    quantum_mps2: float = 0.0  # quantisation step (LSB); 0 for none
    # Sensitivity per channel relative to nominal (1.0: exact); it scales gravity too.
    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)

    def apply(self, accel_mps2: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
        """(n, 3) ideal specific force in, (n, 3) as the sensors report it out."""
        out = accel_mps2 if self.gain == (1.0, 1.0, 1.0) else accel_mps2 * np.asarray(self.gain)
        out = out + np.asarray(self.bias_mps2)
        if self.noise_mps2 > 0:
            out = out + self.noise_mps2 * rng.standard_normal(out.shape)
        if self.quantum_mps2 > 0:
            out = self.quantum_mps2 * np.round(out / self.quantum_mps2)
        return out
