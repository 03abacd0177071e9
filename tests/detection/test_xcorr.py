"""The cross-correlation estimator, and the streaming correlator against the direct reference."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.detection import StreamingCrossCorrelator, xcorr_direct


def test_direct_estimator_is_scipys_full_correlation_over_n() -> None:
    rng = np.random.default_rng(0)
    x, y = rng.standard_normal(300), rng.standard_normal(300)
    full = signal.correlate(x, y, mode="full", method="direct") / 300  # index N-1+k is lag k
    np.testing.assert_allclose(xcorr_direct(x, y, 40), full[299 - 40 : 299 + 41], rtol=1e-12, atol=1e-15)


def test_a_delayed_copy_peaks_at_its_delay_with_the_overlap_energy() -> None:
    rng = np.random.default_rng(1)
    y = rng.standard_normal(1000)
    delay = 7
    x = np.concatenate([np.zeros(delay), y[:-delay]])  # x[n] = y[n - 7]
    c = xcorr_direct(x, y, 20)
    assert int(np.argmax(c)) - 20 == delay
    assert c[20 + delay] == pytest.approx(np.sum(y[: 1000 - delay] ** 2) / 1000, rel=1e-12)


def test_negative_lag_pairs_x_with_later_y() -> None:
    x = np.zeros(10)
    y = np.zeros(10)
    x[2], y[5] = 1.0, 1.0  # y is x three samples later: C_xy(-3) = 1/N
    c = xcorr_direct(x, y, 4)
    expected = np.zeros(9)
    expected[4 - 3] = 0.1
    np.testing.assert_array_equal(c, expected)


def stream_windows(data: np.ndarray, sizes: list[int], correlator: StreamingCrossCorrelator) -> list:
    out, pos, i = [], 0, 0
    while pos < len(data):
        size = sizes[i % len(sizes)]
        out += correlator.push(data[pos : pos + size])
        pos += size
        i += 1
    return out


@settings(max_examples=80, deadline=None)
@given(
    hops_per_window=st.integers(1, 6),
    hop_n=st.integers(1, 40),
    lag_fraction=st.floats(0.0, 0.999),
    sizes=st.lists(st.integers(1, 120), min_size=1, max_size=12),
    scale=st.floats(1e-3, 1e3),
    seed=st.integers(0, 2**32 - 1),
)
def test_streaming_equals_direct_for_any_blocks_hops_and_lags(
    hops_per_window: int, hop_n: int, lag_fraction: float, sizes: list[int], scale: float, seed: int
) -> None:
    window_n = hops_per_window * hop_n
    max_lag_n = min(int(lag_fraction * window_n), window_n - 1)
    rng = np.random.default_rng(seed)
    n = window_n + 5 * hop_n + int(rng.integers(0, hop_n + 1))
    data = scale * rng.standard_normal((n, 3)) + rng.uniform(-5, 5, size=3)
    pairs, zero_pairs = [(0, 2), (1, 2), (2, 0)], [(0, 0), (1, 2)]
    correlator = StreamingCrossCorrelator(3, pairs, window_n, hop_n, max_lag_n, zero_lag_pairs=zero_pairs)
    windows = stream_windows(data, sizes, correlator)
    assert [w.start_index for w in windows] == list(range(0, n - window_n + 1, hop_n))
    for w in windows:
        seg = data[w.start_index : w.start_index + window_n]
        for row, (i, j) in enumerate(pairs):
            ref = xcorr_direct(seg[:, i], seg[:, j], max_lag_n)
            np.testing.assert_allclose(w.lagged[row], ref, rtol=0, atol=1e-9 * np.max(np.abs(ref)))
        for col, (i, j) in enumerate(zero_pairs):
            ref0 = np.dot(seg[:, i], seg[:, j]) / window_n
            assert w.zero_lag[col] == pytest.approx(ref0, rel=1e-9)


def test_reset_forgets_everything_before_it() -> None:
    rng = np.random.default_rng(5)
    first, second = rng.standard_normal((500, 2)), rng.standard_normal((400, 2))
    c = StreamingCrossCorrelator(2, [(0, 1)], 100, 25, 30)
    c.push(first[:437])  # leave a partial hop pending
    c.reset()
    after_reset = c.push(second)
    fresh = StreamingCrossCorrelator(2, [(0, 1)], 100, 25, 30).push(second)
    assert len(after_reset) == len(fresh) == 13
    for a, b in zip(after_reset, fresh, strict=True):
        assert a.start_index == b.start_index
        np.testing.assert_array_equal(a.lagged, b.lagged)


def test_no_window_before_the_first_full_window() -> None:
    c = StreamingCrossCorrelator(2, [(0, 1)], 100, 25, 10)
    assert c.push(np.ones((99, 2))) == []
    assert len(c.push(np.ones((1, 2)))) == 1


@pytest.mark.parametrize(
    ("window_n", "hop_n", "max_lag_n", "match"),
    [(100, 30, 10, "whole number of hops"), (100, 25, 100, "shorter than the window"), (100, 0, 1, "hops")],
)
def test_inconsistent_sizes_are_rejected(window_n: int, hop_n: int, max_lag_n: int, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        StreamingCrossCorrelator(2, [(0, 1)], window_n, hop_n, max_lag_n)


def test_a_pair_naming_a_missing_channel_is_rejected() -> None:
    with pytest.raises(ValueError, match="outside"):
        StreamingCrossCorrelator(2, [(0, 2)], 100, 25, 10)


def test_the_transform_length_is_scipys_next_fast_len_for_real_input() -> None:
    from scipy import fft as scipy_fft

    from bogiemon.detection.xcorr import next_fast_len

    lengths = [*range(1, 5000), 10000, 10007, 59049, 65537, 120000, 2**20 + 1, 3 * 5**9 + 1]
    assert [next_fast_len(n) for n in lengths] == [scipy_fft.next_fast_len(n, real=True) for n in lengths]


@pytest.mark.parametrize(("hops_per_window", "hop_n", "max_lag_n"), [(12, 50, 50), (6, 40, 30), (4, 25, 60), (1, 30, 20)])
def test_the_sliding_sum_stays_within_its_bound_of_the_sum_taken_afresh_for_every_window(hops_per_window: int, hop_n: int, max_lag_n: int) -> None:
    # The per-window path (sliding off) sums the held hops' spectra afresh for every window; the
    # sliding sum adds and takes away one hop at a time, taken afresh every window's worth of hops.
    # Over hundreds of windows of data with a large mean (the worst case for cancellation) the
    # difference stays below 2M roundings of the running total: 1e-12 of the window's largest |C|.
    rng = np.random.default_rng(hops_per_window * hop_n)
    window_n = hops_per_window * hop_n
    data = rng.standard_normal((window_n + 400 * hop_n, 3)) * np.array([1.0, 30.0, 0.01]) + np.array([5.0, -40.0, 0.3])
    sliding = StreamingCrossCorrelator(3, [(0, 1), (1, 2)], window_n, hop_n, max_lag_n)
    afresh = StreamingCrossCorrelator(3, [(0, 1), (1, 2)], window_n, hop_n, max_lag_n)
    afresh.sliding = False
    a, b = stream_windows(data, [97, 13, 300], sliding), stream_windows(data, [97, 13, 300], afresh)
    assert len(a) == len(b) == 401
    worst = max(float(np.max(np.abs(x.lagged - y.lagged) / np.max(np.abs(y.lagged), axis=1, keepdims=True))) for x, y in zip(a, b, strict=True))
    assert worst <= 1e-13  # measured: at most 1.6e-15 (M = 12, hops of 500 samples)
    assert all(x.start_index == y.start_index and np.array_equal(x.zero_lag, y.zero_lag) for x, y in zip(a, b, strict=True))
