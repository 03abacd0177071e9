"""Random vertical irregularities of the two rails from standard spectra, reproducible from a seed.

Each spectrum gives two one-sided spatial PSDs, in m^2/(rad/m) over the angular wavenumber
Omega (rad/m), so that a variance is the integral over 0 < Omega < inf:
  - the vertical level z_v = (z_left + z_right) / 2 (the track centre line), and
  - the cross-level z_c = z_left - z_right (the height difference of the two rails).
They are generated independently, so the rails are strongly correlated at long wavelengths
(where the cross-level spectrum rolls off) and nearly independent at short ones, where
S_c -> 4 S_v, the value for two independent rails. z_left = z_v + z_c / 2, z_right = z_v - z_c / 2.

Spectra (constants in the table below):
  ERRI / ORE B176 ("German" spectra, low and high level), with b = 0.75 m half the contact
  spacing, Omega_c = 0.8246, Omega_r = 0.0206, Omega_s = 0.4380 rad/m:
      S_v = A_v Omega_c^2 / ((Omega^2 + Omega_r^2) (Omega^2 + Omega_c^2))
      S_phi = (A_v / b^2) Omega_c^2 Omega^2 / ((Omega^2 + Omega_r^2) (Omega^2 + Omega_c^2) (Omega^2 + Omega_s^2))
  with S_phi the cross-level angle's PSD (rad^2/(rad/m)), so S_c = (2 b)^2 S_phi;
  A_v = 4.032e-7 m rad (low level), 1.080e-6 m rad (high level). Check: high level at 10 m
  wavelength gives 1.73e-6 m^2/(rad/m) = 1.086e-5 m^2/(cycle/m), the tabulated ORE B176 value.
  FRA (US Federal Railroad Administration track classes, Hamid and Yang), k = 0.25,
  Omega_c = 0.8245 rad/m, A_v in cm^2 rad/m (0.5376, 0.2095, 0.0339 for classes 4, 5, 6) and
  Omega_s = 1.1312, 0.8209, 0.4380 rad/m:
      S_v = k A_v Omega_c^2 / (Omega^2 (Omega^2 + Omega_c^2))
      S_c = 4 k A_v Omega_c^2 / ((Omega^2 + Omega_c^2) (Omega^2 + Omega_s^2))
  (class 4 is the roughest of the three, class 6 the smoothest).

Generation: each process is a sum of harmonics on an FFT grid (spacing dOmega = 2 pi / (N ds))
with independent complex Gaussian amplitudes of variance 2 S(Omega) dOmega, so its PSD is S in
expectation. Wavelengths longer than `longest_wavelength_m` (150 m) are left out: they only
tilt the wagon slowly. Below `rolloff_wavelength_m` (1 m) the spectra are multiplied by
1 / (1 + (Omega / Omega_1)^4), and nothing shorter than a quarter of it is generated: the
standard spectra are defined down to about 1 m, and shorter waves would excite, through the
kinematic wheelsets on a rigid track of this model, frequencies that the real unsprung masses on
the Hertz contact and the track's flexibility filter out (docs/simulator.md). `shaped_psd` is the
spectrum actually generated.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.simulator.errors import SimulationError

FloatArray = NDArray[np.float64]

# Half the distance between the two wheel-rail contact points for the ERRI cross-level (m).
_ERRI_B_M = 0.75
_ERRI_OMEGA_C, _ERRI_OMEGA_R, _ERRI_OMEGA_S = 0.8246, 0.0206, 0.4380
_FRA_K, _FRA_OMEGA_C = 0.25, 0.8245
_CM2_TO_M2 = 1e-4


def _erri(a_v: float) -> tuple[Callable[[FloatArray], FloatArray], Callable[[FloatArray], FloatArray]]:
    def level(omega: FloatArray) -> FloatArray:
        o2 = omega**2
        return a_v * _ERRI_OMEGA_C**2 / ((o2 + _ERRI_OMEGA_R**2) * (o2 + _ERRI_OMEGA_C**2))

    def cross(omega: FloatArray) -> FloatArray:
        o2 = omega**2
        angle = (a_v / _ERRI_B_M**2) * _ERRI_OMEGA_C**2 * o2 / (
            (o2 + _ERRI_OMEGA_R**2) * (o2 + _ERRI_OMEGA_C**2) * (o2 + _ERRI_OMEGA_S**2)
        )
        return (2.0 * _ERRI_B_M) ** 2 * angle

    return level, cross


def _fra(a_v_cm2: float, omega_s: float) -> tuple[Callable[[FloatArray], FloatArray], Callable[[FloatArray], FloatArray]]:
    a_v = a_v_cm2 * _CM2_TO_M2

    def level(omega: FloatArray) -> FloatArray:
        o2 = omega**2
        return _FRA_K * a_v * _FRA_OMEGA_C**2 / (o2 * (o2 + _FRA_OMEGA_C**2))

    def cross(omega: FloatArray) -> FloatArray:
        o2 = omega**2
        return 4.0 * _FRA_K * a_v * _FRA_OMEGA_C**2 / ((o2 + _FRA_OMEGA_C**2) * (o2 + omega_s**2))

    return level, cross


@dataclass(frozen=True)
class TrackSpectrum:
    """A named pair of PSDs, each a function of Omega (rad/m) returning m^2/(rad/m)."""

    name: str
    description: str
    level_psd: Callable[[FloatArray], FloatArray]
    cross_level_psd: Callable[[FloatArray], FloatArray]


def _zero(omega: FloatArray) -> FloatArray:
    return np.zeros_like(np.asarray(omega, dtype=np.float64))


TRACKS: dict[str, TrackSpectrum] = {
    spectrum.name: spectrum
    for spectrum in (
        TrackSpectrum("perfect", "no irregularities (static and free-decay checks)", _zero, _zero),
        TrackSpectrum("erri-low", "ERRI / ORE B176 low level (good main line)", *_erri(4.032e-7)),
        TrackSpectrum("erri-high", "ERRI / ORE B176 high level (poor main line)", *_erri(1.080e-6)),
        TrackSpectrum("fra-4", "FRA class 4 (freight up to 60 mph)", *_fra(0.5376, 1.1312)),
        TrackSpectrum("fra-5", "FRA class 5 (freight up to 80 mph)", *_fra(0.2095, 0.8209)),
        TrackSpectrum("fra-6", "FRA class 6 (up to 110 mph)", *_fra(0.0339, 0.4380)),
    )
}


def track_spectrum(name: str) -> TrackSpectrum:
    try:
        return TRACKS[name]
    except KeyError:
        raise SimulationError(f"unknown track '{name}': use one of {', '.join(TRACKS)}") from None


@dataclass(frozen=True)
class TrackProfile:
    """Vertical positions of the left and right rails (m, z up) every ds_m metres from 0."""

    ds_m: float
    left_m: FloatArray
    right_m: FloatArray

    @property
    def length_m(self) -> float:
        return (self.left_m.shape[0] - 1) * self.ds_m

    @property
    def level_m(self) -> FloatArray:
        return 0.5 * (self.left_m + self.right_m)

    @property
    def cross_level_m(self) -> FloatArray:
        return self.left_m - self.right_m


def band_shaping(omega: FloatArray, rolloff_wavelength_m: float, longest_wavelength_m: float) -> FloatArray:
    """Factor applied to the standard spectra: 0 beyond the band, a 4th-order roll-off at short waves."""
    omega = np.asarray(omega, dtype=np.float64)
    omega_1 = 2.0 * np.pi / rolloff_wavelength_m
    inside = (omega >= 2.0 * np.pi / longest_wavelength_m) & (omega <= 4.0 * omega_1)
    return np.where(inside, 1.0 / (1.0 + (omega / omega_1) ** 4), 0.0)


def shaped_psd(
    psd: Callable[[FloatArray], FloatArray], rolloff_wavelength_m: float = 1.0, longest_wavelength_m: float = 150.0
) -> Callable[[FloatArray], FloatArray]:
    """The PSD that generate_track produces for a standard spectrum `psd` (m^2/(rad/m))."""

    def shaped(omega: FloatArray) -> FloatArray:
        omega = np.asarray(omega, dtype=np.float64)
        factor = band_shaping(omega, rolloff_wavelength_m, longest_wavelength_m)
        out = np.zeros_like(omega)
        out[factor > 0] = psd(omega[factor > 0]) * factor[factor > 0]
        return out

    return shaped


def _synthesise(psd: Callable[[FloatArray], FloatArray], n: int, ds_m: float, rng: np.random.Generator) -> FloatArray:
    """One stationary Gaussian process of n samples with one-sided PSD `psd` (zero outside its band)."""
    n_fft = 1 << max(4, int(np.ceil(np.log2(n))))
    omega = (2.0 * np.pi * np.fft.rfftfreq(n_fft, d=ds_m)).astype(np.float64, copy=False)
    d_omega = omega[1]
    density = psd(omega)
    # Complex Gaussian amplitude with E|c|^2 = 1; a harmonic A c e^{i Omega s} with
    # A = sqrt(2 S dOmega) carries variance S dOmega; irfft divides by n_fft and sums both sides.
    coeff = (rng.standard_normal(omega.shape) + 1j * rng.standard_normal(omega.shape)) / np.sqrt(2.0)
    spectrum = coeff * np.sqrt(2.0 * density * d_omega) * (n_fft / 2.0)
    return np.fft.irfft(spectrum, n=n_fft)[:n]


def generate_track(
    name: str,
    length_m: float,
    rng: np.random.Generator,
    ds_m: float = 0.05,
    rolloff_wavelength_m: float = 1.0,
    longest_wavelength_m: float = 150.0,
    ramp_start_m: float = 0.0,
    ramp_length_m: float = 0.0,
) -> TrackProfile:
    """Left and right rail profiles over [0, length_m].

    The irregularities are faded in with a raised cosine from ramp_start_m over ramp_length_m
    (zero before), so that a vehicle placed in static equilibrium before ramp_start_m starts
    without a jolt.
    """
    spectrum = track_spectrum(name)
    if not length_m > 0 or not ds_m > 0:
        raise ValueError(f"length_m ({length_m}) and ds_m ({ds_m}) must be positive")
    if not ds_m <= rolloff_wavelength_m / 8:
        raise ValueError(f"ds_m ({ds_m}) must resolve the shortest waves ({rolloff_wavelength_m / 4} m) with 2 points")
    n = int(np.ceil(length_m / ds_m)) + 2
    level = _synthesise(shaped_psd(spectrum.level_psd, rolloff_wavelength_m, longest_wavelength_m), n, ds_m, rng)
    cross = _synthesise(shaped_psd(spectrum.cross_level_psd, rolloff_wavelength_m, longest_wavelength_m), n, ds_m, rng)
    if ramp_length_m > 0 or ramp_start_m > 0:
        s = np.arange(n) * ds_m
        x = np.clip((s - ramp_start_m) / max(ramp_length_m, ds_m), 0.0, 1.0)
        fade = 0.5 - 0.5 * np.cos(np.pi * x)
        level *= fade
        cross *= fade
    return TrackProfile(ds_m=ds_m, left_m=level + 0.5 * cross, right_m=level - 0.5 * cross)
