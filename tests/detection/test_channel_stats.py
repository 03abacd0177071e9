"""Raw channel statistics per window: streaming equals direct, and each reads what it claims."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.detection.channel_stats import WindowedChannelStats, channel_stats_reference


@settings(max_examples=50, deadline=None)
@given(hops=st.integers(1, 5), hop_n=st.integers(1, 30), n_hops=st.integers(1, 12), seed=st.integers(0, 2**32 - 1))
def test_streaming_channel_stats_equal_direct(hops: int, hop_n: int, n_hops: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    data = np.round(rng.standard_normal((hop_n * n_hops, 3)) * 2) / 2 + [9.8, -9.8, 0.0]
    stream = WindowedChannelStats(hops, hop_n, clip_level_mps2=10.5)
    for h in range(n_hops):
        got = stream.push_hop(data[h * hop_n : (h + 1) * hop_n])
        if h + 1 < hops:
            assert got is None
            continue
        window = data[(h + 1 - hops) * hop_n : (h + 1) * hop_n]
        want = channel_stats_reference(window, clip_level_mps2=10.5)
        for field in ("mean_mps2", "peak_abs_mps2", "repeat_fraction", "clipped_fraction"):
            assert getattr(got, field) == pytest.approx(getattr(want, field), rel=1e-12, abs=1e-12), field


def test_a_frozen_channel_repeats_every_sample_and_an_inverted_one_reads_minus_g() -> None:
    rng = np.random.default_rng(1)
    data = np.column_stack([np.full(100, 9.81), -9.81 + rng.standard_normal(100), 9.81 + rng.standard_normal(100)])
    stats = WindowedChannelStats(2, 50).push_hop(data[:50])
    assert stats is None
    stats = WindowedChannelStats(1, 100, clip_level_mps2=12.0).push_hop(data)
    assert stats is not None
    assert stats.repeat_fraction == (1.0, 0.0, 0.0)
    assert stats.mean_mps2[1] == pytest.approx(-9.81, abs=0.3)
    assert stats.clipped_fraction[0] == 0.0 and stats.clipped_fraction[2] > 0.0


def test_reset_forgets_the_last_sample() -> None:
    stream = WindowedChannelStats(1, 3)
    stream.push_hop(np.ones((3, 3)))
    stream.reset()
    stats = stream.push_hop(np.array([[1.0, 1.0, 1.0], [2.0, 2.0, 2.0], [3.0, 3.0, 3.0]]))
    assert stats is not None and stats.repeat_fraction == (0.0, 0.0, 0.0)
