"""The filters without scipy.signal: design, steady state and streaming, each against scipy.signal."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.detection import StreamingSOS, butter_sos
from bogiemon.detection.conditioning import CHUNK_N, _cascade, sosfilt_zi

orders = st.integers(1, 8)
btypes = st.sampled_from(["lowpass", "highpass"])
rates_hz = st.floats(50.0, 5000.0)
# Cutoffs as a fraction of fs: from 1/1000 (0.5 Hz at 500 Hz is 1/1000) to just under Nyquist.
cutoff_fractions = st.floats(1e-3, 0.49)


@settings(max_examples=300, deadline=None)
@given(order=orders, btype=btypes, fs_hz=rates_hz, fraction=cutoff_fractions)
def test_butter_sos_gives_scipys_sections(order: int, btype: str, fs_hz: float, fraction: float) -> None:
    ours = butter_sos(order, fraction * fs_hz, fs_hz, btype)
    theirs = signal.butter(order, fraction * fs_hz, btype, fs=fs_hz, output="sos")
    assert ours.shape == theirs.shape
    # Denominators to rounding; numerators relative to each section's largest coefficient (the
    # first section's carry the gain, 1e-20 at order 8 and a low cutoff).
    np.testing.assert_allclose(ours[:, 3:], theirs[:, 3:], rtol=0, atol=1e-14)
    scale = np.max(np.abs(theirs[:, :3]), axis=1, keepdims=True)
    np.testing.assert_allclose(ours[:, :3] / scale, theirs[:, :3] / scale, rtol=0, atol=1e-10)


@settings(max_examples=300, deadline=None)
@given(order=orders, btype=btypes, fs_hz=rates_hz, fraction=cutoff_fractions)
def test_butter_sos_has_scipys_frequency_response(order: int, btype: str, fs_hz: float, fraction: float) -> None:
    _, ours = signal.sosfreqz(butter_sos(order, fraction * fs_hz, fs_hz, btype), worN=1024)
    _, theirs = signal.sosfreqz(signal.butter(order, fraction * fs_hz, btype, fs=fs_hz, output="sos"), worN=1024)
    np.testing.assert_allclose(ours, theirs, rtol=0, atol=1e-10)


def exact_gain(sos: np.ndarray, z: int) -> Fraction:
    """H(z) of the sections as stored, in exact rational arithmetic, at z = 1 or z = -1."""
    gain = Fraction(1)
    for b0, b1, b2, a0, a1, a2 in sos:
        gain *= (Fraction(b0) + Fraction(b1) * z + Fraction(b2)) / (Fraction(a0) + Fraction(a1) * z + Fraction(a2))
    return gain


@pytest.mark.parametrize("order", range(1, 9))
@pytest.mark.parametrize(("btype", "z"), [("lowpass", 1), ("highpass", -1)])
def test_butter_sos_passes_with_unit_gain_even_at_a_very_low_cutoff(order: int, btype: str, z: int) -> None:
    # At 1e-4 fs scipy's gain, from the poles, is off by up to 4e-10; ours is set on the
    # coefficients as stored.
    assert abs(float(exact_gain(butter_sos(order, 0.2, 2000.0, btype), z) - 1)) < 1e-14


def test_butter_sos_rejects_an_order_below_one() -> None:
    with pytest.raises(ValueError, match="order must be >= 1"):
        butter_sos(0, 10.0, 500.0, "lowpass")


def test_butter_sos_rejects_a_band_pass() -> None:
    with pytest.raises(ValueError, match="'lowpass' or 'highpass'"):
        butter_sos(2, 10.0, 500.0, "bandpass")


@settings(max_examples=200, deadline=None)
@given(order=orders, btype=btypes, fs_hz=rates_hz, fraction=cutoff_fractions)
def test_sosfilt_zi_is_scipys(order: int, btype: str, fs_hz: float, fraction: float) -> None:
    sos = signal.butter(order, fraction * fs_hz, btype, fs=fs_hz, output="sos")
    np.testing.assert_allclose(sosfilt_zi(sos), signal.sosfilt_zi(sos), rtol=1e-8, atol=1e-12)


def test_sosfilt_zi_of_a_highpass_is_exactly_zero_after_the_first_section() -> None:
    zi = sosfilt_zi(butter_sos(4, 0.5, 500.0, "highpass"))
    assert np.all(zi[1:] == 0.0)


def test_streaming_sos_rejects_sections_whose_a0_is_not_one() -> None:
    sos = butter_sos(2, 0.5, 500.0, "highpass") * 2.0
    with pytest.raises(ValueError, match="a0"):
        StreamingSOS(sos, 3, start_at_steady_state=True)


def shipped_filter(which: str, fs_hz: float) -> np.ndarray:
    """The daemon's filters (ProcessingSettings' defaults): the 0.5 Hz high-pass, the 10 Hz low-pass."""
    return butter_sos(2, 0.5, fs_hz, "highpass") if which == "highpass" else butter_sos(4, 10.0, fs_hz, "lowpass")


def scipy_filter(sos: np.ndarray, x: np.ndarray, steady: bool) -> np.ndarray:
    if not steady:
        return signal.sosfilt(sos, x, axis=0)
    return signal.sosfilt(sos, x, axis=0, zi=signal.sosfilt_zi(sos)[:, :, None] * x[0][None, None, :])[0]


def filter_in_blocks(f: StreamingSOS, x: np.ndarray, sizes: list[int]) -> np.ndarray:
    """x through f in blocks of the given sizes, cycled; empty blocks included."""
    out, start, k = [], 0, 0
    while start < len(x):
        size = sizes[k % len(sizes)]
        out.append(f.process(x[start : start + size]))
        start, k = start + size, k + 1
    return np.concatenate(out)


# Block sizes: empty, single samples, around a chunk, and longer than one matrix product takes.
block_sizes = st.lists(
    st.one_of(st.sampled_from([0, 1, CHUNK_N - 1, CHUNK_N, CHUNK_N + 1]), st.integers(0, 6000)), min_size=1, max_size=20
).filter(any)


@settings(max_examples=80, deadline=None)
@given(
    which=st.sampled_from(["highpass", "lowpass"]),
    fs_hz=st.floats(200.0, 2000.0),
    sizes=block_sizes,
    steady=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
)
def test_blockwise_filtering_equals_scipys_sosfilt_of_the_whole_signal(
    which: str, fs_hz: float, sizes: list[int], steady: bool, seed: int
) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((12_000, 3)) + np.array([0.1, -0.2, 9.81])  # gravity on the last axis
    sos = shipped_filter(which, fs_hz)
    want = scipy_filter(sos, x, steady)
    got = filter_in_blocks(StreamingSOS(sos, 3, start_at_steady_state=steady), x, sizes)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.max(np.abs(want)))


@settings(max_examples=60, deadline=None)
@given(order=orders, btype=btypes, fraction=st.floats(2e-3, 0.45), sizes=block_sizes, seed=st.integers(0, 2**32 - 1))
def test_any_butterworth_filters_blockwise_as_scipys_sosfilt(
    order: int, btype: str, fraction: float, sizes: list[int], seed: int
) -> None:
    x = np.random.default_rng(seed).standard_normal((8_000, 2))
    sos = butter_sos(order, fraction * 1000.0, 1000.0, btype)
    want = signal.sosfilt(sos, x, axis=0)
    got = filter_in_blocks(StreamingSOS(sos, 2, start_at_steady_state=False), x, sizes)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * np.max(np.abs(want)))


@pytest.mark.parametrize("fs_hz", [500.0, 2000.0])
@pytest.mark.parametrize("which", ["highpass", "lowpass"])
def test_ten_minutes_in_one_second_blocks_stay_within_rounding_of_sosfilt(which: str, fs_hz: float) -> None:
    n = int(600 * fs_hz)
    x = np.random.default_rng(7).standard_normal((n, 3)) + 9.81
    sos = shipped_filter(which, fs_hz)
    want = scipy_filter(sos, x, steady=True)
    got = filter_in_blocks(StreamingSOS(sos, 3, start_at_steady_state=True), x, [int(fs_hz)])
    scale = np.max(np.abs(want))
    last_minute = slice(n - int(60 * fs_hz), n)
    np.testing.assert_allclose(got[last_minute], want[last_minute], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9 * scale)


def test_a_column_slice_of_a_wider_array_filters_as_its_copy() -> None:
    wide = np.random.default_rng(3).standard_normal((3000, 8))
    sos = shipped_filter("lowpass", 500.0)
    view = StreamingSOS(sos, 2, start_at_steady_state=False).process(wide[:, 5:7])
    copy = StreamingSOS(sos, 2, start_at_steady_state=False).process(wide[:, 5:7].copy())
    np.testing.assert_array_equal(view, copy)


@pytest.mark.parametrize("fs_hz", [200.0, 500.0, 2000.0])
def test_the_chunk_step_of_the_highpass_shrinks_every_state(fs_hz: float) -> None:
    # The chunked recursion applies A^L (L = CHUNK_N) once per chunk, and A^k within one: in
    # sosfilt's own form, A^L of this filter at 2 kHz has norm 62 (rounding amplified sixty-fold);
    # in the form used, no power of A has norm above 1.
    a = _cascade(shipped_filter("highpass", fs_hz))[0]
    norms = [np.linalg.norm(np.linalg.matrix_power(a, k), 2) for k in range(1, 4 * CHUNK_N + 1)]
    assert max(norms) <= 1.0
