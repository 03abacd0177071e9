"""Track irregularities: the generated profiles' PSDs re-estimated against the target spectra."""

import numpy as np
import pytest
from scipy import signal

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.track import TRACKS, generate_track, shaped_psd, track_spectrum

RANDOM_TRACKS = [name for name in TRACKS if name != "perfect"]
DS_M = 0.05


def _band_ratio(profile: np.ndarray, psd, lo_m: float, hi_m: float) -> np.ndarray:
    """Welch estimate / target, averaged over octave bands between wavelengths hi_m and lo_m."""
    fs_rad = 2 * np.pi / DS_M  # samples per radian of wavenumber
    omega, estimate = signal.welch(profile, fs=fs_rad, nperseg=int(round(2 * hi_m / DS_M)) * 4)
    edges = 2 * np.pi / np.geomspace(hi_m, lo_m, 7)
    ratios = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        inside = (omega >= a) & (omega < b)
        ratios.append(np.sum(estimate[inside]) / np.sum(psd(omega[inside])))
    return np.array(ratios)


@pytest.mark.parametrize("name", RANDOM_TRACKS)
def test_generated_rails_have_the_target_level_and_cross_level_psd(name: str) -> None:
    track = generate_track(name, 40_000.0, np.random.default_rng(7), ds_m=DS_M)
    spectrum = track_spectrum(name)
    # Octave bands from 64 m down to 1 m wavelength, one-sided PSD in m^2/(rad/m): within 10 %.
    # Down to 2 m the shaping changes the standard spectrum by less than 7 %.
    for generated, standard in ((track.level_m, spectrum.level_psd), (track.cross_level_m, spectrum.cross_level_psd)):
        np.testing.assert_allclose(_band_ratio(generated, shaped_psd(standard), 1.0, 64.0), 1.0, atol=0.1)
        np.testing.assert_allclose(_band_ratio(generated, standard, 2.0, 64.0), 1.0, atol=0.12)


def test_short_waves_roll_off_and_stop_at_a_quarter_metre() -> None:
    track = generate_track("erri-high", 20_000.0, np.random.default_rng(1), ds_m=DS_M)
    omega, estimate = signal.welch(track.level_m, fs=2 * np.pi / DS_M, nperseg=8192)
    target = shaped_psd(track_spectrum("erri-high").level_psd)(omega)
    at_half_m = np.abs(omega - 2 * np.pi / 0.5) < 0.5
    assert np.mean(estimate[at_half_m] / target[at_half_m]) == pytest.approx(1.0, abs=0.25)
    assert np.max(estimate[omega > 2 * np.pi / 0.2]) < 1e-6 * np.max(estimate)


def test_the_erri_high_level_matches_the_tabulated_ore_b176_value() -> None:
    """ORE B176 high level at 10 m wavelength: 1.0863e-5 m^2/(cycle/m) = S(Omega) * 2 pi."""
    s = track_spectrum("erri-high").level_psd(np.array([2 * np.pi / 10.0]))[0]
    assert s * 2 * np.pi == pytest.approx(1.0863e-5, rel=2e-3)


def test_rails_are_correlated_at_long_and_independent_at_short_wavelengths() -> None:
    """Coherence of the two rails: ((S_v - S_c/4) / (S_v + S_c/4))^2, about 0.74 at 50 m and 0 at 1.5 m."""
    track = generate_track("erri-low", 40_000.0, np.random.default_rng(3), ds_m=DS_M)
    omega, coherence = signal.coherence(track.left_m, track.right_m, fs=2 * np.pi / DS_M, nperseg=8192)
    spectrum = track_spectrum("erri-low")
    for wavelength_m in (50.0, 20.0, 5.0, 1.5):
        near = np.abs(omega - 2 * np.pi / wavelength_m) < 0.1 * 2 * np.pi / wavelength_m
        s_v, s_c4 = spectrum.level_psd(omega[near]), spectrum.cross_level_psd(omega[near]) / 4
        expected = np.mean(((s_v - s_c4) / (s_v + s_c4)) ** 2)
        assert np.mean(coherence[near]) == pytest.approx(expected, abs=0.06), wavelength_m
    assert expected < 0.01  # 1.5 m: independent rails


def test_a_seed_gives_the_same_track_and_another_seed_another() -> None:
    a = generate_track("fra-5", 500.0, np.random.default_rng(11))
    b = generate_track("fra-5", 500.0, np.random.default_rng(11))
    c = generate_track("fra-5", 500.0, np.random.default_rng(12))
    np.testing.assert_array_equal(a.left_m, b.left_m)
    np.testing.assert_array_equal(a.right_m, b.right_m)
    assert not np.allclose(a.left_m, c.left_m)


def test_the_fade_in_starts_from_a_level_track() -> None:
    track = generate_track("erri-high", 500.0, np.random.default_rng(0), ramp_start_m=12.0, ramp_length_m=20.0)
    start = int(12.0 / track.ds_m)
    assert np.all(track.left_m[: start + 1] == 0.0) and np.all(track.right_m[: start + 1] == 0.0)
    assert np.std(track.left_m[int(40 / track.ds_m) :]) > 1e-4


def test_the_perfect_track_is_flat() -> None:
    track = generate_track("perfect", 100.0, np.random.default_rng(0))
    assert not track.left_m.any() and not track.right_m.any()


def test_an_unknown_track_names_the_known_ones() -> None:
    with pytest.raises(SimulationError, match="unknown track 'erri-medium': use one of perfect, erri-low"):
        track_spectrum("erri-medium")
