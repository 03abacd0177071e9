"""The replay of a CAN log (drivers/canlog.py: every format, read through the bounded open): its
frames decoded with the DBC through the same CanFrameDecoder as the live CAN source, so that a log
with lost, repeated or foreign frames, or frames with unusable time stamps, is counted and
segmented exactly as on the bus; paced by the log's own time stamps (drivers/replay.py says how)."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S, Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.can_frames import FrameBatch
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.canlog import LogFrames
from bogiemon.drivers.counters import counters
from bogiemon.drivers.files import UntrustedFile
from bogiemon.drivers.segments import SampleQueue

REPLAY_COUNTERS = counters("unreadable_entries")
# The longest silence of a CAN log a paced replay waits out (a wagon standing at a station, or a
# stamp far ahead of its neighbours): the decoder starts a new segment after a pause of half a
# counter period whatever its length, so waiting longer would change nothing but the wall time.
MAX_PACED_PAUSE_S = 10.0


class CanLogReplaySource(Source):
    """A CAN log (any format of drivers/canlog.py) decoded with the DBC layout, paced by the log's
    own time stamps.

    start_s: the log's start from its own header where it has one (ASC's date, BLF's and MF4's
    start), else None; relative: its times count from the log's start (an ASC without a date).
    """

    finite = True

    def __init__(
        self,
        path: str | Path | UntrustedFile,
        layout: CanLayout,
        fs_hz: float,
        rate: float = 1.0,
        max_block_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.path = path.path if isinstance(path, UntrustedFile) else Path(path)
        self.fs_hz = fs_hz
        self.layout = layout
        self.rate = rate
        self.counters = HealthCounters()
        for name in REPLAY_COUNTERS:
            self.counters.extra[name] = 0
        self.max_block_n = max(1, round(max_block_s * fs_hz))
        self._clock = clock
        self._sleep = sleep
        self._queue = SampleQueue(fs_hz)
        self._decoder = CanFrameDecoder(layout, fs_hz, self.counters, self._queue)
        self._log = LogFrames(path, self._unreadable)
        self.format = self._log.format
        self._batches: Iterator[FrameBatch] = iter(self._log)
        self._pending = FrameBatch.empty()  # read, not yet due
        self._pending_paced_s = np.zeros(0)  # their pacing times: log seconds from the first frame
        self._ended = False
        self._pace = _Pace()
        self._start_wall_s: float | None = None

    @property
    def start_s(self) -> float | None:
        return self._log.start_s

    @property
    def fraction_read(self) -> float:
        """How much of the log's file has been read, 0 to 1 (for a progress bar)."""
        return self._log.fraction_read

    @property
    def relative(self) -> bool:
        return self._log.relative

    def _unreadable(self, message: str) -> None:
        self.counters.bad_frames += 1
        self.counters.add("unreadable_entries")
        self.last_error = message

    def _fill(self) -> bool:
        """Read the next batch of the log into the pending frames; False at its end."""
        if self._ended:
            return False
        batch = next(self._batches, None)
        if batch is None:
            self._ended = True
            return False
        paced_s = self._pace.offsets(batch.time_s)
        if self._pending.n:
            batch = _concatenate([self._pending, batch])
            paced_s = np.concatenate([self._pending_paced_s, paced_s])
        self._pending, self._pending_paced_s = batch, paced_s
        return True

    def _due_n(self, wanted: int) -> int:
        """How many of the first `wanted` pending frames are due now."""
        if self.rate == 0:
            return min(wanted, self._pending.n)
        if self._start_wall_s is None:
            self._start_wall_s = self._clock()
        log_s = (self._clock() - self._start_wall_s) * self.rate
        return int(np.searchsorted(self._pending_paced_s[:wanted], log_s, side="right"))

    def read(self, timeout_s: float) -> Block | None:
        deadline = self._clock() + timeout_s
        while not self._queue.full_block_ready(self.max_block_n):
            wanted = max(1, self.max_block_n - self._queue.n_pending) * self.layout.frames_per_instant
            if self._pending.n < wanted and self._fill():
                continue
            due = self._due_n(wanted)
            if due:
                self._decoder.feed_frames(self._pending[:due])
                self._pending, self._pending_paced_s = self._pending[due:], self._pending_paced_s[due:]
                continue
            if self._pending.n == 0:
                break  # the log has ended
            left_s = deadline - self._clock()
            if left_s <= 0:
                break
            assert self._start_wall_s is not None
            due_wall_s = self._start_wall_s + float(self._pending_paced_s[0]) / self.rate
            self._sleep(max(1e-4, min(left_s, due_wall_s - self._clock())))
        block = self._queue.take(self.max_block_n)
        self.counters.gaps = self._queue.gaps
        if block is None:
            if self._ended and self._pending.n == 0:
                raise EndOfStream
            self.counters.timeouts += 1
        return block

    def close(self) -> None:
        self._log.close()


class _Pace:
    """The pacing time of a log's frames: seconds from its first frame, following only plausible
    stamps, a stamp behind its predecessor due with it, a silence longer than MAX_PACED_PAUSE_S
    paced as that long (a stamp from next century never stalls a replay)."""

    def __init__(self) -> None:
        self.last_s: float | None = None  # the latest plausible stamp seen
        self.paced_s = 0.0

    def offsets(self, time_s: NDArray[np.float64]) -> NDArray[np.float64]:
        with np.errstate(invalid="ignore"):
            plausible = np.abs(time_s) <= MAX_TIME_S  # False for NaN
        if not plausible.any():
            return np.full(time_s.shape[0], self.paced_s)
        if self.last_s is None:
            self.last_s = float(time_s[np.argmax(plausible)])
        # Each frame's latest plausible stamp so far (an implausible one repeats its predecessor's).
        index = np.where(plausible, np.arange(time_s.shape[0]), -1)
        np.maximum.accumulate(index, out=index)
        known = np.concatenate([[self.last_s], time_s])[index + 1]
        steps = np.clip(np.diff(known, prepend=self.last_s), 0.0, MAX_PACED_PAUSE_S)
        offsets = self.paced_s + np.cumsum(steps)
        self.paced_s = float(offsets[-1])
        self.last_s = float(known[-1])
        return offsets


def _concatenate(parts: list[FrameBatch]) -> FrameBatch:
    return FrameBatch(
        np.concatenate([p.time_s for p in parts]), np.concatenate([p.key for p in parts]), np.concatenate([p.length for p in parts]),
        np.concatenate([p.data for p in parts]), np.concatenate([p.flags for p in parts]),
    )  # fmt: skip
