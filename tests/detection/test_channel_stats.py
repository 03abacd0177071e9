"""Raw channel statistics per window: streaming equals direct, and each reads what it claims."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.detection.channel_stats import ChannelStats, WindowedChannelStats, channel_stats_reference, longest_run_reference

FS_HZ = 500.0


@settings(max_examples=80, deadline=None)
@given(
    hops=st.integers(1, 5),
    hop_n=st.integers(1, 30),
    n_hops=st.integers(1, 12),
    seed=st.integers(0, 2**32 - 1),
    frozen=st.lists(st.tuples(st.integers(0, 3), st.integers(0, 359), st.integers(1, 120)), max_size=4),
)
def test_streaming_channel_stats_equal_direct(hops: int, hop_n: int, n_hops: int, seed: int, frozen: list[tuple[int, int, int]]) -> None:
    rng = np.random.default_rng(seed)
    data = np.round(rng.standard_normal((hop_n * n_hops, 3)) * 2) / 2 + [9.8, -9.8, 0.0]
    # Frozen stretches (channel 3 means all three) of any length, crossing hops and windows.
    for channel, start, length in frozen:
        columns = slice(None) if channel == 3 else channel
        if start < len(data):
            data[start : start + length, columns] = data[start, columns]
    stream = WindowedChannelStats(hops, hop_n, FS_HZ, clip_level_mps2=10.5)
    for h in range(n_hops):
        got = stream.push_hop(data[h * hop_n : (h + 1) * hop_n])
        if h + 1 < hops:
            assert got is None
            continue
        window = data[(h + 1 - hops) * hop_n : (h + 1) * hop_n]
        want = channel_stats_reference(window, FS_HZ, clip_level_mps2=10.5, hop_n=hop_n)
        for field in dataclasses.fields(ChannelStats):
            assert getattr(got, field.name) == pytest.approx(getattr(want, field.name), rel=1e-12, abs=1e-12), field.name


def test_a_frozen_channel_repeats_every_sample_and_an_inverted_one_reads_minus_g() -> None:
    rng = np.random.default_rng(1)
    data = np.column_stack([np.full(100, 9.81), -9.81 + rng.standard_normal(100), 9.81 + rng.standard_normal(100)])
    stats = WindowedChannelStats(2, 50, FS_HZ).push_hop(data[:50])
    assert stats is None
    stats = WindowedChannelStats(1, 100, FS_HZ, clip_level_mps2=12.0).push_hop(data)
    assert stats is not None
    assert stats.repeat_fraction == (1.0, 0.0, 0.0)
    assert stats.longest_run_s == (100 / FS_HZ, 1 / FS_HZ, 1 / FS_HZ)
    assert stats.mean_mps2[1] == pytest.approx(-9.81, abs=0.3)
    assert stats.clipped_fraction[0] == 0.0 and stats.clipped_fraction[2] > 0.0


def test_reset_forgets_the_last_sample() -> None:
    stream = WindowedChannelStats(1, 3, FS_HZ)
    stream.push_hop(np.ones((3, 3)))
    stream.reset()
    stats = stream.push_hop(np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]]))
    assert stats is not None and stats.repeat_fraction == (0.0, 0.0, 0.0)
    assert stats.longest_run_s == (1 / FS_HZ,) * 3


def test_a_channel_that_froze_late_in_the_window_has_a_short_share_but_a_long_run() -> None:
    # The window's last 2 s frozen out of 60 s: 3 % of the samples repeat, one run of 2 s.
    rng = np.random.default_rng(4)
    data = 9.81 + rng.standard_normal((30_000, 3))
    data[-1000:, 1] = data[-1000, 1]
    stream = WindowedChannelStats(6, 5000, FS_HZ)
    got = [stream.push_hop(data[h * 5000 : (h + 1) * 5000]) for h in range(6)][-1]
    assert got is not None
    assert got.repeat_fraction[1] == pytest.approx(999 / 29_999)
    assert got.longest_run_s[1] == pytest.approx(1000 / FS_HZ)
    assert got.longest_run_s[0] < 0.01 and got.longest_run_s[2] < 0.01


def test_the_longest_run_reference_walks_the_samples() -> None:
    assert longest_run_reference(np.array([1.0, 1.0, 2.0, 2.0, 2.0, 1.0])) == 3
    assert longest_run_reference(np.array([np.nan, np.nan])) == 1  # NaN equals nothing
    assert longest_run_reference(np.array([5.0])) == 1


def test_a_stop_inside_the_window_is_its_quietest_hop_whatever_the_gravity_and_bias() -> None:
    # Six hops of 1 m/s^2 of running about gravity and a bias, the fourth standing (0.01 of noise).
    rng = np.random.default_rng(7)
    level = np.array([1.0, 1.0, 1.0, 0.01, 1.0, 1.0])
    data = rng.standard_normal((6, 1000, 3)) * level[:, None, None] + [9.81, 9.5, 10.1]
    stream = WindowedChannelStats(6, 1000, FS_HZ)
    got = [stream.push_hop(hop) for hop in data][-1]
    assert got is not None
    assert got.hop_rms_min_mps2 == pytest.approx((0.01,) * 3, rel=0.1)
    assert got.hop_rms_max_mps2 == pytest.approx((1.0,) * 3, rel=0.1)


def test_a_record_built_without_hops_carries_no_hop_rms() -> None:
    stats = ChannelStats((9.81,) * 3, (10.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)
    assert all(np.isnan(stats.hop_rms_min_mps2)) and all(np.isnan(stats.hop_rms_max_mps2))


@settings(max_examples=40, deadline=None)
@given(hop_n=st.integers(2, 6000), seed=st.integers(0, 2**32 - 1))
def test_a_hops_sum_and_rms_are_numpys_down_the_columns_bit_for_bit(hop_n: int, seed: int) -> None:
    # The per-hop statistics run channel-major for speed, in the order numpy reduces down the
    # columns of the (n, 3) hop: a window's mean and hop RMS keep every bit they had.
    rng = np.random.default_rng(seed)
    hop = rng.standard_normal((hop_n, 3)) * [0.1, 3.0, 30.0] + [9.81, -9.81, 0.0]
    stats = WindowedChannelStats(1, hop_n, FS_HZ).push_hop(hop)
    assert stats is not None
    assert stats.mean_mps2 == tuple(hop.sum(axis=0) / hop_n)
    assert stats.hop_rms_min_mps2 == stats.hop_rms_max_mps2 == tuple(hop.std(axis=0))
    assert stats.peak_abs_mps2 == tuple(np.abs(hop).max(axis=0))
