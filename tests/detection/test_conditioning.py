"""Conditioning: the filters are causal, carry their state across blocks, and do what they claim."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.detection import StreamingSOS, butter_sos

FS_HZ = 500.0


def split_points(draw_sizes: list[int], n: int) -> list[int]:
    cuts, pos = [], 0
    for size in draw_sizes:
        pos += size
        if pos >= n:
            break
        cuts.append(pos)
    return cuts


@settings(max_examples=60, deadline=None)
@given(
    sizes=st.lists(st.integers(min_value=1, max_value=400), min_size=1, max_size=30),
    steady=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_blockwise_filtering_equals_filtering_the_whole_signal(sizes: list[int], steady: bool, seed: int) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((2000, 3)) + rng.uniform(-10, 10, size=3)
    for sos in (butter_sos(2, 0.5, FS_HZ, "highpass"), butter_sos(4, 10.0, FS_HZ, "lowpass")):
        whole = StreamingSOS(sos, 3, start_at_steady_state=steady).process(x)
        f = StreamingSOS(sos, 3, start_at_steady_state=steady)
        pieces = [f.process(part) for part in np.split(x, split_points(sizes, len(x)))]
        np.testing.assert_allclose(np.concatenate(pieces), whole, rtol=0, atol=1e-12)


def test_whole_signal_filter_is_scipys_sosfilt() -> None:
    x = np.random.default_rng(4).standard_normal((1000, 3))
    sos = butter_sos(4, 10.0, FS_HZ, "lowpass")
    ours = StreamingSOS(sos, 3, start_at_steady_state=False).process(x)
    np.testing.assert_allclose(ours, signal.sosfilt(sos, x, axis=0), rtol=0, atol=1e-14)


def test_highpass_started_at_steady_state_removes_gravity_without_a_transient() -> None:
    gravity = np.full((5000, 3), [9.81, 9.79, 9.83])
    out = StreamingSOS(butter_sos(2, 0.5, FS_HZ, "highpass"), 3, start_at_steady_state=True).process(gravity)
    assert np.max(np.abs(out)) < 1e-9


def test_reset_starts_a_new_signal() -> None:
    f = StreamingSOS(butter_sos(2, 0.5, FS_HZ, "highpass"), 1, start_at_steady_state=True)
    f.process(np.full((100, 1), 3.0))
    f.reset()
    out = f.process(np.full((100, 1), -7.0))
    assert np.max(np.abs(out)) < 1e-9


def steady_gain(sos: np.ndarray, freq_hz: float) -> float:
    t = np.arange(int(20 * FS_HZ)) / FS_HZ
    y = signal.sosfilt(sos, np.sin(2 * np.pi * freq_hz * t))
    return float(np.sqrt(2 * np.mean(y[len(y) // 2 :] ** 2)))


def test_highpass_passes_the_bogie_band_and_blocks_drift() -> None:
    sos = butter_sos(2, 0.5, FS_HZ, "highpass")
    assert steady_gain(sos, 1.0) == pytest.approx(1 / np.sqrt(1 + 0.5**4), rel=1e-3)  # 0.970
    assert steady_gain(sos, 5.0) > 0.9999
    assert steady_gain(sos, 0.05) < 0.011  # drift at 20 s periods: -40 dB


def test_lowpass_has_its_corner_at_10_hz() -> None:
    sos = butter_sos(4, 10.0, FS_HZ, "lowpass")
    assert steady_gain(sos, 2.0) > 0.9999
    assert steady_gain(sos, 10.0) == pytest.approx(1 / np.sqrt(2), rel=1e-3)
    assert steady_gain(sos, 50.0) < 2e-3  # 4th order: -80 dB per decade, -54 dB at 50 Hz


@pytest.mark.parametrize("cutoff_hz", [0.0, 250.0, 300.0])
def test_cutoff_outside_zero_to_nyquist_is_rejected(cutoff_hz: float) -> None:
    with pytest.raises(ValueError, match="Nyquist"):
        butter_sos(2, cutoff_hz, FS_HZ, "lowpass")
