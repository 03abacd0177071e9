"""Replay sources: a recording of samples or a CAN log played back as if live, then EndOfStream.

Recordings of samples (drivers/recording.py: .csv, .csv.gz, .parquet) come back as they were
written, read as they are replayed: the block times are the file's time_s. CAN logs are anything
python-can reads by suffix (candump -L .log, Vector .asc and .blf, ...), decoded with the DBC through the same
CanFrameDecoder as the live CAN source, so a log with lost, repeated or foreign frames, or frames
with unusable time stamps, is counted and segmented exactly as on the bus; the block times come
from the log's time stamps (absolute in .log and .blf, from 0 in .asc).

A line python-can cannot parse is counted (bad_frames and extra["unreadable_entries"]) and
skipped: the text logs (.log, .asc) are read on from the next line. A binary log (.blf) and the
other formats cannot be resynchronised: the replay ends at the unreadable entry, counted, with
last_error saying so.

rate 1 paces the samples at real time (a sample is delivered once its time, counted from the
first read(), has come); rate N is N times faster; rate 0 delivers as fast as the caller reads.
Pacing follows only plausible time stamps and replays a silence longer than MAX_PACED_PAUSE_S
as that long: a stamp from next century never stalls a replay.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Generator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.columns import ColumnMap
from bogiemon.drivers.counters import counters
from bogiemon.drivers.files import UntrustedFile, open_untrusted
from bogiemon.drivers.recording import RECORDING_FILE, RecordingError, follows_gap, open_recording_reader
from bogiemon.drivers.sniff import NOT_READ, input_kind

if TYPE_CHECKING:  # cantools and python-can load with a CAN log only
    from bogiemon.drivers.candb import CanLayout

RECORDING_COUNTERS = counters("clipped_samples", "resampled_samples", "recording_gaps")
__all__ = ["CsvReplaySource", "RecordingReplaySource", "open_replay"]


class RecordingReplaySource(Source):
    """A recording of samples (CSV, .csv.gz, Parquet), block by block, at real-time pace (rate 1), N
    times faster, or unpaced (0).

    The file is read as it is replayed, a chunk at a time (drivers/recording.py), so memory does not
    grow with its length; its rate is known at the open. A bad row ends the replay where the reading
    reaches it: the samples before it are delivered (the last block may be short), then read()
    raises RecordingError naming the line. Samples beyond the converter's range arrive clipped, and
    are counted (counters.extra["clipped_samples"]); so are the samples of jittered stretches
    resampled onto the nominal grid and the gaps, after each of which a block starts a segment
    (gap_before).
    """

    finite = True

    def __init__(
        self,
        path: str | Path | UntrustedFile,
        rate: float = 1.0,
        max_block_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        columns: ColumnMap | None = None,
    ) -> None:
        self.reader = open_recording_reader(path, columns=columns)
        self.fs_hz = self.reader.fs_hz
        self.counters = HealthCounters()
        for name in RECORDING_COUNTERS:
            self.counters.extra[name] = 0
        self.rate = rate
        self.max_block_n = max(1, round(max_block_s * self.fs_hz))
        self._clock = clock
        self._sleep = sleep
        self._chunks: Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None] = self.reader.chunks()
        self._ended = False
        self._error: RecordingError | None = None  # found while reading on: raised once what was before it is delivered
        # The samples read and not yet delivered.
        self._time_s: NDArray[np.float64] = np.empty(0)
        self._accel_mps2: NDArray[np.float64] = np.empty((0, 3))
        self._delivered = 0
        self._start_wall_s: float | None = None
        # A chunk after a gap waits here until the samples before it are delivered: a block never
        # spans a gap.
        self._after_gap: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
        self._gap_before = True  # the pending samples start a segment
        self._last_read_s: float | None = None

    @property
    def fraction_read(self) -> float:
        """How much of the recording has been delivered, 0 to 1 (for a progress bar)."""
        return min(1.0, self._delivered / max(1, self.reader.n_samples))

    def _fill(self) -> None:
        """Read on until a whole block is pending or the file has ended."""
        if self._after_gap is not None and self._time_s.shape[0] == 0:
            (self._time_s, self._accel_mps2), self._after_gap, self._gap_before = self._after_gap, None, True
        while self._time_s.shape[0] < self.max_block_n and not self._ended and self._after_gap is None:
            try:
                time_s, accel_mps2 = next(self._chunks)
            except StopIteration:
                self._ended = True
                break
            except RecordingError as exc:
                self._ended, self._error = True, exc
                break
            finally:
                self._count()
            if not time_s.shape[0]:
                continue
            gap = self._last_read_s is not None and follows_gap(self._last_read_s, float(time_s[0]), self.fs_hz)
            self._last_read_s = float(time_s[-1])
            if gap:
                if self._time_s.shape[0]:
                    self._after_gap = (time_s, accel_mps2)  # delivered once those before it are
                    break
                self._gap_before = True
            if self._time_s.shape[0]:
                time_s = np.concatenate([self._time_s, time_s])
                accel_mps2 = np.concatenate([self._accel_mps2, accel_mps2])
            self._time_s, self._accel_mps2 = time_s, accel_mps2

    def _count(self) -> None:
        """Bring the counters up to the reader's, so far."""
        extra = self.counters.extra
        for name, value in (
            ("clipped_samples", self.reader.clipped_samples),
            ("resampled_samples", self.reader.resampled_samples),
            ("recording_gaps", self.reader.gap_count),
        ):
            if value > extra[name]:
                self.counters.add(name, value - extra[name])

    def _due_n(self) -> int:
        """Pending samples whose time has come (all of them when unpaced)."""
        if self.rate == 0:
            return self._time_s.shape[0]
        if self._start_wall_s is None:
            self._start_wall_s = self._clock()
        data_s = self.reader.start_s + (self._clock() - self._start_wall_s) * self.rate
        return int(np.searchsorted(self._time_s, data_s, side="right"))

    def read(self, timeout_s: float) -> Block | None:
        self._fill()
        pending = self._time_s.shape[0]
        if pending == 0:
            if self._error is not None:
                raise self._error
            raise EndOfStream
        deadline = self._clock() + timeout_s
        while True:
            ready = min(self._due_n(), self.max_block_n)
            if ready == self.max_block_n or ready == pending:
                break
            left_s = deadline - self._clock()
            if left_s <= 0:
                break
            assert self._start_wall_s is not None
            wanted = min(self.max_block_n, pending) - 1
            due_wall_s = self._start_wall_s + (self._time_s[wanted] - self.reader.start_s) / self.rate
            self._sleep(max(1e-4, min(left_s, due_wall_s - self._clock())))
        if ready == 0:
            self.counters.timeouts += 1
            return None
        block = Block(
            start_s=float(self._time_s[0]),
            fs_hz=self.fs_hz,
            accel_mps2=self._accel_mps2[:ready],
            gap_before=self._gap_before,
        )
        self._gap_before = False
        self._time_s, self._accel_mps2 = self._time_s[ready:], self._accel_mps2[ready:]
        self._delivered += ready
        self.counters.frames += ready
        return block

    def close(self) -> None:
        self._chunks.close()  # closes the file it reads


# The name from before Parquet recordings.
CsvReplaySource = RecordingReplaySource


def open_replay(
    path: str | Path,
    rate: float,
    layout: CanLayout | Callable[[], CanLayout] | None,
    fs_hz: float,
    max_block_s: float = 1.0,
    columns: ColumnMap | None = None,
) -> Source:
    """The replay source for a file, by its content: a recording of samples (.csv, .csv.gz,
    .parquet, MF4 of signals), or a CAN log decoded with layout (a CanLayout, or a function
    giving it: the DBC is then read only for a CAN log). The file is opened once, and read
    through the descriptor that was checked."""
    with open_untrusted(path, RECORDING_FILE, RecordingError) as f:  # opened once: read by its descriptor
        kind = input_kind(f)
        if kind is None:
            raise RecordingError(f"{path}: {NOT_READ}")
        if kind == "samples":
            return RecordingReplaySource(f, rate=rate, max_block_s=max_block_s, columns=columns)
        if layout is None:
            raise RecordingError(f"{path}: a CAN log needs a DBC layout to be decoded")
        from bogiemon.drivers.replay_can import CanLogReplaySource  # python-can, for CAN logs only

        return CanLogReplaySource(f, layout() if callable(layout) else layout, fs_hz, rate=rate, max_block_s=max_block_s)
