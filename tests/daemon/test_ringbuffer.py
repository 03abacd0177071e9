"""The ring between source and core: bounded, lossless in order, drops counted with a gap after."""

import threading

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.daemon.ringbuffer import BlockRing, RingClosed
from bogiemon.drivers.base import Block, SensorStatus


def block(start: int, n: int, gap: bool = False, status=(SensorStatus.OK,) * 3) -> Block:
    data = np.arange(start, start + n, dtype=float)[:, None] * [1.0, -1.0, 2.0]
    return Block(start_s=start / 100, fs_hz=100.0, accel_mps2=data, gap_before=gap, status=status)


@settings(max_examples=60, deadline=None)
@given(sizes=st.lists(st.integers(1, 40), min_size=1, max_size=40), capacity=st.integers(40, 120), reads_every=st.integers(1, 4))
def test_blocks_come_out_as_they_went_in_across_the_wrap(sizes: list[int], capacity: int, reads_every: int) -> None:
    ring = BlockRing(capacity, max_blocks=8)
    sent, got, pos = [], [], 0
    for i, n in enumerate(sizes):
        b = block(pos, n, gap=(i % 5 == 0), status=(SensorStatus.OK, SensorStatus(i % 4), SensorStatus.OK))
        pos += n
        if ring.put(b):
            sent.append(b)
        if i % reads_every == 0:
            while (out := ring.get(timeout_s=0)) is not None:
                got.append(out)
    ring.close()
    while True:
        try:
            out = ring.get(timeout_s=0)
        except RingClosed:
            break
        assert out is not None
        got.append(out)
    assert len(got) == len(sent) == ring.counters.blocks_out
    for a, b in zip(got, sent, strict=True):
        np.testing.assert_array_equal(a.accel_mps2, b.accel_mps2)
        assert (a.start_s, a.fs_hz, a.status) == (b.start_s, b.fs_hz, b.status)
        assert a.gap_before >= b.gap_before  # a drop before it may add a gap, never remove one


def test_a_full_ring_drops_counts_and_marks_the_next_block_as_after_a_gap() -> None:
    ring = BlockRing(10)
    assert ring.put(block(0, 8))
    assert not ring.put(block(8, 5))
    assert ring.counters.overflows == 1 and ring.counters.samples_dropped == 5
    assert ring.get(timeout_s=0).gap_before is False
    assert ring.put(block(13, 5))
    assert ring.get(timeout_s=0).gap_before is True


def test_backpressure_waits_for_room_instead_of_dropping() -> None:
    ring = BlockRing(10, backpressure=True)
    ring.put(block(0, 8))
    assert ring.put(block(8, 5), timeout_s=0.01) is False  # timed out: nothing dropped
    assert ring.counters.overflows == 0
    reader = threading.Timer(0.05, ring.get, kwargs={"timeout_s": 1})
    reader.start()
    assert ring.put(block(8, 5), timeout_s=2.0) is True
    reader.join()


def test_blocks_pass_without_a_copy_and_the_ring_holds_at_most_its_capacity() -> None:
    ring = BlockRing(20, max_blocks=3)
    sent = [block(i * 7, 7) for i in range(4)]
    assert [ring.put(b) for b in sent] == [True, True, False, False]  # 14 samples held; a third block would make 21
    first = ring.get(timeout_s=0)
    assert first is sent[0] and first.accel_mps2 is sent[0].accel_mps2
    assert ring.put(sent[2]) and ring.put(block(28, 7)) is False  # 14 + 7 > 20: dropped
    second, third = ring.get(timeout_s=0), ring.get(timeout_s=0)
    assert second is sent[1]
    assert third.accel_mps2 is sent[2].accel_mps2 and third.gap_before  # after a drop: the same samples, a gap


def test_the_ring_holds_at_most_max_blocks() -> None:
    ring = BlockRing(1000, max_blocks=2)
    assert [ring.put(block(i, 1)) for i in range(3)] == [True, True, False]


def test_get_times_out_empty_and_raises_once_closed_and_drained() -> None:
    ring = BlockRing(10)
    assert ring.get(timeout_s=0.01) is None
    ring.put(block(0, 3))
    ring.close()
    assert ring.get(timeout_s=0).n_samples == 3
    with pytest.raises(RingClosed):
        ring.get(timeout_s=0)


def test_an_oversized_block_is_a_bug() -> None:
    with pytest.raises(ValueError, match="cannot fit"):
        BlockRing(10).put(block(0, 11))
