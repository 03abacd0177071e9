"""Replay sources: a CSV recording or a CAN log played back as if live, then EndOfStream.

CSV recordings (drivers/recording.py) come back as they were written: the block times are the
file's time_s. CAN logs are anything python-can reads by suffix (candump -L .log, Vector .asc
and .blf, ...), decoded with the DBC through the same CanFrameDecoder as the live CAN source, so
a log with lost, repeated or foreign frames is counted and segmented exactly as on the bus; the
block times come from the log's time stamps (absolute in .log and .blf, from 0 in .asc).

rate 1 paces the samples at real time (a sample is delivered once its time, counted from the
first read(), has come); rate N is N times faster; rate 0 delivers as fast as the caller reads.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import numpy as np

from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.recording import RecordingError, read_csv_recording
from bogiemon.drivers.segments import SampleQueue


class CsvReplaySource(Source):
    """A CSV recording, block by block, at real-time pace (rate 1), N times faster, or unpaced (0)."""

    finite = True

    def __init__(
        self,
        path: str | Path,
        rate: float = 1.0,
        max_block_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.recording = read_csv_recording(path)
        self.fs_hz = self.recording.fs_hz
        self.counters = HealthCounters()
        self.rate = rate
        self.max_block_n = max(1, round(max_block_s * self.fs_hz))
        self._clock = clock
        self._sleep = sleep
        self._next = 0
        self._start_wall_s: float | None = None

    def _due_n(self) -> int:
        """Samples whose time has come (all of them when unpaced)."""
        rec = self.recording
        if self.rate == 0:
            return rec.n_samples
        if self._start_wall_s is None:
            self._start_wall_s = self._clock()
        data_s = rec.time_s[0] + (self._clock() - self._start_wall_s) * self.rate
        return int(np.searchsorted(rec.time_s, data_s, side="right"))

    def read(self, timeout_s: float) -> Block | None:
        rec = self.recording
        if self._next >= rec.n_samples:
            raise EndOfStream
        deadline = self._clock() + timeout_s
        while True:
            due = self._due_n()
            ready = min(due, self._next + self.max_block_n)
            if ready - self._next == self.max_block_n or ready == rec.n_samples:
                break
            left_s = deadline - self._clock()
            if left_s <= 0:
                break
            assert self._start_wall_s is not None
            wanted = min(self._next + self.max_block_n, rec.n_samples) - 1
            due_wall_s = self._start_wall_s + (rec.time_s[wanted] - rec.time_s[0]) / self.rate
            self._sleep(max(1e-4, min(left_s, due_wall_s - self._clock())))
        if ready == self._next:
            self.counters.timeouts += 1
            return None
        block = Block(
            start_s=float(rec.time_s[self._next]),
            fs_hz=self.fs_hz,
            accel_mps2=rec.accel_mps2[self._next : ready],
            gap_before=self._next == 0,
        )
        self._next = ready
        self.counters.frames += block.n_samples
        return block


class CanLogReplaySource(Source):
    """A CAN log decoded with the DBC layout, paced by the log's own time stamps."""

    finite = True

    def __init__(
        self,
        path: str | Path,
        layout: CanLayout,
        fs_hz: float,
        rate: float = 1.0,
        max_block_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.path = Path(path)
        self.fs_hz = fs_hz
        self.layout = layout
        self.rate = rate
        self.counters = HealthCounters()
        self.max_block_n = max(1, round(max_block_s * fs_hz))
        self._clock = clock
        self._sleep = sleep
        self._queue = SampleQueue(fs_hz)
        self._decoder = CanFrameDecoder(layout, fs_hz, self.counters, self._queue)
        try:
            self._reader = can.LogReader(str(self.path))
        except ValueError:  # python-can names no reader for the suffix
            raise RecordingError(
                f"{self.path}: not a recording bogiemon replays: use a .csv recording or a CAN log "
                "(.log from candump -L, .asc, .blf)"
            ) from None
        except OSError as exc:
            raise RecordingError(f"{self.path}: cannot read the CAN log: {exc.strerror or exc}") from None
        self._frames: Iterator[can.Message] = iter(self._reader)
        self._peeked: can.Message | None = None
        self._ended = False
        self._first_log_s: float | None = None
        self._start_wall_s = 0.0

    def _peek(self) -> can.Message | None:
        if self._peeked is None and not self._ended:
            try:
                self._peeked = next(self._frames)
            except StopIteration:
                self._ended = True
            except Exception as exc:  # noqa: BLE001 - each python-can reader raises its own kind for a bad line
                # The reader cannot go on past a line it fails on: count it, end the stream there.
                self.counters.bad_frames += 1
                self.last_error = f"{self.path}: unreadable CAN log entry, replay ends here: {exc}"
                self._ended = True
        return self._peeked

    def _due(self, message: can.Message) -> bool:
        if self.rate == 0:
            return True
        if self._first_log_s is None:
            self._first_log_s = message.timestamp
            self._start_wall_s = self._clock()
        return (message.timestamp - self._first_log_s) / self.rate <= self._clock() - self._start_wall_s

    def read(self, timeout_s: float) -> Block | None:
        deadline = self._clock() + timeout_s
        while not self._queue.full_block_ready(self.max_block_n):
            wanted = max(1, self.max_block_n - self._queue.n_pending) * self.layout.frames_per_instant
            batch: list[can.Message] = []
            while len(batch) < wanted:
                message = self._peek()
                if message is None or not self._due(message):
                    break
                batch.append(message)
                self._peeked = None
            self._decoder.feed(batch)
            if self._ended or batch:
                if self._ended:
                    break
                continue
            left_s = deadline - self._clock()
            if left_s <= 0:
                break
            message = self._peek()
            if message is not None:
                assert self._first_log_s is not None
                due_wall_s = self._start_wall_s + (message.timestamp - self._first_log_s) / self.rate
                self._sleep(max(1e-4, min(left_s, due_wall_s - self._clock())))
        block = self._queue.take(self.max_block_n)
        self.counters.gaps = self._queue.gaps
        if block is None:
            if self._ended:
                raise EndOfStream
            self.counters.timeouts += 1
        return block

    def close(self) -> None:
        self._reader.stop()


def open_replay(
    path: str | Path,
    rate: float,
    layout: CanLayout | None,
    fs_hz: float,
    max_block_s: float = 1.0,
) -> Source:
    """The replay source for a file: a .csv recording, or a CAN log decoded with layout."""
    if Path(path).suffix.lower() == ".csv":
        return CsvReplaySource(path, rate=rate, max_block_s=max_block_s)
    if layout is None:
        raise RecordingError(f"{path}: a CAN log needs a DBC layout to be decoded")
    return CanLogReplaySource(path, layout, fs_hz, rate=rate, max_block_s=max_block_s)
