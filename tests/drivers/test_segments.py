"""Sequence counters and segments: every counter anomaly classified, fast path equal to the frame-by-frame one."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.base import SensorStatus
from bogiemon.drivers.segments import RESTART_AFTER_BEHIND, SampleQueue, SequenceTracker

FS_HZ = 500.0
SILENCE_S = 127 / FS_HZ


def check(counters: list[int], times_s: list[float] | None = None, modulus: int = 256) -> tuple:
    tracker = SequenceTracker(modulus, SILENCE_S)
    times = np.arange(len(counters)) / FS_HZ if times_s is None else np.array(times_s)
    v = tracker.check(np.array(counters), times)
    return v.accept.tolist(), v.new_segment.tolist(), v.duplicates, v.out_of_order, v.lost


def test_a_contiguous_stream_across_the_wrap_is_one_segment() -> None:
    accept, new, *counts = check([254, 255, 0, 1])
    assert accept == [True] * 4 and new == [True, False, False, False] and counts == [0, 0, 0]


def test_a_counter_jump_starts_a_segment_and_counts_the_lost_frames() -> None:
    assert check([10, 11, 14, 15]) == ([True] * 4, [True, False, True, False], 0, 0, 2)


def test_a_repeated_counter_is_dropped_as_a_duplicate() -> None:
    assert check([10, 11, 11, 12]) == ([True, True, False, True], [True, False, False, False], 1, 0, 0)


def test_a_late_frame_is_dropped_as_out_of_order() -> None:
    # 13 arrives after 14: 14 started a segment (13 was missing then), the late 13 is dropped.
    assert check([11, 12, 14, 13, 15]) == ([True, True, True, False, True], [True, False, True, False, False], 0, 1, 1)


def test_a_counter_that_restarts_from_zero_starts_a_segment_after_a_few_frames() -> None:
    counters = [100, 101, 0, 1, 2, 3, 4]
    accept, new, dup, ooo, lost = check(counters)
    assert ooo == RESTART_AFTER_BEHIND - 1
    assert accept == [True, True] + [False] * (RESTART_AFTER_BEHIND - 1) + [True] * (5 - RESTART_AFTER_BEHIND + 1)
    assert new.index(True, 1) == 2 + RESTART_AFTER_BEHIND - 1


def test_a_pause_longer_than_half_a_counter_period_starts_a_segment_whatever_the_counter() -> None:
    # 256 frames lost exactly: the counter looks contiguous, the receive times do not.
    times = [0.0, 0.002, 0.002 + 257 / FS_HZ]
    assert check([5, 6, 7], times) == ([True] * 3, [True, False, True], 0, 0, 0)


@st.composite
def counter_streams(draw: st.DrawFn) -> tuple[list[int], list[float], list[int]]:
    """Counters mostly +1 with drops, repeats, swaps, restarts and pauses; and batch sizes."""
    counters, times = [], []
    c, t = draw(st.integers(0, 255)), 0.0
    for _ in range(draw(st.integers(1, 120))):
        event = draw(st.sampled_from(["next"] * 6 + ["skip", "repeat", "back", "restart", "pause"]))
        if event == "skip":
            c += draw(st.integers(2, 200))
        elif event == "back":
            c -= draw(st.integers(1, 5))
        elif event == "restart":
            c = 0
        elif event == "pause":
            t += draw(st.floats(0.1, 2.0))
            c += 1
        elif event == "next":
            c += 1
        c %= 256
        t += 1 / FS_HZ
        counters.append(c)
        times.append(t)
    splits = draw(st.lists(st.integers(1, 40), min_size=1, max_size=10))
    return counters, times, splits


@settings(max_examples=200, deadline=None)
@given(stream=counter_streams())
def test_batched_checks_equal_the_frame_by_frame_reference(stream: tuple[list[int], list[float], list[int]]) -> None:
    counters, times, splits = stream
    reference = SequenceTracker(256, SILENCE_S)
    ref = reference._check_frame_by_frame(np.array(counters), np.array(times))
    tracker = SequenceTracker(256, SILENCE_S)
    accept, new, totals = [], [], np.zeros(3, int)
    i, s = 0, 0
    while i < len(counters):
        j = min(len(counters), i + splits[s % len(splits)])
        v = tracker.check(np.array(counters[i:j]), np.array(times[i:j]))
        accept += v.accept.tolist()
        new += v.new_segment.tolist()
        totals += (v.duplicates, v.out_of_order, v.lost)
        i, s = j, s + 1
    assert accept == ref.accept.tolist()
    assert new == ref.new_segment.tolist()
    assert totals.tolist() == [ref.duplicates, ref.out_of_order, ref.lost]
    # Accepted counters are +1 steps inside every segment: nothing bridged.
    kept = np.array(counters)[np.array(accept)]
    starts = np.array(new)[np.array(accept)]
    assert all((b - a) % 256 == 1 for a, b, s in zip(kept[:-1], kept[1:], starts[1:], strict=True) if not s)


def test_queue_cuts_blocks_at_segment_boundaries_with_times_from_the_sample_count() -> None:
    queue = SampleQueue(FS_HZ)
    accel = np.arange(30, dtype=float).reshape(10, 3)
    status = np.zeros((10, 3), np.uint8)
    status[2, 1] = SensorStatus.OVER_RANGE
    new = np.zeros(10, bool)
    new[[0, 6]] = True
    times = 50.0 + np.arange(10) / FS_HZ + 0.0007 * np.arange(10) % 0.001  # arrival jitter is ignored
    times[6] = 60.0
    queue.append(accel, status, new, times)
    first = queue.take(4)
    assert (first.start_s, first.n_samples, first.gap_before) == (times[0], 4, True)
    assert first.status == (SensorStatus.OK, SensorStatus.OVER_RANGE, SensorStatus.OK)
    second = queue.take(4)  # the segment ends after two more samples
    assert (second.start_s, second.n_samples, second.gap_before) == pytest.approx((times[0] + 4 / FS_HZ, 2, False))
    third = queue.take(4)
    assert (third.start_s, third.n_samples, third.gap_before) == (60.0, 4, True)
    assert queue.take(4) is None
    assert queue.gaps == 1
    np.testing.assert_array_equal(np.concatenate([first.accel_mps2, second.accel_mps2, third.accel_mps2]), accel)


def test_queue_continues_the_open_segment_across_appends() -> None:
    queue = SampleQueue(FS_HZ)
    for lo in (0, 3):
        new = np.zeros(3, bool)
        new[0] = lo == 0
        queue.append(np.ones((3, 3)) * lo, np.zeros((3, 3), np.uint8), new, 7.0 + np.arange(lo, lo + 3) / FS_HZ)
    block = queue.take(100)
    assert (block.n_samples, block.start_s, block.gap_before) == (6, 7.0, True)
    queue.close_segment()
    queue.append(np.ones((1, 3)), np.zeros((1, 3), np.uint8), np.zeros(1, bool), np.array([9.0]))
    assert queue.take(100).gap_before and queue.gaps == 1
