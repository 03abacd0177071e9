"""The sensors' noise floor: learned at commissioning in the top octave below Nyquist, a noisy sensor
named whatever filter reads the frame, the healthy frame never."""

import dataclasses

from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.daemon import tomlout
from bogiemon.daemon.config import ConfigError, parse_config
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.health import SensorProblem, assess_window
from bogiemon.judgement.noise_floor import (
    floor_bands, floor_excess, floor_noisy_channels, learn_noise_floor, merge_noise_floors, top_octave, unexplained_densities,
)  # fmt: skip
from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings, WindowIndicators, from_modal
from bogiemon.detection.spectra import BANDS_HZ, N_BANDS, WindowSpectra

FS_HZ = 500.0
SETTINGS = ProcessingSettings(fs_hz=FS_HZ, window_s=20.0, hop_s=5.0, max_lag_s=2.0)
GEOMETRY = BogieGeometry()


def frame_run(
    seed: int,
    duration_s: float = 60.0,
    hiss_mps2: tuple[float, float, float] = (0.0, 0.0, 0.0),
    gain: float = 1.0,
    vibration_mps2: float = 0.0,
    sensor_hz: float | None = None,
) -> list[WindowIndicators]:
    """Windows of a rigid frame driven by three independent inputs below 30 Hz (a bogie frame seen
    through anti-alias filters gives little above), each sensor with its own small white noise
    (0.002 m/s^2 per sample) and, per channel, extra white noise of hiss_mps2 RMS per sample.
    vibration_mps2: the frame's own vibration up to 225 Hz (per modal input, RMS), as a filter near
    Nyquist lets it through; sensor_hz: the sensors' own 4th-order low-pass, their noise inside it,
    the hiss after it."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * FS_HZ)
    sos = signal.butter(4, 30.0, fs=FS_HZ, output="sos")
    modal = signal.sosfilt(sos, rng.normal(size=(n, 3)), axis=0) * gain * np.array([2.0, 1.5, 1.5])
    if vibration_mps2:
        modal += signal.sosfilt(signal.butter(4, 225.0, fs=FS_HZ, output="sos"), rng.normal(size=(n, 3)), axis=0) * vibration_mps2
    accel = from_modal(modal, GEOMETRY) + rng.normal(0.0, 0.002, size=(n, 3))
    if sensor_hz is not None:
        accel = signal.sosfilt(signal.butter(4, sensor_hz, fs=FS_HZ, output="sos"), accel, axis=0)
    accel += 9.81 + rng.normal(size=(n, 3)) * np.asarray(hiss_mps2)
    return IndicatorStream(SETTINGS, GEOMETRY).process(accel)


def commissioned(seeds=(1, 2, 3)) -> HealthSettings:
    fit = learn_noise_floor(w for s in seeds for w in frame_run(s))
    assert fit is not None
    return dataclasses.replace(HealthSettings(), noise_floor_psd=fit.psd, noise_floor_ratio=fit.ratio)


def schur_reference(s: np.ndarray, c: int) -> float:
    """S_cc - S_co S_oo^-1 S_oc: the part of channel c the other two cannot explain, written out."""
    others = [k for k in range(3) if k != c]
    s_oo = s[np.ix_(others, others)]
    s_co = s[c, others]
    return float(np.real(s[c, c] - s_co @ np.linalg.solve(s_oo, s_co.conj())))


@settings(max_examples=50, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_each_bands_unexplained_density_is_the_schur_complement_over_its_width(seed: int) -> None:
    rng = np.random.default_rng(seed)
    h = rng.normal(size=(N_BANDS, 3, 4)) + 1j * rng.normal(size=(N_BANDS, 3, 4))
    matrix = h @ np.conj(np.transpose(h, (0, 2, 1))) * rng.uniform(0.01, 10.0, size=(N_BANDS, 1, 1))
    widths = np.diff(BANDS_HZ)
    expected = [[schur_reference(matrix[b], c) / widths[b] for c in range(3)] for b in range(N_BANDS)]
    np.testing.assert_allclose(unexplained_densities(matrix, BANDS_HZ), expected, rtol=1e-9)


def test_the_top_octave_is_the_bands_within_an_octave_of_the_highest_with_power() -> None:
    present = np.ones(N_BANDS, dtype=bool)
    assert top_octave(BANDS_HZ, present).tolist() == [8, 9]  # 128-181 and 181-256 Hz
    present[8:] = False  # a rate of 256 Hz: nothing above 128 Hz
    assert top_octave(BANDS_HZ, present).tolist() == [7]
    assert top_octave(BANDS_HZ, np.zeros(N_BANDS, dtype=bool)).size == 0


def test_bands_without_power_are_skipped_and_none_left_is_no_floor() -> None:
    matrix = np.zeros((N_BANDS, 3, 3), dtype=np.complex128)
    assert floor_bands(matrix, BANDS_HZ) is None
    matrix[2] = np.diag([1.0, 2.0, 4.0])
    floor = floor_bands(matrix, BANDS_HZ)
    assert floor is not None and floor.bands == (2,)
    np.testing.assert_allclose(floor.density, [np.array([1.0, 2.0, 4.0]) / (BANDS_HZ[3] - BANDS_HZ[2])])
    np.testing.assert_allclose(floor.ratio, [[1.0 / np.sqrt(8.0), 2.0 / 2.0, 4.0 / np.sqrt(2.0)]])


def test_white_noise_lifts_a_sensors_top_octave_to_its_density_and_leaves_the_others() -> None:
    hiss_mps2 = 0.4  # per sample at 500 Hz: a density of 0.4^2 / 250 Hz
    density = hiss_mps2**2 / (FS_HZ / 2)
    healthy = np.array([floor_bands(w.spectra.matrix, BANDS_HZ).density for w in frame_run(7)])
    noisy = np.array([floor_bands(w.spectra.matrix, BANDS_HZ).density for w in frame_run(7, hiss_mps2=(0.0, hiss_mps2, 0.0))])
    assert np.all(noisy[:, :, 1] > 0.8 * density) and np.all(noisy[:, :, 1] < 1.2 * density)
    assert np.all(healthy[:, :, 1] < 0.01 * density)
    np.testing.assert_allclose(noisy[:, :, [0, 2]], healthy[:, :, [0, 2]], rtol=0.5)


def test_commissioning_learns_each_channels_smallest_density_and_largest_ratio_in_the_top_octave() -> None:
    windows = frame_run(1)
    fit = learn_noise_floor(windows)
    floors = [floor_bands(w.spectra.matrix, BANDS_HZ) for w in windows]
    densities = np.concatenate([f.density for f in floors])
    others = np.array([[np.sqrt(d[(c + 1) % 3] * d[(c + 2) % 3]) for c in range(3)] for d in densities])
    assert fit is not None and fit.windows == len(windows) and all(f.bands == (8, 9) for f in floors)
    np.testing.assert_allclose(fit.psd, densities.min(axis=0))
    np.testing.assert_allclose(fit.ratio, (densities / others).max(axis=0))


def test_merging_the_loads_fits_is_learning_on_their_windows_together() -> None:
    a, b = frame_run(1), frame_run(2, gain=3.0)
    merged = merge_noise_floors([learn_noise_floor(a), learn_noise_floor(b)])
    together = learn_noise_floor(a + b)
    assert merged is not None and together is not None
    assert merged.psd == together.psd and merged.ratio == together.ratio and merged.windows == together.windows
    assert merge_noise_floors([None, None]) is None


def test_a_noisy_sensor_is_named_on_its_channel_after_commissioning() -> None:
    health = commissioned()
    for w in frame_run(11, hiss_mps2=(0.0, 0.4, 0.0)):
        assert floor_noisy_channels(w, health) == [1]
        assert assess_window(w, health, geometry=GEOMETRY).problems == {"a2": (SensorProblem.NOISY,)}


def test_a_stuck_sensor_does_not_make_the_others_look_noisy() -> None:
    health = commissioned()
    stuck = frame_run(13, hiss_mps2=(0.0, 0.0, 0.0))
    for w in stuck:
        frozen = dataclasses.replace(w.channels, repeat_fraction=(0.0, 0.9, 0.0))
        matrix = w.spectra.matrix.copy()
        matrix[:, 1, :] *= 1e-4  # a2 holds still: next to nothing left of it in any band
        matrix[:, :, 1] *= 1e-4
        held = dataclasses.replace(w, channels=frozen, spectra=WindowSpectra(BANDS_HZ, matrix))
        assert assess_window(held, health, geometry=GEOMETRY).problems == {"a2": (SensorProblem.STUCK,)}


def test_the_healthy_frame_on_other_runs_is_never_noisy() -> None:
    health = commissioned()
    for seed in range(20, 30):
        for w in frame_run(seed):
            assert floor_noisy_channels(w, health) == []


def test_a_rougher_track_lifting_every_floor_is_not_noise() -> None:
    health = commissioned()
    for w in frame_run(12, gain=30.0, hiss_mps2=(0.06, 0.06, 0.06)):
        assert floor_noisy_channels(w, health) == []


def test_the_floor_excess_is_the_margin_up_to_which_a_channel_is_named() -> None:
    health = commissioned()
    window = frame_run(11, hiss_mps2=(0.0, 0.4, 0.0))[0]
    excess = floor_excess(window, health)
    assert excess is not None and excess[1] > 100.0 and max(excess[0], excess[2]) < health.noise_floor_margin
    assert 1 in floor_noisy_channels(window, dataclasses.replace(health, noise_floor_margin=0.99 * excess[1]))
    assert 1 not in floor_noisy_channels(window, dataclasses.replace(health, noise_floor_margin=1.01 * excess[1]))
    assert floor_excess(window, HealthSettings()) is None


def test_without_commissioning_the_check_is_not_in_force() -> None:
    for w in frame_run(11, hiss_mps2=(0.0, 0.4, 0.0)):
        assert floor_noisy_channels(w, HealthSettings()) == []


def test_commissioned_floors_go_through_the_config_as_calibrate_writes_them() -> None:
    fit = learn_noise_floor(frame_run(1))
    assert fit is not None
    config = parse_config(tomlout.dumps({"health": fit.health_fields()}), "calibration.toml")
    health = config.health_settings()
    np.testing.assert_allclose(health.noise_floor_psd, fit.psd, rtol=1e-3)
    np.testing.assert_allclose(health.noise_floor_ratio, fit.ratio, rtol=1e-3)


@pytest.mark.parametrize("fields", [{"noise_floor_psd": [1e-6, 1e-6]}, {"noise_floor_psd": [1e-6] * 3}, {"noise_floor_ratio": [1.0] * 3}])
def test_floors_need_one_value_per_channel_each(fields: dict) -> None:
    with pytest.raises(ConfigError, match="noise_floor_psd and noise_floor_ratio"):
        parse_config(tomlout.dumps({"health": fields}), "bogiemon.toml")


def test_a_window_built_without_the_noise_floor_bands_still_has_a_floor() -> None:
    # Records of the judged bands only (built by hand, or older): the top octave of what they hold.
    matrix = np.tile(np.diag([1e-3, 2e-3, 3e-3]).astype(np.complex128), (7, 1, 1))
    spectra = WindowSpectra(BANDS_HZ[:8], matrix)
    floor = floor_bands(spectra.matrix, spectra.bands_hz)
    assert floor is not None and floor.bands == (6,)  # 32-64 Hz


@pytest.mark.parametrize(
    ("vibration_mps2", "sensor_hz"),
    [(0.0, None), (0.1, None), (0.0, 50.0)],
    ids=["steep-filter", "frame-vibration-in-the-top-octave", "low-cut-noise-inside"],
)
def test_a_noisy_sensor_is_named_and_the_healthy_frame_never_whatever_reads_the_frame(vibration_mps2: float, sensor_hz: float | None) -> None:
    # The frame's own vibration in the top octave (a filter near Nyquist) lifts every channel's
    # density there, the hiss one channel's; a 50 Hz low-pass inside the sensors leaves nothing of
    # the frame or of their own noise up there, the hiss after it all of its own.
    runs: dict[str, Any] = {"vibration_mps2": vibration_mps2, "sensor_hz": sensor_hz}
    fit = learn_noise_floor(w for s in (1, 2, 3) for w in frame_run(s, **runs))
    assert fit is not None
    health = dataclasses.replace(HealthSettings(), noise_floor_psd=fit.psd, noise_floor_ratio=fit.ratio)
    for w in frame_run(11, hiss_mps2=(0.0, 0.0, 0.4), **runs):
        assert floor_noisy_channels(w, health) == [2]
    for seed in (20, 21, 22):
        assert all(floor_noisy_channels(w, health) == [] for w in frame_run(seed, **runs))
