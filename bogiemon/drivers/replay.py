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
from collections.abc import Callable, Generator, Iterator
from pathlib import Path

import can
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source, plausible_time
from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.files import FileKind, TextLines, open_untrusted
from bogiemon.drivers.recording import RecordingError, is_sample_recording_name, open_recording_reader
from bogiemon.drivers.segments import SampleQueue
from bogiemon.drivers.counters import counters

# The longest silence of a CAN log a paced replay waits out (a wagon standing at a station, or a
# stamp far ahead of its neighbours): the decoder starts a new segment after a pause of half a
# counter period whatever its length, so waiting longer would change nothing but the wall time.
MAX_PACED_PAUSE_S = 10.0
REPLAY_COUNTERS = counters("unreadable_entries")
RECORDING_COUNTERS = counters("clipped_samples")
# A CAN log: a day of a hub at 500 Hz is about 3 GiB of candump -L text. Lines of a log are a
# hundred bytes; a longer one than this is no frame, and is counted and skipped unread.
CAN_LOG_FILE = FileKind(
    name="CAN log",
    description="a CAN log is a candump -L .log, a Vector .asc or .blf file",
    max_bytes=16 << 30,
    too_large="split the log into files of a few hours",
    max_line_bytes=64 << 10,
)


class RecordingReplaySource(Source):
    """A recording of samples (CSV, .csv.gz, Parquet), block by block, at real-time pace (rate 1), N
    times faster, or unpaced (0).

    The file is read as it is replayed, a chunk at a time (drivers/recording.py), so memory does not
    grow with its length; its rate is known at the open. A bad row ends the replay where the reading
    reaches it: the samples before it are delivered (the last block may be short), then read()
    raises RecordingError naming the line. Samples beyond the converter's range arrive clipped, and
    are counted (counters.extra["clipped_samples"]). A wagon's recording (both bogies) gives each
    stretch as one block per bogie (Block.bogie), bogie 1's first, read after read.
    """

    finite = True

    def __init__(
        self,
        path: str | Path,
        rate: float = 1.0,
        max_block_s: float = 1.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.reader = open_recording_reader(path)
        self.fs_hz = self.reader.fs_hz
        self.bogies = self.reader.bogies
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
        self._accel_mps2: NDArray[np.float64] = np.empty((0, 3 * self.reader.bogies))
        self._delivered = 0
        self._start_wall_s: float | None = None
        self._other_bogies: list[Block] = []  # a wagon's stretch: the blocks of its other bogies, next

    def _fill(self) -> None:
        """Read on until a whole block is pending or the file has ended."""
        while self._time_s.shape[0] < self.max_block_n and not self._ended:
            try:
                time_s, accel_mps2 = next(self._chunks)
            except StopIteration:
                self._ended = True
                break
            except RecordingError as exc:
                self._ended, self._error = True, exc
                break
            finally:
                clipped = self.reader.clipped_samples - self.counters.extra["clipped_samples"]
                if clipped:
                    self.counters.add("clipped_samples", clipped)
            if self._time_s.shape[0]:
                time_s = np.concatenate([self._time_s, time_s])
                accel_mps2 = np.concatenate([self._accel_mps2, accel_mps2])
            self._time_s, self._accel_mps2 = time_s, accel_mps2

    def _due_n(self) -> int:
        """Pending samples whose time has come (all of them when unpaced)."""
        if self.rate == 0:
            return self._time_s.shape[0]
        if self._start_wall_s is None:
            self._start_wall_s = self._clock()
        data_s = self.reader.start_s + (self._clock() - self._start_wall_s) * self.rate
        return int(np.searchsorted(self._time_s, data_s, side="right"))

    def read(self, timeout_s: float) -> Block | None:
        if self._other_bogies:
            return self._other_bogies.pop(0)
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
        block, *self._other_bogies = (
            Block(
                start_s=float(self._time_s[0]),
                fs_hz=self.fs_hz,
                accel_mps2=self._accel_mps2[:ready, 3 * k : 3 * k + 3],
                gap_before=self._delivered == 0,
                bogie=k,
            )
            for k in range(self.reader.bogies)
        )
        self._time_s, self._accel_mps2 = self._time_s[ready:], self._accel_mps2[ready:]
        self._delivered += ready
        self.counters.frames += ready
        return block

    def close(self) -> None:
        self._chunks.close()  # closes the file it reads


# The name from before Parquet recordings.
CsvReplaySource = RecordingReplaySource


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
        for name in REPLAY_COUNTERS:
            self.counters.extra[name] = 0
        self.max_block_n = max(1, round(max_block_s * fs_hz))
        self._clock = clock
        self._sleep = sleep
        self._queue = SampleQueue(fs_hz)
        self._decoder = CanFrameDecoder(layout, fs_hz, self.counters, self._queue)
        self._entries = _LogEntries(self.path, self._unreadable)
        self._frames: Iterator[can.Message] = iter(self._entries)
        self._peeked: can.Message | None = None
        self._ended = False
        self._first_log_s: float | None = None  # pacing: the log time that maps to _start_wall_s
        self._paced_log_s = 0.0  # pacing: the latest plausible log time seen
        self._start_wall_s = 0.0

    def _unreadable(self, message: str) -> None:
        self.counters.bad_frames += 1
        self.counters.add("unreadable_entries")
        self.last_error = message

    def _peek(self) -> can.Message | None:
        if self._peeked is None and not self._ended:
            try:
                self._peeked = next(self._frames)
            except StopIteration:
                self._ended = True
        return self._peeked

    def _due(self, message: can.Message) -> bool:
        if self.rate == 0:
            return True
        time_s = message.timestamp
        if not (isinstance(time_s, float | int) and plausible_time(time_s)):
            return True  # the decoder counts and drops it; it must not pace anything
        if self._first_log_s is None:
            self._first_log_s = self._paced_log_s = float(time_s)
            self._start_wall_s = self._clock()
        step_s = time_s - self._paced_log_s
        if step_s > MAX_PACED_PAUSE_S:  # replay a long silence as MAX_PACED_PAUSE_S
            self._first_log_s += step_s - MAX_PACED_PAUSE_S
        elif step_s < 0:  # a stamp behind: due with its predecessor, and the pace goes on from it
            self._first_log_s += step_s
        self._paced_log_s = float(time_s)
        return self._due_wall_s(float(time_s)) <= self._clock()

    def _due_wall_s(self, time_s: float) -> float:
        assert self._first_log_s is not None
        return self._start_wall_s + (time_s - self._first_log_s) / self.rate

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
            if self._peeked is not None:  # not yet due: _due has mapped its time to the wall clock
                self._sleep(max(1e-4, min(left_s, self._due_wall_s(self._paced_log_s) - self._clock())))
        block = self._queue.take(self.max_block_n)
        self.counters.gaps = self._queue.gaps
        if block is None:
            if self._ended:
                raise EndOfStream
            self.counters.timeouts += 1
        return block

    def close(self) -> None:
        self._entries.close()


class _ResumedAscReader(can.ASCReader):
    """An ASCReader reading on where another one failed, with the header settings that one read."""

    def __init__(self, file: TextLines, failed: can.ASCReader) -> None:
        # The failed reader's base comes from the file's header, in any case ("base HEX" parses):
        # the constructor takes only "hex" or "dec"; anything else falls back to its default.
        base = str(failed.base).lower()
        super().__init__(file, base=base if base in ("hex", "dec") else "hex", relative_timestamp=failed.relative_timestamp)  # type: ignore[arg-type]
        self.date = failed.date
        self.start_time = failed.start_time
        self.timestamps_format = failed.timestamps_format
        self.internal_events_logged = failed.internal_events_logged

    def _extract_header(self) -> None:
        """The header was read by the reader this one resumes; here it would swallow a frame line."""


class _CheckedBlfReader(can.BLFReader):
    """A BLFReader that refuses an object shorter than its own header instead of spinning on it.

    python-can's BLF parser advances by each object's declared size: one of size 0 (a corrupt or
    zeroed object) keeps it on the same spot forever, yielding the same frame or logging the
    same warning without end. Each container is walked by the sizes first, as the parser will
    walk it: the objects before one declaring less than a header are parsed, then BLFParseError.
    """

    def _parse_data(self, data: bytes) -> Iterator[can.Message]:
        header = can.io.blf.OBJ_HEADER_BASE_STRUCT
        pos = 0
        while pos + header.size <= len(data):
            found = data.find(b"LOBJ", pos, pos + 8)
            if found < 0 or found + header.size > len(data):
                break  # the parser raises for the one, keeps the other for the next container
            obj_size = header.unpack_from(data, found)[3]
            if obj_size < header.size:
                yield from super()._parse_data(data[:found])
                raise can.io.blf.BLFParseError(f"an object of a container declares {obj_size} bytes")
            pos = found + obj_size
        yield from super()._parse_data(data)


class _LogEntries:
    """The messages of a CAN log; an entry python-can cannot parse is reported and skipped.

    Text logs are opened here (UTF-8, undecodable bytes replaced, so a bad byte spoils only its
    own line; a line longer than CAN_LOG_FILE allows is not even read whole) and a fresh reader
    goes on over the same file object from the line after the one its predecessor failed on. A
    binary log cannot be resynchronised: the messages end there.
    """

    RESUMABLE = (".log", ".asc")

    def __init__(self, path: Path, on_unreadable: Callable[[str], None]) -> None:
        self.path = path
        self._on_unreadable = on_unreadable
        self._file: TextLines | None = None
        suffix = path.suffix.lower()
        # A regular file within the size cap (drivers/files.py); a text log's lines are bounded too:
        # a longer one is an unreadable line, counted and skipped like any other.
        untrusted = open_untrusted(path, CAN_LOG_FILE, RecordingError)
        try:
            try:
                if suffix in self.RESUMABLE:
                    self._file = untrusted.text_lines()
                    # python-can's readers take a TextIO or BinaryIO and use only what TextLines and
                    # UntrustedFile provide: iteration over the lines, and read and seek.
                    self._reader: can.io.generic.MessageReader = (
                        can.CanutilsLogReader(self._file) if suffix == ".log" else can.ASCReader(self._file)  # type: ignore[arg-type]
                    )
                elif suffix == ".blf":
                    self._reader = _CheckedBlfReader(untrusted)  # type: ignore[arg-type]
                else:
                    untrusted.close()  # checked; python-can's reader for the suffix opens it by name
                    self._reader = can.LogReader(str(path))
            except BaseException:
                untrusted.close()
                raise
        except RecordingError:  # drivers/files.py's own refusal, already naming the file
            raise
        except OSError as exc:
            raise RecordingError(f"{path}: cannot read the CAN log: {exc.strerror or exc}") from None
        except ValueError as exc:
            if "unknown log format" in str(exc):  # python-can names no reader for the suffix
                raise RecordingError(
                    f"{path}: not a recording bogiemon replays: use a recording (.csv, .csv.gz, .parquet) or a CAN log "
                    "(.log from candump -L, .asc, .blf)"
                ) from None
            raise RecordingError(f"{path}: not a readable CAN log: {exc}") from None
        except Exception as exc:  # noqa: BLE001 - each python-can reader raises its own kind for a bad header
            raise RecordingError(f"{path}: not a readable CAN log ({type(exc).__name__}: {exc})") from None

    def __iter__(self) -> Iterator[can.Message]:
        entries = 0
        while True:
            try:
                for message in self._reader:
                    entries += 1
                    yield message
                return
            except Exception as exc:  # noqa: BLE001 - each python-can reader raises its own kind for a bad line
                detail = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
                if self._file is None:
                    self._on_unreadable(f"{self.path}: unreadable CAN log entry after {entries} frames, replay ends here: {detail}")
                    return
                self._on_unreadable(f"{self.path}: unreadable CAN log line after {entries} frames, skipped: {detail}")
                failed = self._reader
                self._reader = (
                    _ResumedAscReader(self._file, failed)
                    if isinstance(failed, can.ASCReader)
                    else can.CanutilsLogReader(self._file)  # type: ignore[arg-type]  # as in open
                )

    def close(self) -> None:
        try:
            self._reader.stop()
        except Exception:  # noqa: BLE001, S110 - closing a file that failed to parse: nothing left to release
            pass


def open_replay(
    path: str | Path,
    rate: float,
    layout: CanLayout | None,
    fs_hz: float,
    max_block_s: float = 1.0,
) -> Source:
    """The replay source for a file: a recording of samples (.csv, .csv.gz, .parquet), or a CAN log
    decoded with layout."""
    if is_sample_recording_name(path):  # before python-can, which would read a .csv.gz as its own CSV log format
        return RecordingReplaySource(path, rate=rate, max_block_s=max_block_s)
    if layout is None:
        raise RecordingError(f"{path}: a CAN log needs a DBC layout to be decoded")
    return CanLogReplaySource(path, layout, fs_hz, rate=rate, max_block_s=max_block_s)
