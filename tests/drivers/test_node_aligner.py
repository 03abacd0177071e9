"""The per-node aligner (drivers/can_decode.py NodeAligner): the numpy join of regular batches gives
exactly what the frame-by-frame rules give, on streams with lost, repeated and reordered frames,
counter wraps, silences and restarts, cut into batches anywhere."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bogiemon.drivers.can_decode import AlignedSamples, NodeAligner, NodeFrames, max_silence_s
from tests.drivers.frames import FS_HZ
from tests.tier import sized

Frame = tuple[int, int, float, int, float]  # channel, counter, value, status bits, receive time


class FrameByFrame(NodeAligner):
    """The plain reference: every batch through the frame-by-frame rules."""

    def push(self, channel, counter, value, status, times_s) -> AlignedSamples:
        return self._push_frame_by_frame(NodeFrames(channel, counter, value, status, times_s))


class Counting(NodeAligner):
    """The aligner under test, counting the batches its numpy path joined."""

    regular = 0

    def _push_regular(self, frames: NodeFrames) -> AlignedSamples | None:
        joined = super()._push_regular(frames)
        self.regular += joined is not None
        return joined


def as_arrays(frames: list[Frame]) -> tuple[np.ndarray, ...]:
    channel, counter, value, status, times_s = zip(*frames, strict=True) if frames else ((),) * 5
    return (np.array(channel, np.int64), np.array(counter, np.int64), np.array(value, np.float64),
            np.array(status, np.uint8), np.array(times_s, np.float64))  # fmt: skip


def assert_same(got: AlignedSamples, expected: AlignedSamples) -> None:
    np.testing.assert_array_equal(got.accel_mps2, expected.accel_mps2)
    np.testing.assert_array_equal(got.status, expected.status)
    np.testing.assert_array_equal(got.new_segment, expected.new_segment)
    np.testing.assert_array_equal(got.times_s, expected.times_s)
    assert (got.duplicates, got.out_of_order, got.lost) == (expected.duplicates, expected.out_of_order, expected.lost)


def join_both(frames: list[Frame], splits: list[int], modulus: int) -> tuple[list[AlignedSamples], list[AlignedSamples], Counting]:
    silence_s = max_silence_s(modulus, FS_HZ)
    fast, reference = Counting(modulus, silence_s), FrameByFrame(modulus, silence_s)
    got, expected = [], []
    i = s = 0
    while i < len(frames):
        batch = as_arrays(frames[i : i + splits[s % len(splits)]])
        got.append(fast.push(*batch))
        expected.append(reference.push(*batch))
        i, s = i + splits[s % len(splits)], s + 1
    return got, expected, fast


def instant_frames(j: int, counter: int, t_s: float, order: list[int]) -> list[Frame]:
    """The three nodes' answers to instant j (values name the instant and the node), in the given order."""
    return [(ch, counter, float(3 * j + ch), (j + ch) % 4, t_s + 1e-5 * position) for position, ch in enumerate(order)]


@st.composite
def node_streams(draw: st.DrawFn, modulus: int) -> tuple[list[Frame], list[int]]:
    """Instants of three nodes with losses, repeats, reordering, wraps, silences and restarts; and batch sizes."""
    silence_s = max_silence_s(modulus, FS_HZ)
    counter = draw(st.integers(0, modulus - 1))
    t_s = 1000.0
    frames: list[Frame] = []
    for j in range(draw(st.integers(1, 300))):
        event = draw(st.sampled_from(["ok"] * 12 + ["drop", "drop_run", "repeat", "late", "swap", "silence", "restart", "skip", "stale"]))
        if event == "silence":
            t_s += silence_s + draw(st.floats(0.001, 1.0))
        elif event == "restart":
            counter = draw(st.integers(0, modulus - 1))
        elif event == "skip":  # the Sync master skipped counters (the nodes never saw them)
            counter = (counter + draw(st.integers(1, modulus - 1))) % modulus
        order = draw(st.permutations([0, 1, 2]))
        instant = instant_frames(j, counter, t_s, order)
        if event == "drop":
            del instant[draw(st.integers(0, 2))]
        elif event == "drop_run":  # one node silent for a while
            node = draw(st.integers(0, 2))
            instant = [f for f in instant if f[0] != node]
        elif event == "repeat":
            instant.append(instant[draw(st.integers(0, 2))])
        elif event == "stale":  # a frame of an instant long past
            instant.insert(0, (draw(st.integers(0, 2)), (counter - draw(st.integers(1, modulus - 1))) % modulus, -1.0, 0, t_s))
        frames += instant
        if event == "late" and len(frames) > 3:  # a frame overtaken by up to 8 later ones
            k = draw(st.integers(1, min(8, len(frames) - 1)))
            frames.insert(len(frames) - 1 - k, frames.pop())
        elif event == "swap" and len(frames) > 4:
            a, b = len(frames) - 1, len(frames) - 1 - draw(st.integers(1, 4))
            frames[a], frames[b] = frames[b], frames[a]
        counter = (counter + 1) % modulus
        t_s += 1 / FS_HZ
    splits = draw(st.lists(st.integers(1, 400), min_size=1, max_size=6))
    return frames, splits


# The slow tier (tests/tier.py): 150 streams per modulus under `make test-slow`; `make test` keeps 25
# of each (a stream draws every kind of damage, so 25 already meet each of them many times).
@pytest.mark.slow_tier
@pytest.mark.parametrize("modulus", [256, 64])
@settings(max_examples=sized(25, 150), deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_the_numpy_join_gives_exactly_the_frame_by_frame_rules(modulus: int, data: st.DataObject) -> None:
    frames, splits = data.draw(node_streams(modulus))
    got, expected, _ = join_both(frames, splits, modulus)
    for g, e in zip(got, expected, strict=True):
        assert_same(g, e)


def clean_frames(n: int, first_counter: int = 250) -> list[Frame]:
    rng = np.random.default_rng(5)
    frames: list[Frame] = []
    for j in range(n):
        frames += instant_frames(j, (first_counter + j) % 256, 1000.0 + j / FS_HZ, rng.permutation(3).tolist())
    return frames


def test_a_clean_stream_is_joined_in_numpy_after_its_first_batch() -> None:
    frames = clean_frames(1000)  # wraps the counter several times
    got, expected, fast = join_both(frames, [37, 250, 3, 500], 256)
    assert fast.regular == len(got) - 1
    values = np.concatenate([g.accel_mps2 for g in got])
    np.testing.assert_array_equal(values, 3 * np.arange(1000)[:, None] + np.arange(3))  # every instant, in order
    for g, e in zip(got, expected, strict=True):
        assert_same(g, e)


def test_a_lost_node_frame_is_joined_in_numpy_too_and_ends_the_segment() -> None:
    frames = clean_frames(400)
    del frames[3 * 200 + 1]  # one node's answer to instant 200
    got, expected, fast = join_both(frames, [100], 256)
    assert fast.regular == len(got) - 1
    assert sum(g.lost for g in got) == 1
    new_segment = np.concatenate([g.new_segment for g in got])
    assert np.flatnonzero(new_segment).tolist() == [0, 200]  # the stream's start, and the instant after the loss
    for g, e in zip(got, expected, strict=True):
        assert_same(g, e)


def test_a_repeated_frame_goes_by_the_frame_by_frame_rules() -> None:
    frames = clean_frames(300)
    frames.insert(3 * 150, frames[3 * 150])
    got, expected, fast = join_both(frames, [100], 256)
    assert fast.regular == len(got) - 2  # the first batch, and the one with the repeat
    assert sum(g.duplicates for g in got) == 1
    for g, e in zip(got, expected, strict=True):
        assert_same(g, e)


def test_a_loss_at_the_end_of_one_batch_starts_the_segment_at_the_next_batchs_first_instant() -> None:
    frames = clean_frames(300)
    at = {(f[0], round(f[2]) // 3): i for i, f in enumerate(frames)}  # (node, instant) -> position
    late = frames[at[2, 201]]  # node 3's answer to instant 201 comes after the first answer to instant 216
    node2_of_200 = frames[at[1, 200]]
    frames = [f for f in frames if f is not late and f is not node2_of_200]
    cut = frames.index(next(f for f in frames if round(f[2]) // 3 == 216)) + 1
    frames.insert(cut, late)
    # A batch ends where instant 200 is given up, 201 still waiting, after instants it delivered
    # (or none); the next begins with 201's last frame. The first batch of all, the segment's
    # start, goes by the frame-by-frame rules.
    for splits in ([30, cut - 30, len(frames)], [30, cut - 31, 1, len(frames)]):
        got, expected, fast = join_both(frames, splits, 256)
        assert fast.regular == len(got) - 1 and got[-2].lost == 1
        assert got[-1].new_segment.tolist() == [True] + [False] * (got[-1].new_segment.size - 1)
        assert got[-1].accel_mps2[0, 0] == 3 * 201
        for g, e in zip(got, expected, strict=True):
            assert_same(g, e)


def test_a_nodes_late_frames_are_counted_afresh_once_its_frames_flow_again() -> None:
    frames = clean_frames(400)
    last_of_node1 = max(i for i, f in enumerate(frames[:300]) if f[0] == 0)
    stale = (0, 10, -1.0, 0, frames[last_of_node1][4])  # node 1's answer to a Sync long past
    frames.insert(last_of_node1 + 1, stale)  # a batch ends with node 1 one behind
    frames[330:330] = [stale] * 3  # three more, after a batch of its regular frames
    ends = [30, last_of_node1 + 2, 330, len(frames)]
    got, expected, fast = join_both(frames, np.diff([0, *ends]).tolist(), 256)
    assert fast.regular == 1  # the batch between the late frames
    assert sum(g.out_of_order for g in got) == 4  # not a restart: the count started again at the regular frames
    assert sum(g.new_segment.sum() for g in got) == 1
    for g, e in zip(got, expected, strict=True):
        assert_same(g, e)
