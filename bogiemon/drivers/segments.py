"""Sequence counters and segments: from numbered samples to gap-aware, uniformly timed Blocks.

Every live format tags each sampling instant with a wrapping sequence counter. SequenceTracker
decides, frame by frame, whether a frame continues the current segment, repeats or precedes
one already taken (dropped), or follows a loss (a new segment starts). SampleQueue keeps the
accepted samples by segment and cuts them into Blocks whose times come from the sample count
within the segment, anchored to the receive time of the segment's first sample: uniform by
construction, never bent by arrival jitter. A Block never spans two segments. TimestampGuard
checks the receive times themselves before any of that: what a source cannot trust never
anchors a segment.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S, Block, HealthCounters, SensorStatus, plausible_time
from bogiemon.drivers.counters import counters

# A stream whose counter runs this many frames in a row behind the last accepted one has
# restarted (a sensor reset or a power cycle): begin a new segment instead of dropping forever.
RESTART_AFTER_BEHIND = 4
# A time stamp may lag the latest accepted one by this much and still pass: frames of two
# interfaces merged into one log, or stamped on different CPUs, arrive a few ms out of order.
# Far below the 0.25 s of half a counter period at 500 Hz, where a counter jump turns ambiguous.
TIME_STAMP_TOLERANCE_S = 0.1
# This many consecutive stamps behind the latest accepted one, and in order among themselves, are
# the clock having stepped back (NTP stepping a gateway's wall clock, which the kernel's receive
# stamps follow), not a bad stamp: from then on the guard follows the new clock.
CLOCK_STEP_AFTER = 8
TIMESTAMP_COUNTERS = counters("bad_timestamps", "clock_steps")


class TimestampGuard:
    """Receive time stamps checked at a source's boundary: finite, plausible, monotonic within a tolerance.

    check(times_s) says which frames of a batch may pass. The others are counted in
    counters.bad_frames and counters.extra["bad_timestamps"] and must be dropped by the caller: a
    stamp that is not finite, lies beyond +/-MAX_TIME_S (drivers/base.py), or is more than
    tolerance_s behind the latest accepted one. CLOCK_STEP_AFTER consecutive stamps behind, in
    order among themselves, are a clock that stepped back: the last of them passes, the guard
    follows the new clock and counts extra["clock_steps"]. A stamp ahead always passes (a pause on
    the bus; the sequence check starts a new segment after a long one).
    """

    def __init__(
        self,
        counters: HealthCounters,
        tolerance_s: float = TIME_STAMP_TOLERANCE_S,
        clock_step_after: int = CLOCK_STEP_AFTER,
    ) -> None:
        if not tolerance_s >= 0 or clock_step_after < 1:
            raise ValueError(f"tolerance_s must be >= 0 and clock_step_after >= 1, got {tolerance_s}, {clock_step_after}")
        self.counters = counters
        self.tolerance_s = tolerance_s
        self.clock_step_after = clock_step_after
        for name in TIMESTAMP_COUNTERS:
            counters.extra.setdefault(name, 0)
        self._latest_s = -np.inf  # the latest stamp accepted so far
        self._behind_n = 0  # consecutive stamps behind it, in order among themselves
        self._behind_latest_s = -np.inf

    def check(self, times_s: NDArray[np.float64]) -> NDArray[np.bool_]:
        """(n,) True where the frame's receive time (n,) seconds may pass; counts the others."""
        times_s = np.asarray(times_s, dtype=np.float64)
        if times_s.size == 0:
            return np.ones(0, dtype=bool)
        if self._behind_n == 0:
            # Fast path, the steady state: every stamp plausible and none behind the running latest.
            with np.errstate(invalid="ignore"):
                plausible = bool((np.abs(times_s) <= MAX_TIME_S).all())  # False for NaN
            if plausible:
                latest = np.maximum.accumulate(np.concatenate([[self._latest_s], times_s]))
                if bool((times_s >= latest[:-1] - self.tolerance_s).all()):
                    self._latest_s = float(latest[-1])
                    return np.ones(times_s.size, dtype=bool)
        return self._check_one_by_one(times_s)

    def _check_one_by_one(self, times_s: NDArray[np.float64]) -> NDArray[np.bool_]:
        accept = np.zeros(times_s.size, dtype=bool)
        for i, time_s in enumerate(times_s.tolist()):
            if not plausible_time(time_s):
                continue
            if time_s >= self._latest_s - self.tolerance_s:
                accept[i] = True
                self._latest_s = max(self._latest_s, time_s)
                self._behind_n = 0
                continue
            if self._behind_n and time_s >= self._behind_latest_s - self.tolerance_s:
                self._behind_n += 1
                self._behind_latest_s = max(self._behind_latest_s, time_s)
            else:
                self._behind_n, self._behind_latest_s = 1, time_s
            if self._behind_n >= self.clock_step_after:
                accept[i] = True
                self._latest_s = self._behind_latest_s
                self._behind_n = 0
                self.counters.add("clock_steps")
        rejected = int(times_s.size - accept.sum())
        if rejected:
            self.counters.bad_frames += rejected
            self.counters.add("bad_timestamps", rejected)
        return accept


@dataclass(frozen=True)
class SequenceVerdict:
    """What SequenceTracker.check decided for each frame of a batch."""

    accept: NDArray[np.bool_]  # (n,) the frame's sample is delivered
    new_segment: NDArray[np.bool_]  # (n,) this accepted frame starts a new segment
    duplicates: int  # same counter as the frame just accepted: dropped
    out_of_order: int  # counter behind the last accepted one: dropped
    lost: int  # frames missing inside forward counter jumps (a lower bound: jumps alias mod `modulus`)


class SequenceTracker:
    """Checks a wrapping sequence counter frame by frame; keeps its state across batches.

    modulus: the counter wraps to 0 after modulus - 1 (256 for 8 bits);
    max_silence_s: a pause between two frames longer than this starts a new segment whatever
      the counters say. It must stay below half a counter period (modulus / 2 / fs_hz): past
      that a jump of k frames is indistinguishable from one of k + modulus.
    """

    def __init__(self, modulus: int, max_silence_s: float) -> None:
        if modulus < 4:
            raise ValueError(f"a sequence counter needs at least 4 values, got modulus {modulus}")
        self.modulus = modulus
        self.max_silence_s = max_silence_s
        self._last: int | None = None  # counter of the last accepted frame; None: next starts a segment
        self._last_time_s = 0.0
        self._behind = 0  # consecutive frames behind the last accepted one

    def restart(self) -> None:
        """The next frame starts a new segment (after a reconnect, a bus-off, a resync)."""
        self._last = None
        self._behind = 0

    def check(self, counters: NDArray[np.int64], times_s: NDArray[np.float64]) -> SequenceVerdict:
        """Classify a batch of frames in arrival order: counters (n,), receive times (n,) in seconds."""
        counters = np.asarray(counters, dtype=np.int64)
        times_s = np.asarray(times_s, dtype=np.float64)
        n = counters.shape[0]
        if n and self._last is not None and self._behind == 0:
            # Fast path, the steady state: every counter one more than the previous, no pause.
            prev = np.empty(n, dtype=np.int64)
            prev[0] = self._last
            prev[1:] = counters[:-1]
            step = (counters - prev) % self.modulus
            pause_s = np.diff(times_s, prepend=self._last_time_s)
            if bool((step == 1).all()) and bool((pause_s <= self.max_silence_s).all()):
                self._last = int(counters[-1])
                self._last_time_s = float(times_s[-1])
                return SequenceVerdict(np.ones(n, bool), np.zeros(n, bool), 0, 0, 0)
        return self._check_frame_by_frame(counters, times_s)

    def _check_frame_by_frame(self, counters: NDArray[np.int64], times_s: NDArray[np.float64]) -> SequenceVerdict:
        n = counters.shape[0]
        accept = np.zeros(n, bool)
        new_segment = np.zeros(n, bool)
        duplicates = out_of_order = lost = 0
        half = self.modulus // 2
        for i, (counter, time_s) in enumerate(zip(counters.tolist(), times_s.tolist(), strict=True)):
            if self._last is None or time_s - self._last_time_s > self.max_silence_s:
                new_segment[i] = True
            else:
                step = (counter - self._last) % self.modulus
                if step == 0:
                    duplicates += 1
                    continue
                if step > half:
                    self._behind += 1
                    if self._behind < RESTART_AFTER_BEHIND:
                        out_of_order += 1
                        continue
                    new_segment[i] = True
                elif step > 1:
                    lost += step - 1
                    new_segment[i] = True
            accept[i] = True
            self._last = counter
            self._last_time_s = time_s
            self._behind = 0
        return SequenceVerdict(accept, new_segment, duplicates, out_of_order, lost)


@dataclass
class _Segment:
    anchor_s: float  # receive time of the segment's first sample
    chunks: list[NDArray[np.float64]] = field(default_factory=list)
    status_chunks: list[NDArray[np.uint8]] = field(default_factory=list)
    n_pending: int = 0
    n_taken: int = 0  # samples already handed out as Blocks


class SampleQueue:
    """Accepted samples by segment, handed out as Blocks of at most max_n samples.

    Status bits per sample are (n, 3) uint8 with SensorStatus values; a Block carries their OR.
    The first Block of every segment has gap_before=True (the first of all included: the stream
    started there); `gaps` counts those after the first, the discontinuities proper.
    """

    def __init__(self, fs_hz: float) -> None:
        self.fs_hz = fs_hz
        self._segments: deque[_Segment] = deque()
        self._open = False  # the last segment may still grow
        self._blocks_out = 0
        self.gaps = 0

    @property
    def n_pending(self) -> int:
        return sum(s.n_pending for s in self._segments)

    def close_segment(self) -> None:
        """Whatever arrives next belongs to a new segment."""
        self._open = False

    def discard(self) -> None:
        """Drop every sample not handed out yet; what arrives next starts afresh, as the first
        samples did (its first Block is not counted in `gaps`)."""
        self._segments.clear()
        self._open = False
        self._blocks_out = 0

    def append(
        self,
        accel_mps2: NDArray[np.float64],
        status: NDArray[np.uint8],
        new_segment: NDArray[np.bool_],
        times_s: NDArray[np.float64],
    ) -> None:
        """Add accepted samples (m, 3) in order; new_segment[i] starts a segment at sample i."""
        m = accel_mps2.shape[0]
        if m == 0:
            return
        starts = np.flatnonzero(new_segment)
        if not self._open and (starts.size == 0 or starts[0] != 0):
            starts = np.concatenate([[0], starts])
        bounds = np.concatenate([starts, [m]])
        if bounds[0] > 0:  # the head continues the open segment
            self._extend(self._segments[-1], accel_mps2[: bounds[0]], status[: bounds[0]])
        for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True):
            segment = _Segment(anchor_s=float(times_s[lo]))
            self._extend(segment, accel_mps2[lo:hi], status[lo:hi])
            self._segments.append(segment)
        self._open = True

    def _drop_drained(self) -> None:
        """Forget the ended segments whose samples have all gone out. A drained segment at the head
        must never hide those behind it: a source would then wait on its device for each of them,
        one segment per read's timeout, and fall behind after every burst of errors."""
        while len(self._segments) > 1 and self._segments[0].n_pending == 0:
            self._segments.popleft()

    @staticmethod
    def _extend(segment: _Segment, accel: NDArray[np.float64], status: NDArray[np.uint8]) -> None:
        if accel.shape[0]:
            segment.chunks.append(np.array(accel, dtype=np.float64))
            segment.status_chunks.append(np.array(status, dtype=np.uint8))
            segment.n_pending += accel.shape[0]

    def full_block_ready(self, max_n: int) -> bool:
        """A Block can go out now: max_n samples are waiting, or the oldest segment with samples has ended."""
        self._drop_drained()
        if not self._segments:
            return False
        first = self._segments[0]
        return first.n_pending >= max_n or (len(self._segments) > 1 and first.n_pending > 0)

    def take(self, max_n: int) -> Block | None:
        """The next Block of at most max_n samples from the oldest segment, or None if empty."""
        self._drop_drained()
        if not self._segments or self._segments[0].n_pending == 0:
            return None  # nothing, or the open segment drained
        segment = self._segments[0]
        accel = np.concatenate(segment.chunks) if len(segment.chunks) > 1 else segment.chunks[0]
        status = np.concatenate(segment.status_chunks) if len(segment.status_chunks) > 1 else segment.status_chunks[0]
        n = min(max_n, accel.shape[0])
        segment.chunks = [accel[n:]] if n < accel.shape[0] else []
        segment.status_chunks = [status[n:]] if n < accel.shape[0] else []
        bits = np.bitwise_or.reduce(status[:n], axis=0) if n else np.zeros(3, np.uint8)
        block = Block(
            start_s=segment.anchor_s + segment.n_taken / self.fs_hz,
            fs_hz=self.fs_hz,
            accel_mps2=accel[:n],
            gap_before=segment.n_taken == 0,
            status=(SensorStatus(int(bits[0])), SensorStatus(int(bits[1])), SensorStatus(int(bits[2]))),
        )
        segment.n_taken += n
        segment.n_pending -= n
        if block.gap_before and self._blocks_out:
            self.gaps += 1
        self._blocks_out += 1
        return block
