"""Sequence counters, segments and time stamps: every anomaly classified, fast paths equal to the plain references."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.base import MAX_TIME_S, Block, HealthCounters, SensorStatus
from bogiemon.drivers.segments import (
    CLOCK_STEP_AFTER,
    RESTART_AFTER_BEHIND,
    TIME_STAMP_TOLERANCE_S,
    SampleQueue,
    SequenceTracker,
    TimestampGuard,
)

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


# --- TimestampGuard: receive times checked at the source boundary --------------------------------


def guard_reference(times_s: list[float], tolerance_s: float = TIME_STAMP_TOLERANCE_S, step_after: int = CLOCK_STEP_AFTER) -> tuple[list[bool], int]:
    """The guard's rule written out plainly, one stamp at a time: (passed, clock steps)."""
    latest, run, run_latest, steps, passed = -math.inf, 0, -math.inf, 0, []
    for t in times_s:
        if not (math.isfinite(t) and abs(t) <= MAX_TIME_S):
            passed.append(False)
        elif t >= latest - tolerance_s:
            passed.append(True)
            latest, run = max(latest, t), 0
        else:
            run, run_latest = (run + 1, max(run_latest, t)) if run and t >= run_latest - tolerance_s else (1, t)
            if run >= step_after:
                passed.append(True)
                latest, run, steps = run_latest, 0, steps + 1
            else:
                passed.append(False)
    return passed, steps


def guard_check(times_s: list[float]) -> tuple[list[bool], HealthCounters]:
    counters = HealthCounters()
    return TimestampGuard(counters).check(np.array(times_s)).tolist(), counters


def test_a_monotonic_stream_of_time_stamps_passes_whole_and_counts_nothing() -> None:
    passed, counters = guard_check((1.7e9 + np.arange(50) / FS_HZ).tolist())
    assert passed == [True] * 50
    assert counters.bad_frames == counters.extra["bad_timestamps"] == counters.extra["clock_steps"] == 0


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, 1e300, -1e300, MAX_TIME_S * 1.0001])
def test_a_non_finite_or_implausible_time_stamp_is_dropped_and_counted(bad: float) -> None:
    passed, counters = guard_check([10.0, 10.002, bad, 10.006])
    assert passed == [True, True, False, True]
    assert counters.bad_frames == counters.extra["bad_timestamps"] == 1


def test_a_nan_first_time_stamp_is_dropped_and_the_next_one_anchors_the_stream() -> None:
    passed, counters = guard_check([math.nan, 1.7e9, 1.7e9 + 0.002])
    assert passed == [False, True, True] and counters.extra["bad_timestamps"] == 1


def test_a_stamp_behind_beyond_the_tolerance_is_dropped_one_within_passes() -> None:
    t = 100.0
    passed, counters = guard_check([t, t + 0.2, t + 0.2 - TIME_STAMP_TOLERANCE_S / 2, t + 0.2 - 2 * TIME_STAMP_TOLERANCE_S, t + 0.21])
    assert passed == [True, True, True, False, True]
    assert counters.extra["bad_timestamps"] == 1 and counters.extra["clock_steps"] == 0


def test_a_clock_stepped_back_is_followed_after_clock_step_after_stamps() -> None:
    before = [500.0 + i / FS_HZ for i in range(5)]
    after = [100.0 + i / FS_HZ for i in range(CLOCK_STEP_AFTER + 3)]
    passed, counters = guard_check(before + after)
    assert passed == [True] * 5 + [False] * (CLOCK_STEP_AFTER - 1) + [True] * 4
    assert counters.extra["bad_timestamps"] == CLOCK_STEP_AFTER - 1 and counters.extra["clock_steps"] == 1


@st.composite
def stamp_streams(draw: st.DrawFn) -> tuple[list[float], list[int]]:
    """Mostly increasing stamps with bad values, stamps behind, clock steps both ways; and batch sizes."""
    t, out = draw(st.sampled_from([0.0, 1.7e9])), []
    for _ in range(draw(st.integers(1, 150))):
        event = draw(st.sampled_from(["next"] * 8 + ["bad", "behind", "step_back", "jitter", "pause"]))
        if event == "bad":
            out.append(draw(st.sampled_from([math.nan, math.inf, -math.inf, 1e300])))
            continue
        if event == "behind":
            out.append(t - draw(st.floats(0.0, 5.0)))
            continue
        if event == "step_back":
            t -= draw(st.floats(0.2, 100.0))
        elif event == "jitter":
            t -= draw(st.floats(0.0, 0.15))
        elif event == "pause":
            t += draw(st.floats(0.2, 1000.0))
        t += 1 / FS_HZ
        out.append(t)
    return out, draw(st.lists(st.integers(1, 40), min_size=1, max_size=10))


@settings(max_examples=200, deadline=None)
@given(stream=stamp_streams())
def test_the_batched_guard_equals_the_plain_reference(stream: tuple[list[float], list[int]]) -> None:
    times, splits = stream
    counters = HealthCounters()
    guard = TimestampGuard(counters)
    passed: list[bool] = []
    i = s = 0
    while i < len(times):
        j = min(len(times), i + splits[s % len(splits)])
        passed += guard.check(np.array(times[i:j])).tolist()
        i, s = j, s + 1
    want, steps = guard_reference(times)
    assert passed == want
    assert counters.extra["bad_timestamps"] == counters.bad_frames == want.count(False)
    assert counters.extra["clock_steps"] == steps


@pytest.mark.parametrize(("start_s", "fs_hz"), [(math.nan, FS_HZ), (math.inf, FS_HZ), (0.0, math.inf), (0.0, 0.0)])
def test_a_block_with_a_time_or_rate_that_is_not_finite_is_refused_as_a_driver_bug(start_s: float, fs_hz: float) -> None:
    with pytest.raises(ValueError, match="must be finite"):
        Block(start_s=start_s, fs_hz=fs_hz, accel_mps2=np.zeros((4, 3)))
