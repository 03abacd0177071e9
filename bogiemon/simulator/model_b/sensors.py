"""Model B's accelerometers: a MEMS-like sensor from the frame's specific force to converter codes.

In the kernel, at the integration rate, for each channel (a reference of the same chain is
`SensorChain`, tested against the kernel):
  1. the vertical specific force at the sensor's corner of the rigid frame (gravity included) plus
     the cross-axis sensitivity times the frame's lateral acceleration (`lateral_acceleration`:
     not a degree of freedom of the vertical model, synthesised: a hunting-like narrow band at
     speed / wavelength and a broad-band part, both growing with speed);
  2. the channel's sample skew, a fractional delay (linear interpolation on a short delay line);
  3. the mounting/sensor resonance, a lightly damped second-order low-pass (bilinear transform,
     prewarped at the resonance; it lifts the response by (f / f_n)^2 below the resonance);
  4. the sensor's digital anti-alias filter, a Butterworth (4th order as shipped) at a fraction of
     the output rate (MEMS output filters sit at ODR/4 to ODR/2, so some aliasing remains, as in real
     parts), and decimation to the output rate.
After the kernel, at the output rate (`convert`): the channel's gain and zero-g bias, a 1/f-like
bias drift (four Ornstein-Uhlenbeck processes a decade apart, which approximate flicker noise,
plus a random walk), white noise of the given density shaped by the same anti-alias response (or,
with noise_inside false, white after it), a failing element's white noise per channel (shaped
by the filter: inside), clipping at the range and quantisation to the converter's step.
Another sensor part (simulator/sensors.py SENSOR_VARIANTS) is the parameter set's [sensor] with
its filter and noise entry: parameters.with_sensor_variant.
Model A's sensor is a Chebyshev anti-alias with gain, constant bias, white noise and quantisation.

BOGIE 2 (a run recording both bogies): its three sensors are other parts of the same type, so
every per-channel error of the part is drawn anew (`other_part`), within the tolerances its
[sensor] section states for the first three (gain +/-1 %, zero-g bias +/-25 mg, cross-axis
sensitivity and mounting +/-3 %, sample instants 0 to 0.1 ms after its first channel), and its
noise, drift and lateral acceleration (the other bogie's hunting) are drawn apart too. A parameter
set's [sensor_bogie_2] table, where given, states any of those per-channel values instead.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b.parameters import MAX_ANTIALIAS_ORDER, SensorParameters

if TYPE_CHECKING:
    from bogiemon.simulator.scenario import SpeedProfile

FloatArray = NDArray[np.float64]
STANDARD_GRAVITY_MPS2 = 9.80665  # the unit of a sensor's range in g
DELAY_LINE = 16  # samples kept per channel for the skew (a power of two: the kernel masks the index)
N_SECTIONS = 1 + (MAX_ANTIALIAS_ORDER + 1) // 2  # the resonance, then the Butterworth's, identity sections after a lower order
REFERENCE_SPEED_MPS = 100.0 / 3.6
DRIFT_TIME_CONSTANTS_S = (0.3, 3.0, 30.0, 300.0)
LATERAL_BAND_HZ = (0.5, 20.0)
IDENTITY_SECTION = np.array([1.0, 0.0, 0.0, 1.0, 0.0, 0.0])
# Another part of the same type (module docstring, BOGIE 2): uniform half-widths of its errors.
OTHER_PART_GAIN = 0.01
OTHER_PART_BIAS_MPS2 = 0.25
OTHER_PART_CROSS_AXIS = 0.03
OTHER_PART_SKEW_S = 1.0e-4
# What a parameter set's [sensor_bogie_2] may state (each three values, b1..b3).
OTHER_PART_KEYS = ("gain", "bias_mps2", "cross_axis", "skew_s", "noise_density_mps2_per_sqrt_hz", "element_noise_density_mps2_per_sqrt_hz")


def other_part(sensor: SensorParameters, rng: np.random.Generator, given: Mapping[str, Any] | None = None) -> SensorParameters:
    """Bogie 2's sensors: the part type of `sensor` with every per-channel error drawn anew
    (module docstring), then whatever `given` (a [sensor_bogie_2] table) states instead."""
    def triple(values: Any) -> tuple[float, float, float]:
        a, b, c = (float(x) for x in values)
        return (a, b, c)

    skew = rng.uniform(0.0, OTHER_PART_SKEW_S, 3)
    skew[0] = 0.0  # instants relative to the bus's first channel
    drawn: dict[str, Any] = {
        "gain": triple(1.0 + rng.uniform(-OTHER_PART_GAIN, OTHER_PART_GAIN, 3)),
        "bias_mps2": triple(rng.uniform(-OTHER_PART_BIAS_MPS2, OTHER_PART_BIAS_MPS2, 3)),
        "cross_axis": triple(rng.uniform(-OTHER_PART_CROSS_AXIS, OTHER_PART_CROSS_AXIS, 3)),
        "skew_s": triple(skew),
    }
    for key, value in (given or {}).items():
        if key not in OTHER_PART_KEYS:
            raise SimulationError(f"model B [sensor_bogie_2]: unknown key '{key}': use {', '.join(OTHER_PART_KEYS)}")
        drawn[key] = float(value) if key == "noise_density_mps2_per_sqrt_hz" else triple(value)
    return dataclasses.replace(sensor, **drawn)


def resonance_section(resonance_hz: float, damping_ratio: float, rate_hz: float) -> FloatArray:
    """One second-order section: omega^2 / (s^2 + 2 zeta omega s + omega^2) at the step rate (unit DC gain)."""
    if resonance_hz <= 0.0:
        return IDENTITY_SECTION.copy()
    omega = 2.0 * rate_hz * math.tan(math.pi * resonance_hz / rate_hz)  # prewarped
    b, a = signal.bilinear([omega**2], [1.0, 2.0 * damping_ratio * omega, omega**2], fs=rate_hz)
    return np.concatenate([b / a[0], a / a[0]])


def chain_sos(sensor: SensorParameters, rate_hz: float, fs_out_hz: float) -> FloatArray:
    """(N_SECTIONS, 6) sections of the in-kernel chain: resonance, then the anti-alias Butterworth
    (identity sections after a lower order, so that every scenario of a batch has as many)."""
    butter = signal.butter(sensor.antialias_order, sensor.antialias_fraction_of_fs * fs_out_hz, fs=rate_hz, output="sos")
    pad = np.tile(IDENTITY_SECTION, (N_SECTIONS - 1 - butter.shape[0], 1))
    return np.vstack([resonance_section(sensor.resonance_hz, sensor.resonance_damping_ratio, rate_hz)[None, :], butter, pad])


def output_sos(sensor: SensorParameters, fs_out_hz: float) -> FloatArray:
    """The anti-alias response at the output rate (it shapes the white noise inside the sensor)."""
    return signal.butter(sensor.antialias_order, sensor.antialias_fraction_of_fs * fs_out_hz, fs=fs_out_hz, output="sos")


def skew_steps(sensor: SensorParameters, step_s: float) -> FloatArray:
    return np.array(sensor.skew_s) / step_s


class SensorChain:
    """Reference of the kernel's per-channel chain (steps 1-4 of the module docstring), block by block.

    Input: (n, 3) specific force at the step rate (with gravity) and (n,) lateral acceleration;
    output: every `factor`-th filtered sample. Starts in steady state at `start_mps2`.
    """

    def __init__(self, sensor: SensorParameters, rate_hz: float, fs_out_hz: float, factor: int, start_mps2: float) -> None:
        self.factor = factor
        self._sos = chain_sos(sensor, rate_hz, fs_out_hz)
        self._cross = np.array(sensor.cross_axis)
        self._skew = skew_steps(sensor, 1.0 / rate_hz)
        self._history = np.full((DELAY_LINE, 3), start_mps2)
        self._zi = signal.sosfilt_zi(self._sos)[:, :, None] * np.full(3, start_mps2)[None, None, :]

    def process(self, vertical_mps2: FloatArray, lateral_mps2: FloatArray) -> FloatArray:
        x = np.asarray(vertical_mps2, dtype=np.float64) + np.asarray(lateral_mps2)[:, None] * self._cross[None, :]
        padded = np.vstack([self._history, x])
        delayed = np.empty_like(x)
        n0 = DELAY_LINE
        for ch in range(3):
            i0 = int(self._skew[ch])
            f = self._skew[ch] - i0
            k = np.arange(x.shape[0]) + n0
            delayed[:, ch] = (1.0 - f) * padded[k - i0, ch] + f * padded[k - i0 - 1, ch]
        self._history = padded[-DELAY_LINE:]
        y, self._zi = signal.sosfilt(self._sos, delayed, axis=0, zi=self._zi)
        return y[:: self.factor]


def lateral_acceleration(
    sensor: SensorParameters, speed: SpeedProfile, time_s: FloatArray, fs_hz: float, rng: np.random.Generator
) -> FloatArray:
    """The frame's lateral acceleration (m/s^2) at the output-rate times `time_s` (uniform, 1 / fs_hz apart).

    Hunting-like part: sqrt(2) a_h cos(phi), phi' = 2 pi f_h + phase diffusion, f_h = V / wavelength,
    the diffusion giving a Lorentzian band of full width `hunting_bandwidth_fraction` x f_h; plus
    band-limited noise (0.5-20 Hz); both scale with V / (100 km/h).
    """
    n = time_s.size
    v = np.interp(time_s, *speed.arrays_mps())
    scale = v / REFERENCE_SPEED_MPS
    if n == 0 or not np.any(scale > 0):
        return np.zeros(n)
    dt = 1.0 / fs_hz
    f_h = v / sensor.hunting_wavelength_m
    diffusion = 2.0 * math.pi * sensor.hunting_bandwidth_fraction * f_h  # rad^2/s
    phase = rng.uniform(0.0, 2.0 * math.pi) + np.cumsum(
        2.0 * math.pi * f_h * dt + np.sqrt(diffusion * dt) * rng.standard_normal(n)
    )
    hunting = math.sqrt(2.0) * sensor.hunting_rms_mps2_at_100_kmh * scale * np.cos(phase)
    high = min(LATERAL_BAND_HZ[1], 0.4 * fs_hz)
    sos = signal.butter(2, [LATERAL_BAND_HZ[0], high], btype="bandpass", fs=fs_hz, output="sos")
    impulse = signal.sosfilt(sos, np.r_[1.0, np.zeros(int(20 * fs_hz))])
    gain = math.sqrt(float(np.sum(impulse**2)))  # the filter's noise gain: unit-variance output below
    broad = signal.sosfilt(sos, rng.standard_normal(n)) / gain
    return hunting + sensor.random_lateral_rms_mps2_at_100_kmh * scale * broad


def bias_drift(sensor: SensorParameters, n: int, fs_hz: float, rng: np.random.Generator) -> FloatArray:
    """(n, 3) slow offset drift: flicker-like (four OU processes a decade apart) plus a random walk."""
    dt = 1.0 / fs_hz
    out = np.zeros((n, 3))
    if sensor.bias_instability_mps2 > 0:
        sigma = sensor.bias_instability_mps2 / math.sqrt(len(DRIFT_TIME_CONSTANTS_S))
        for tau in DRIFT_TIME_CONSTANTS_S:
            a = math.exp(-dt / tau)
            drive = sigma * math.sqrt(1.0 - a * a) * rng.standard_normal((n, 3))
            start = sigma * rng.standard_normal(3)  # the stationary distribution
            out += signal.lfilter([1.0], [1.0, -a], drive, axis=0, zi=(a * start)[None, :])[0]
    if sensor.bias_random_walk_mps2_per_sqrt_s > 0:
        out += np.cumsum(sensor.bias_random_walk_mps2_per_sqrt_s * math.sqrt(dt) * rng.standard_normal((n, 3)), axis=0)
    return out


def convert(accel_mps2: FloatArray, sensor: SensorParameters, fs_hz: float, rng: np.random.Generator) -> FloatArray:
    """The decimated chain output (n, 3) to what the converter reports: gain, bias, drift, noise, range, LSB."""
    n = accel_mps2.shape[0]
    out = accel_mps2 * np.array(sensor.gain) + np.array(sensor.bias_mps2)
    out = out + bias_drift(sensor, n, fs_hz, rng)
    if sensor.noise_density_mps2_per_sqrt_hz > 0:
        white = sensor.noise_density_mps2_per_sqrt_hz * math.sqrt(fs_hz / 2.0) * rng.standard_normal((n, 3))
        out = out + (signal.sosfilt(output_sos(sensor, fs_hz), white, axis=0) if sensor.noise_inside else white)
    if any(sensor.element_noise_density_mps2_per_sqrt_hz):  # a failing element: inside, shaped alike
        white = np.asarray(sensor.element_noise_density_mps2_per_sqrt_hz) * math.sqrt(fs_hz / 2.0) * rng.standard_normal((n, 3))
        out = out + signal.sosfilt(output_sos(sensor, fs_hz), white, axis=0)
    if sensor.bits:
        full_scale = sensor.range_g * STANDARD_GRAVITY_MPS2
        lsb = 2.0 * full_scale / 2**sensor.bits
        codes = np.clip(np.round(out / lsb), -(2 ** (sensor.bits - 1)), 2 ** (sensor.bits - 1) - 1)
        out = codes * lsb
    return out
