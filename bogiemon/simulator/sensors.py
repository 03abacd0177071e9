"""From the kernel's accelerations to what an accelerometer delivers: anti-aliasing, decimation, errors.

The kernel writes the specific force at the sensors at the integration rate (gravity included:
a sensor at rest reads +g). A Chebyshev type II low-pass (order 10, 80 dB from the output's
Nyquist frequency up) runs at that rate and every `factor`-th sample is kept, so nothing above
the output's Nyquist frequency folds back. Its passband is flat to 0.01 dB up to
0.2 fs (100 Hz at 500 Hz), -0.4 dB at 0.3 fs, with a group delay of about 4.7 ms at low frequency. The
same filter runs on the three channels, so its phase cancels in every cross-correlation. Then the sensor's own errors are
added: a gain per channel (a calibration error; -1 is a sensor mounted upside down), a constant
bias per channel, white noise, and quantisation to a step (LSB).

SENSOR VARIANTS (SENSOR_VARIANTS: the part that reads the frame, chosen per scenario). A part has
a Butterworth low-pass of its own at a fraction of the output rate (a MEMS part's digital filter
runs at its output data rate, ODR, with its corner anywhere from ODR/2 down to ODR/800; an analog
part's output stage is a two-pole filter) and puts its white noise before that filter (the sensing
element and front end feed it: the noise is shaped like the signal) or after it (the converter's or
the cable's: white up to Nyquist). On model A (SensorModel.variant) the filter above stands for an
ideal converter and the part's filter runs after it, at the output rate; "standard" has no filter
of its own and its noise after: model A's sensor as it always was, bit for bit. On model B the part
is the parameter set's [sensor] (simulator/model_b/parameters.py with_sensor_variant): its filter
becomes B's own anti-alias filter in the kernel. The element noise (SensorModel.element_noise_mps2,
per channel: a failing element) always enters before the part's filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

# scipy.signal (0.9 s to import) where a filter is designed or run: `bogiemon simulate` checks its
# arguments, building the scenario, without it.

ANTI_ALIAS_ORDER = 10
ANTI_ALIAS_STOPBAND_DB = 80.0


def anti_alias_sos(fs_in_hz: float, fs_out_hz: float) -> NDArray[np.float64]:
    """Second-order sections of the decimation filter: stopband from fs_out / 2."""
    from scipy import signal

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
        from scipy import signal

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
class SensorVariant:
    """An accelerometer part after the ideal converter (module docstring): its own low-pass and
    where its white noise enters."""

    description: str
    order: int = 0  # of its Butterworth low-pass; 0: no filter of its own
    corner_fraction_of_fs: float = 0.25  # the low-pass's -3 dB corner over the output rate
    noise_inside: bool = False  # its noise enters before its filter (True) or after it

    def __post_init__(self) -> None:
        if self.order < 0 or not 0.0 < self.corner_fraction_of_fs < 0.5:
            raise ValueError(f"a sensor variant's order is >= 0 and its corner inside (0, 0.5) of the rate, got {self.order}, {self.corner_fraction_of_fs}")

    def sos(self) -> NDArray[np.float64] | None:
        """Its low-pass at the output rate (frequencies as fractions of it), None without one."""
        from scipy import signal

        if self.order == 0:
            return None
        return signal.butter(self.order, 2.0 * self.corner_fraction_of_fs, output="sos")

    def response(self, f_over_fs: NDArray[np.float64]) -> NDArray[np.complex128]:
        """Its filter's complex response at frequencies given as fractions of the output rate."""
        from scipy import signal

        sos = self.sos()
        f = np.asarray(f_over_fs, dtype=np.float64)
        if sos is None:
            return np.ones(f.shape, dtype=np.complex128)
        return signal.sosfreqz(sos, worN=f, fs=1.0)[1]


SENSOR_VARIANTS: dict[str, SensorVariant] = {
    "standard": SensorVariant("the model's own sensor: model A's converter (its anti-alias filter, the noise after it), model B's MEMS"),
    "mems-odr10": SensorVariant(
        "a MEMS part with its digital low-pass at ODR/10 (4th-order Butterworth, 50 Hz at 500 Hz), its noise inside: "
        "above 100 Hz it gives next to nothing, of the frame or of its noise",
        order=4, corner_fraction_of_fs=0.1, noise_inside=True,
    ),  # fmt: skip
    "two-pole": SensorVariant(
        "an analog part with a two-pole output filter (2nd-order Butterworth) at ODR/4, its noise after it "
        "(the converter's and the cable's)",
        order=2, corner_fraction_of_fs=0.25, noise_inside=False,
    ),  # fmt: skip
    "wideband": SensorVariant(
        "a MEMS part with its digital low-pass at 0.45 ODR (4th-order Butterworth), its noise inside: on model B the "
        "frame's own vibration, and what folds back from above Nyquist, fills the top bands",
        order=4, corner_fraction_of_fs=0.45, noise_inside=True,
    ),  # fmt: skip
}


@dataclass(frozen=True)
class SensorModel:
    """Errors of the accelerometers. m/s^2; zero everywhere is an ideal sensor."""

    noise_mps2: float = 0.0  # standard deviation of white noise per output sample
    bias_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)  # constant offset per channel
    quantum_mps2: float = 0.0  # quantisation step (LSB); 0 for none
    # Sensitivity per channel relative to nominal (1.0: exact); it scales gravity too.
    gain: tuple[float, float, float] = (1.0, 1.0, 1.0)
    # The part (SENSOR_VARIANTS): its own filter and where noise_mps2 enters.
    variant: str = "standard"
    # White noise of each channel's sensing element (a failing one), before the variant's filter:
    # in its passband the density of white noise of this standard deviation per output sample.
    element_noise_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def part(self) -> SensorVariant:
        try:
            return SENSOR_VARIANTS[self.variant]
        except KeyError:
            raise ValueError(f"unknown sensor variant '{self.variant}': use one of {', '.join(SENSOR_VARIANTS)}") from None

    def apply(self, accel_mps2: NDArray[np.float64], rng: np.random.Generator) -> NDArray[np.float64]:
        """(n, 3) ideal specific force in, (n, 3) as the sensors report it out."""
        from scipy import signal

        out = accel_mps2 if self.gain == (1.0, 1.0, 1.0) else accel_mps2 * np.asarray(self.gain)
        out = out + np.asarray(self.bias_mps2)
        sos = self.part.sos()
        if sos is None and self.noise_mps2 > 0:  # the standard part: its draws as they always were
            out = out + self.noise_mps2 * rng.standard_normal(out.shape)
        if sos is not None:
            inside = np.zeros(out.shape)
            if self.noise_mps2 > 0 and self.part.noise_inside:
                inside += self.noise_mps2 * rng.standard_normal(out.shape)
            if any(self.element_noise_mps2):
                inside += np.asarray(self.element_noise_mps2) * rng.standard_normal(out.shape)
            # The filter starts in steady state at the first sample (the wagon's +g, no transient).
            zi = signal.sosfilt_zi(sos)[:, :, None] * out[0][None, None, :]
            out = signal.sosfilt(sos, out + inside, axis=0, zi=zi)[0]
            if self.noise_mps2 > 0 and not self.part.noise_inside:
                out = out + self.noise_mps2 * rng.standard_normal(out.shape)
        elif any(self.element_noise_mps2):
            out = out + np.asarray(self.element_noise_mps2) * rng.standard_normal(out.shape)
        if self.quantum_mps2 > 0:
            out = self.quantum_mps2 * np.round(out / self.quantum_mps2)
        return out
