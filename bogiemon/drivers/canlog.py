"""CAN logs as loggers write them, read through the one bounded open (drivers/files.py) into
batches of frames (drivers/can_frames.py: FrameBatch) for the CAN decoder.

The formats are a table (FORMATS), each recognised by its first bytes (a name's suffix only
decides where the content says nothing), plain or gzip-compressed where the format is a stream:

    candump -L .log, Vector .asc and .blf, PEAK .trc, python-can's CSV (.csv) and SQLite (.db)
    logs, and MF4 bus logs (CAN_DataFrame groups: drivers/mf4.py).

Every reader reads from the descriptor open_untrusted checked: python-can's text readers iterate
its bounded lines (UntrustedFile.text_lines), the BLF reader its bounded stream with every
container's inflation bounded here, SQLite opens /proc/self/fd/N read-only, asammdf the stream
itself. A line or entry python-can cannot parse is reported and skipped where the format has
lines (the text logs read on from the next one); a binary log cannot be resynchronised and ends
there, reported. candump's human format (`candump -ta`, `-tz`, `-td`) is recognised and refused
with the remedy: record with `candump -L`.
"""

from __future__ import annotations

import base64
import os
import sqlite3
import zlib
from collections.abc import Callable, Generator, Iterable, Iterator
from pathlib import Path

import can
import numpy as np

from bogiemon.drivers.can_frames import FrameBatch
from bogiemon.drivers.files import FileKind, TextLines, UntrustedFile, one_line, open_untrusted
from bogiemon.drivers.recording_format import RecordingError
from bogiemon.drivers.sniff import FORMATS, NOT_READ, CandumpHuman, LogFormat, candump_human_message, sniff_log_format

# A day of a hub at 500 Hz is about 3 GiB of candump -L text. Lines of a log are a hundred
# bytes; a longer one than this is no frame, and is counted and skipped unread. A log compresses
# 5 to 15 times (time stamps and identifiers repeat); a compression bomb does a thousand.
CAN_LOG_FILE = FileKind(
    name="CAN log",
    description=(
        "a CAN log is a candump -L .log, a Vector .asc or .blf, a PEAK .trc, python-can's .csv or .db, "
        "or an MF4 bus log (.gz compressed where it is text or .blf)"
    ),
    max_bytes=16 << 30,
    too_large="split the log into files of a few hours",
    gzip=True,
    max_inflated_bytes=16 << 30,
    max_inflate_ratio=50.0,
    max_line_bytes=64 << 10,
)
# Frames handed to the decoder per batch: numpy's work per batch is then small against its cost.
BATCH_FRAMES = 4096
# A BLF container holds 128 KiB of objects when Vector's tools or python-can write it; one that
# inflates past this is no log's.
MAX_BLF_CONTAINER_BYTES = 16 << 20
# What a BLF object may carry over into the next container (an object split between two).
MAX_BLF_TAIL_BYTES = 1 << 20

class LogFrames:
    """The frames of a CAN log as FrameBatches, in the log's order; an entry that cannot be parsed
    is reported (on_unreadable) and skipped where the format has lines, else ends the frames.

    start_s: the log's start from its own header where it has one (ASC's date, BLF's and MF4's
    start), as Unix seconds; None where the log holds no date (its times may still be absolute:
    candump -L's and python-can's are).
    """

    def __init__(self, path: str | Path | UntrustedFile, on_unreadable: Callable[[str], None]) -> None:
        self._file = path.reopen(CAN_LOG_FILE) if isinstance(path, UntrustedFile) else open_untrusted(path, CAN_LOG_FILE, RecordingError)
        self.path = self._file.path
        self._on_unreadable = on_unreadable
        self.start_s: float | None = None
        self.relative = False  # the frames' times count from the log's start, not from 1970
        try:
            self.format = self._sniff()
            self._batches = self._open()
        except BaseException:
            self._file.close()
            raise

    def _sniff(self) -> LogFormat:
        try:
            key = sniff_log_format(self._file.head(4096), self.path.name)
        except CandumpHuman:
            raise RecordingError(candump_human_message(self.path)) from None
        if key is None and self.path.name.lower().endswith(".mfc"):
            raise RecordingError(
                f"{self.path}: a CANedge-compressed MF4 (.MFC), which no MF4 reader opens: decompress it with the "
                "logger maker's tool (CSS Electronics' mdf2finalized, or the CANedge config tool) into an .MF4 first"
            )
        if key is None:
            raise RecordingError(f"{self.path}: {NOT_READ}")
        fmt = FORMATS[key]
        if self._file.compressed and not fmt.streams:
            raise RecordingError(f"{self.path}: {fmt.words} cannot be read compressed: decompress it first (gunzip)")
        return fmt

    def _open(self) -> Iterator[FrameBatch]:
        key = self.format.key
        if key == "mf4":
            from bogiemon.drivers.mf4 import open_mf4

            mf4 = open_mf4(self._file)
            self.start_s = mf4.start_s
            return mf4.frames(self.path)
        if key == "sqlite":
            return _sqlite_frames(self._file, self._on_unreadable)
        return self._python_can_frames(key)

    def _python_can_frames(self, key: str) -> Iterator[FrameBatch]:
        text = self._file.text_lines() if key != "blf" else None
        try:
            reader: Iterable[can.Message]
            if key == "blf":
                blf = BoundedBlfReader(self._file)  # type: ignore[arg-type]  # a readable binary stream
                self.start_s = float(blf.start_timestamp) or None
                reader = blf
            elif key == "asc":
                reader = _asc_reader(text)  # type: ignore[arg-type]
            elif key == "trc":
                reader = _CountedTrcReader(text)  # type: ignore[arg-type]
            elif key == "pycsv":
                reader = _ResumableCsvReader(text, skip_header=True)  # type: ignore[arg-type]
            else:
                reader = can.CanutilsLogReader(text)  # type: ignore[arg-type]
        except RecordingError:
            raise
        except Exception as exc:  # noqa: BLE001 - each python-can reader raises its own kind for a bad header
            raise RecordingError(f"{self.path}: not a readable CAN log ({self.format.words}; {type(exc).__name__}: {one_line(str(exc))})") from None
        return self._batched(_ResumingMessages(self.path, reader, text, self._on_unreadable, self))

    def _batched(self, messages: Iterable[can.Message]) -> Iterator[FrameBatch]:
        batch: list[can.Message] = []
        for message in messages:
            batch.append(message)
            if len(batch) >= BATCH_FRAMES:
                yield FrameBatch.from_messages(batch)
                batch = []
        if batch:
            yield FrameBatch.from_messages(batch)

    def __iter__(self) -> Iterator[FrameBatch]:
        return self._batches

    @property
    def fraction_read(self) -> float:
        """How much of the file has been read, 0 to 1: its descriptor's position on disk (an MF4's
        and an SQLite log's are read elsewhere: 0 until they end)."""
        try:
            return min(1.0, os.lseek(self._file.fileno(), 0, os.SEEK_CUR) / max(1, self._file.size_bytes))
        except (OSError, ValueError):
            return 1.0

    def close(self) -> None:
        close = getattr(self._batches, "close", None)
        if close is not None:
            close()
        self._file.close()


def _asc_reader(text: TextLines) -> can.ASCReader:
    """An ASCReader whose times are absolute where the header has a date (Vector writes one)."""
    reader = can.ASCReader(text, relative_timestamp=False)  # type: ignore[arg-type]
    return reader


class _ResumingMessages:
    """python-can's messages of a log; after an entry it cannot parse, a fresh reader goes on over
    the same lines from the next one (text formats), or the messages end (binary ones)."""

    def __init__(self, path: Path, reader: Iterable[can.Message], text: TextLines | None,
                 on_unreadable: Callable[[str], None], frames: LogFrames) -> None:  # fmt: skip
        self.path = path
        self.reader = reader
        self.text = text
        self.on_unreadable = on_unreadable
        self.frames = frames

    def __iter__(self) -> Iterator[can.Message]:
        entries = 0
        first = True
        while True:
            try:
                for message in self.reader:
                    if first:
                        first = False
                        self._header_read()
                    entries += 1
                    yield message
                return
            except RecordingError:  # the bounded open's own refusal (a compression bomb): not a line
                raise
            except Exception as exc:  # noqa: BLE001 - each python-can reader raises its own kind for a bad line
                detail = one_line(f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__, 200)
                if self.text is None:
                    self.on_unreadable(f"{self.path}: unreadable CAN log entry after {entries} frames, replay ends here: {detail}")
                    return
                self.on_unreadable(f"{self.path}: unreadable CAN log line after {entries} frames, skipped: {detail}")
                self.reader = _resumed(self.reader, self.text)

    def _header_read(self) -> None:
        """What the header told, once the reader has read it: the log's start."""
        reader = self.reader
        if isinstance(reader, can.ASCReader):
            if reader.date is not None and reader.start_time:
                self.frames.start_s = float(reader.start_time)
            else:
                self.frames.relative = True  # an ASC without a date: times from 0
        elif isinstance(reader, can.TRCReader):
            start = reader.start_time
            if start is not None:
                self.frames.start_s = start.timestamp()
            else:
                self.frames.relative = True


def _resumed(failed: Iterable[can.Message], text: TextLines) -> Iterable[can.Message]:
    if isinstance(failed, can.ASCReader):
        return _ResumedAscReader(text, failed)
    if isinstance(failed, can.TRCReader):
        return _ResumedTrcReader(text, failed)
    if isinstance(failed, _ResumableCsvReader):
        return _ResumableCsvReader(text, skip_header=False)
    return can.CanutilsLogReader(text)  # type: ignore[arg-type]  # a TextLines iterates like a text file


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


class _CountedTrcReader(can.TRCReader):
    """A TRCReader that raises for a line it cannot parse (python-can's logs a warning and drops
    it uncounted), so that the line is counted and skipped like any other log's."""

    def _parse_line(self, line: str) -> can.Message | None:
        stripped = line.strip()
        if not stripped:
            # No line: what _extract_header gives at the end of the file. Parsed, it fails where
            # the header's columns lack one (KeyError) before any line is read: a reader resumed
            # after it would fail on it again, forever.
            return None
        message = super()._parse_line(line)
        if message is None and not stripped.startswith(";"):
            raise ValueError(f"not a frame: {one_line(stripped)}")
        return message


class _ResumedTrcReader(_CountedTrcReader):
    """A TRC reader going on where another one failed, with the header it read."""

    def __init__(self, file: TextLines, failed: can.TRCReader) -> None:
        super().__init__(file)  # type: ignore[arg-type]
        self.file_version = failed.file_version
        self._start_time = failed._start_time
        self.columns = failed.columns
        self._num_columns = failed._num_columns
        self._parse_cols = failed._parse_cols

    def _extract_header(self) -> str:
        return ""  # the header was read by the reader this one resumes; "" is no line to parse


class _ResumableCsvReader:
    """python-can's CSV log (timestamp,arbitration_id,extended,remote,error,dlc,data; the data in
    base64), parsed as python-can's CSVReader does; its header skipped only at the start, so a
    reader made after a bad line goes on from the next."""

    def __init__(self, file: TextLines, skip_header: bool) -> None:
        self.file = file
        self.skip_header = skip_header

    def __iter__(self) -> Iterator[can.Message]:
        if self.skip_header:
            self.skip_header = False
            if next(self.file, None) is None:
                return
        for line in self.file:
            if not line.strip():
                continue
            timestamp, arbitration_id, extended, remote, error, dlc, data = line.rstrip("\r\n").split(",")
            yield can.Message(
                timestamp=float(timestamp), is_remote_frame=remote == "1", is_extended_id=extended == "1",
                is_error_frame=error == "1", arbitration_id=int(arbitration_id, base=16), dlc=int(dlc),
                data=base64.b64decode(data, validate=True),
            )  # fmt: skip


class BoundedBlfReader(can.BLFReader):
    """python-can's BLF reader with every container's inflation bounded, an object's carry-over
    into the next container bounded, and an object shorter than its own header refused (the
    parser advances by each object's declared size: one of size 0 keeps it on one spot forever).
    """

    def __iter__(self) -> Generator[can.Message, None, None]:
        header = can.io.blf.OBJ_HEADER_BASE_STRUCT
        container = can.io.blf.LOG_CONTAINER_STRUCT
        while True:
            data = self.file.read(header.size)
            if not data:
                break
            if len(data) < header.size:
                raise can.io.blf.BLFParseError("the log ends inside an object's header")
            signature, _, _, obj_size, obj_type = header.unpack(data)
            if signature != b"LOBJ":
                raise can.io.blf.BLFParseError("no object where one should start")
            if obj_size < header.size:
                raise can.io.blf.BLFParseError(f"an object declares {obj_size} bytes, less than its own header")
            obj_data = self.file.read(obj_size - header.size)
            self.file.read(obj_size % 4)
            if obj_type != can.io.blf.LOG_CONTAINER:
                continue
            if len(obj_data) < container.size:
                raise can.io.blf.BLFParseError("a container ends inside its header")
            method, _ = container.unpack_from(obj_data)
            packed = obj_data[container.size :]
            if method == can.io.blf.NO_COMPRESSION:
                data = packed
            elif method == can.io.blf.ZLIB_DEFLATE:
                inflater = zlib.decompressobj()
                try:
                    data = inflater.decompress(packed, MAX_BLF_CONTAINER_BYTES)
                except zlib.error as exc:
                    raise can.io.blf.BLFParseError(f"a container does not inflate: {exc}") from None
                if inflater.unconsumed_tail:
                    raise can.io.blf.BLFParseError(f"a container inflates to more than {MAX_BLF_CONTAINER_BYTES >> 20} MiB")
            else:
                raise can.io.blf.BLFParseError(f"a container of unknown compression method {method}")
            yield from self._parse_container(data)
            if len(self._tail) > MAX_BLF_TAIL_BYTES:
                raise can.io.blf.BLFParseError(f"an object runs over more than {MAX_BLF_TAIL_BYTES >> 20} MiB of containers")
        self.stop()

    def _parse_data(self, data: bytes) -> Iterator[can.Message]:
        pos = 0
        while pos + header_size() <= len(data):
            found = data.find(b"LOBJ", pos, pos + 8)
            if found < 0 or found + header_size() > len(data):
                break  # the parser raises for the one, keeps the other for the next container
            obj_size = can.io.blf.OBJ_HEADER_BASE_STRUCT.unpack_from(data, found)[3]
            if obj_size < header_size():
                yield from super()._parse_data(data[:found])
                raise can.io.blf.BLFParseError(f"an object of a container declares {obj_size} bytes")
            pos = found + obj_size
        yield from super()._parse_data(data)


def header_size() -> int:
    return int(can.io.blf.OBJ_HEADER_BASE_STRUCT.size)


# python-can's SQLite log: messages(ts REAL, arbitration_id INTEGER, extended INTEGER, remote
# INTEGER, error INTEGER, dlc INTEGER, data BLOB). Rows whose data is longer than a CAN FD frame
# are read as one count, never loaded.
_SQLITE_QUERY = (
    "SELECT ts, arbitration_id, extended, remote, error, dlc, data FROM messages "
    "WHERE typeof(data) IN ('blob', 'null') AND coalesce(length(data), 0) <= 64 ORDER BY rowid"
)
# The longest text or blob SQLite makes of a row's value: a frame's data is 64 bytes at most.
_SQLITE_MAX_VALUE_BYTES = 1 << 20
_SQLITE_BAD = "SELECT count(*) FROM messages WHERE NOT (typeof(data) IN ('blob', 'null') AND coalesce(length(data), 0) <= 64)"


def _sqlite_frames(f: UntrustedFile, on_unreadable: Callable[[str], None]) -> Iterator[FrameBatch]:
    """python-can's SQLite log, read-only through the checked descriptor (SQLite opens names
    only: /proc/self/fd/N, immutable: no journal, no lock, nothing written)."""
    uri = f"file:{f.proc_path}?mode=ro&immutable=1"
    try:
        connection = sqlite3.connect(uri, uri=True, check_same_thread=False)
    except sqlite3.Error as exc:
        raise RecordingError(f"{f.path}: not a readable SQLite log ({one_line(str(exc))})") from None
    try:
        connection.setlimit(sqlite3.SQLITE_LIMIT_LENGTH, _SQLITE_MAX_VALUE_BYTES)
        _check_sqlite_table(f, connection)
        bad = connection.execute(_SQLITE_BAD).fetchone()[0]
        cursor = connection.execute(_SQLITE_QUERY)
    except RecordingError:
        connection.close()
        raise
    except sqlite3.Error as exc:
        connection.close()
        raise RecordingError(
            f"{f.path}: not a python-can SQLite log ({one_line(str(exc))}): expected its table 'messages' "
            "(ts, arbitration_id, extended, remote, error, dlc, data)"
        ) from None
    return _sqlite_batches(f, connection, cursor, int(bad), on_unreadable)


def _check_sqlite_table(f: UntrustedFile, connection: sqlite3.Connection) -> None:
    """Refuse a `messages` that is not a table of stored rows, as python-can's writer makes it: a
    view (its query may never end: a recursive one), a virtual table, or columns computed when
    read (a generated blob of hundreds of MiB per row). Reading those reads no file."""
    found = connection.execute("SELECT type, sql FROM sqlite_master WHERE name = 'messages'").fetchone()
    if found is None:
        return  # the query names what is missing
    kind, sql = found
    computed = [row[1] for row in connection.execute("PRAGMA table_xinfo(messages)") if row[6] != 0]
    if kind != "table" or str(sql or "").lstrip().upper().startswith("CREATE VIRTUAL") or computed:
        what = f"its column(s) {', '.join(map(str, computed))} computed when read" if kind == "table" and computed else f"its messages a {'virtual table' if kind == 'table' else kind}"
        raise RecordingError(
            f"{f.path}: not a python-can SQLite log ({one_line(what)}): expected its table 'messages' of stored rows "
            "(ts, arbitration_id, extended, remote, error, dlc, data)"
        )


def _sqlite_batches(f: UntrustedFile, connection: sqlite3.Connection, cursor: sqlite3.Cursor, bad: int,
                    on_unreadable: Callable[[str], None]) -> Iterator[FrameBatch]:  # fmt: skip
    try:
        for _ in range(bad):  # one count each, one message
            on_unreadable(f"{f.path}: {bad} row(s) of the SQLite log hold no CAN frame's data, skipped")
        while True:
            try:
                rows = cursor.fetchmany(BATCH_FRAMES)
            except sqlite3.Error as exc:
                on_unreadable(f"{f.path}: the SQLite log is damaged, replay ends here: {one_line(str(exc))}")
                return
            if not rows:
                return
            messages = []
            for ts, arbitration_id, extended, remote, error, dlc, data in rows:
                try:
                    messages.append(can.Message(
                        timestamp=float(ts), arbitration_id=int(arbitration_id), is_extended_id=bool(extended),
                        is_remote_frame=bool(remote), is_error_frame=bool(error), dlc=int(dlc), data=bytes(data or b""),
                        check=False,
                    ))  # fmt: skip
                except (TypeError, ValueError, OverflowError) as exc:
                    on_unreadable(f"{f.path}: an SQLite log row is no frame, skipped: {one_line(str(exc))}")
            if messages:
                yield FrameBatch.from_messages(messages)
    finally:
        connection.close()


def frames_of_times(time_s: np.ndarray, keys: np.ndarray, data: np.ndarray, length: np.ndarray) -> FrameBatch:
    """A FrameBatch of data frames from columns (a columnar reader's: MF4)."""
    n = int(time_s.shape[0])
    return FrameBatch(
        np.asarray(time_s, np.float64), np.asarray(keys, np.int64), np.asarray(length, np.int64),
        np.ascontiguousarray(data, np.uint8).reshape(n, 8), np.zeros(n, np.uint8),
    )  # fmt: skip

