"""Hop assembly: blocks of any size in, the same samples out in whole hops, nothing lost or doubled."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from bogiemon.detection.hops import HopAssembler


@given(hop_n=st.integers(1, 50), sizes=st.lists(st.integers(0, 120), max_size=20))
def test_hops_are_the_stream_cut_in_order(hop_n: int, sizes: list[int]) -> None:
    total = sum(sizes)
    data = np.arange(total * 2, dtype=float).reshape(total, 2)
    assembler, hops, pos = HopAssembler(hop_n, 2), [], 0
    for size in sizes:
        hops += [hop.copy() for hop in assembler.split(data[pos : pos + size])]
        pos += size
    whole = (total // hop_n) * hop_n
    assert all(h.shape == (hop_n, 2) for h in hops)
    np.testing.assert_array_equal(np.concatenate(hops) if hops else np.empty((0, 2)), data[:whole])


def test_reset_drops_the_partial_hop() -> None:
    assembler = HopAssembler(4, 1)
    assert list(assembler.split(np.ones((3, 1)))) == []
    assembler.reset()
    hops = list(assembler.split(np.arange(4.0)[:, None]))
    np.testing.assert_array_equal(hops[0][:, 0], [0, 1, 2, 3])
