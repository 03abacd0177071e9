"""Recordings of samples: the bench's exchange format between the simulator, loggers, the gateway's
recorder and every command that reads one (`analyze`, `replay`, `calibrate`, `play`, the fleet).

Two formats hold the same thing, one row per sampling instant: the time in seconds from any origin
and the three vertical accelerations in m/s^2 (with or without gravity).

- CSV: a first line exactly `time_s,a1,a2,a3`, then rows of four numbers; plain (`.csv`) or
  gzip-compressed (`.csv.gz`, what the recorder writes: read when the name ends in .gz or the first
  bytes are gzip's magic). Written with 6 decimals.
- Parquet (`.parquet`, or a file starting with Parquet's magic): four float64 columns `time_s`,
  `a1`, `a2`, `a3`; the samples exactly as given (no decimals lost), compressed (zstd, the
  accelerations dictionary-encoded: a 16-bit converter's samples take a fraction of their text).
  Any writer's file with these columns is read (pyarrow, pandas, DuckDB, polars).

Rows are uniformly sampled and strictly increasing in time; the sample rate is that of the whole
file, (n - 1) / (last time - first time). A recording with a gap is two recordings. Times are
plausible ones (drivers/base.py: finite, within +/-MAX_TIME_S).

Reading streams: open_recording_reader() surveys the file (its rows, first and last time: the
rate, before the first sample is used) and RecordingReader.chunks() gives the samples chunk by
chunk, checked, in bounded memory whatever the file's length (pyarrow's C readers, a megabyte of
text at a time). The same samples give the same values, bit for bit, from either format.

A bad row is an error naming its line (CSV) or row (Parquet, counted from 1), never a skipped one:
the rows are one uniform time axis, so a row left out would shift every later sample by a period
without a trace. A file cut in the middle of a UTF-8 character (a logger killed mid-write) is such a
bad row. What concerns the whole file (too few rows for a window, no finite rate) is refused at
the open; a bad row is found when the reading reaches it, so a reader may have used the rows
before it (the windows before a bad line are analysed, or judged by a replay) when it stops.

NaN is no reading: a row holding one is refused. A sample beyond the converter's range (or
infinite: an overflowed reading) is clipped to its full scale, as the sensor would have clipped
it (MIN_ACCEL_MPS2, MAX_ACCEL_MPS2: config/bogiemon.dbc's int16 over +/-16 g), and counted: one
absurd value must not put inf or NaN into the core's filters, where it would stay for minutes.

Files are opened through drivers/files.py: a regular file, at most MAX_RECORDING_BYTES, a gzip
stream decompressing to at most 100 times its size, lines of at most 1 MiB.
"""

from __future__ import annotations

import enum
import gzip
import importlib.util
import math
import os
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, NoReturn

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S, Block
from bogiemon.drivers.csv_rows import NUMBER, RowsError, parse_rows
from bogiemon.drivers.files import FileKind, UntrustedFile, open_untrusted, size_text

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq

HEADER = "time_s,a1,a2,a3"
COLUMNS = ("time_s", "a1", "a2", "a3")
# A time step may deviate this much (relative) from the file's step: enough for times printed
# with 6 decimals at 1 kHz, far less than the 100 % of one lost sample.
TIME_STEP_TOLERANCE = 0.01
# The file's step is the median of its first steps (of all of them in a file this short): a
# streaming reader cannot wait for the whole file's median before it checks the first rows.
REFERENCE_STEPS = 4096

# The converter's range (config/bogiemon.dbc: int16 samples, 1 LSB = 16 g / 32768, g = 9.80665
# m/s^2): -16 g .. +16 g - 1 LSB. A sample beyond it is clipped to it at the source boundary.
ACCEL_LSB_MPS2 = 16 * 9.80665 / 32768
MIN_ACCEL_MPS2 = -32768 * ACCEL_LSB_MPS2  # -156.9064 m/s^2
MAX_ACCEL_MPS2 = 32767 * ACCEL_LSB_MPS2  # +156.9016 m/s^2

# A day at 1 kHz is 86.4 M rows: about 4 GiB of CSV, 2.8 GiB of float64 Parquet. Reading streams,
# so the cap bounds the time a wrong file takes (a disk image named by mistake), not memory.
MAX_RECORDING_BYTES = 16 << 30
# Recordings' CSV compresses 2.5 to 6 times (simulated noise, a 16-bit converter's samples);
# a constant signal a little better. A compression bomb does 1000 times.
MAX_INFLATE_RATIO = 100.0
# pyarrow parses the text a block at a time and a row must fit in one: the longest line read.
MAX_LINE_BYTES = 1 << 20
RECORDING_FILE = FileKind(
    name="recording",
    description=f"a recording is a CSV file ({HEADER}), plain or .csv.gz, or a .parquet file",
    max_bytes=MAX_RECORDING_BYTES,
    too_large="split the recording into files of a few hours",
    gzip=True,
    max_inflated_bytes=MAX_RECORDING_BYTES,
    max_inflate_ratio=MAX_INFLATE_RATIO,
    max_line_bytes=MAX_LINE_BYTES,
)

_ROW_FORMAT = "%.6f,%.6f,%.6f,%.6f\n"
_WRITE_CHUNK_ROWS = 65536
# zlib's level 6 (gzip's own default): on 220 s of simulated bogie at 500 Hz (5.1 MB of text) 1.80 MB
# in 0.35 s here, against 1.78 MB in 1.2 s at level 9 and 2.02 MB in 0.06 s at level 1.
GZIP_LEVEL = 6
PARQUET_MAGIC = b"PAR1"
PARQUET_SUFFIX = ".parquet"


class RecordingFormat(enum.StrEnum):
    """The formats a recording is written in (`[recorder] format`); read by any of its names."""

    CSV_GZ = "csv.gz"
    PARQUET = "parquet"

    @property
    def suffix(self) -> str:
        return f".{self.value}"
# Rows per Parquet row group (2.1 min at 500 Hz): a row group is read whole, 2 MiB decoded.
PARQUET_GROUP_ROWS = 65536
# What a row group of a Parquet recording may hold (decoded: 32 MiB) and declare uncompressed per
# value (8 bytes plain, a dictionary of at most as many values again, page headers).
MAX_PARQUET_GROUP_ROWS = 1 << 20
_PARQUET_BYTES_PER_VALUE = 16
_PARQUET_FOOTER_LIMIT = 1 << 20  # thrift strings and containers of the footer: ours are a few KiB

# A number as pyarrow's CSV reader takes it: the slow path that names a bad line must find the
# line pyarrow refused, not one Python's float() refuses (and numpy's parser keeps to it).
_NUMBER = NUMBER
_NOT_BREAK = re.compile(rb"[^\r\n]+")
_LINE_BREAK = re.compile(rb"\r\n|\r|\n")


class RecordingError(ValueError):
    """A recording that cannot be used; the message names the file, the line and the remedy."""


# Parquet is pyarrow's, which a gateway may be installed without (CSV is read either way).
NEEDS_PYARROW = "needs pyarrow, which this install leaves out: pip install 'bogiemon[recordings]', or use CSV (.csv.gz)"


def parquet_available() -> bool:
    """Whether pyarrow, which Parquet recordings need, is installed (and not hidden, as a test hides it)."""
    return importlib.util.find_spec("pyarrow") is not None


@dataclass(frozen=True)
class Recording:
    """A whole recording in memory (read_recording); for recordings of minutes, not days."""

    path: Path
    time_s: NDArray[np.float64]  # (n,)
    accel_mps2: NDArray[np.float64]  # (n, 3)
    fs_hz: float
    clipped_samples: int = 0  # samples beyond the converter's range, clipped to it

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    @property
    def start_s(self) -> float:
        return float(self.time_s[0])

    def blocks(self, block_n: int) -> list[Block]:
        """The recording cut into consecutive Blocks of block_n samples (the last may be shorter)."""
        return [
            Block(start_s=float(self.time_s[i]), fs_hz=self.fs_hz, accel_mps2=self.accel_mps2[i : i + block_n])
            for i in range(0, self.n_samples, block_n)
        ]

    def chunks(self, chunk_n: int = 65536) -> Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None]:
        """(time_s, accel_mps2) in consecutive chunks, as RecordingReader.chunks gives them."""
        for i in range(0, self.n_samples, chunk_n):
            yield self.time_s[i : i + chunk_n], self.accel_mps2[i : i + chunk_n]


def is_sample_recording_name(path: str | Path) -> bool:
    """Whether a file name is a recording of samples (.csv, .csv.gz, .parquet), not a CAN log's."""
    return str(path).lower().endswith((".csv", ".csv.gz", PARQUET_SUFFIX))


# ------------------------------------------------------------------------------------------------
# Reading


class RecordingReader(ABC):
    """A recording opened for reading: its rate and length known, its samples read chunk by chunk.

    Opened by open_recording_reader (which refuses what concerns the whole file); chunks() gives
    (time_s (m,), accel_mps2 (m, 3)) float64 in order, every row checked and clipped, and raises
    RecordingError at the first bad row. It may be iterated again (each pass reads the file anew).
    """

    path: Path
    format: str  # "csv" or "parquet"
    n_samples: int
    start_s: float  # the time of the first sample
    last_s: float  # the time of the last sample
    fs_hz: float

    def __init__(self) -> None:
        self.clipped_samples = 0  # of the last pass of chunks(), so far

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    @abstractmethod
    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The file's rows as arrays, unchecked, in order; RecordingError for what cannot be parsed."""

    @abstractmethod
    def where(self, row: int) -> str:
        """Where data row `row` (from 0) is in the file, for a message: 'line 1873', 'row 1872'."""

    def error(self, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {problem}")

    def row_error(self, row: int, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {self.where(row)}: {problem}")

    def chunks(self) -> Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None]:
        checker = _RowChecker(self)
        self.clipped_samples = 0
        yield from checker.checked(self._raw_chunks())
        if checker.rows != self.n_samples or checker.last_s != self.last_s:
            self.error(
                f"changed while it was read ({checker.rows} rows, not {self.n_samples}): is a logger still writing it? "
                "Use the recording once it is complete"
            )

    def read_all(self) -> Recording:
        """The whole recording in memory."""
        times, accels = [], []
        for time_s, accel_mps2 in self.chunks():
            times.append(time_s)
            accels.append(accel_mps2)
        return Recording(
            path=self.path,
            time_s=np.concatenate(times),
            accel_mps2=np.ascontiguousarray(np.concatenate(accels)),
            fs_hz=self.fs_hz,
            clipped_samples=self.clipped_samples,
        )

    # -- what the open checks ----------------------------------------------------------------------

    def _check_whole(self, min_samples: int, first_s: float | None, last_s: float | None) -> None:
        """Set the rate from the survey; refuse what concerns the whole file, after naming any bad row.

        A file whose rows cannot give a rate (fewer than two, times not increasing from the first
        to the last) or too short for min_samples is read through first: a bad row in it is the
        error, as it is what the user must repair.
        """
        n = self.n_samples
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            fs_hz = float((n - 1) / (np.float64(last_s) - np.float64(first_s))) if n >= 2 and None not in (first_s, last_s) else math.nan
        usable = n >= 2 and math.isfinite(fs_hz) and fs_hz > 0
        if usable and n >= min_samples:
            self.start_s, self.last_s, self.fs_hz = float(first_s), float(last_s), fs_hz  # type: ignore[arg-type]
            return
        # The rows are read through for a bad one; the survey's own values do not judge them.
        self.start_s = self.last_s = math.nan
        self.fs_hz = fs_hz
        checker = _RowChecker(self)
        for _ in checker.checked(self._raw_chunks()):
            pass
        if checker.rows == 0:
            self.error("holds no samples after the header" if self.format == "csv" else "holds no samples")
        if checker.rows < 2:
            self.error(f"holds {checker.rows} sample(s); a recording needs at least two rows" + (" after the header" if self.format == "csv" else ""))
        if not usable:
            if checker.rows == n and checker.reference_step_s is not None:
                self.error(f"time steps of {checker.reference_step_s:.6g} s give no finite sample rate: time_s must be in seconds")
            self.error(f"changed while it was read ({checker.rows} rows, not {n}): is a logger still writing it? Use the recording once it is complete")
        self.error(
            f"{n} samples ({n / fs_hz:.1f} s) is shorter than one analysis window "
            f"({min_samples} samples, {min_samples / fs_hz:.1f} s): use a longer recording or a shorter window_s"
        )

    def require_samples(self, min_samples: int) -> None:
        """Refuse a recording shorter than min_samples (e.g. one analysis window), after naming a bad row."""
        if self.n_samples < min_samples:
            self._check_whole(min_samples, self.start_s, self.last_s)


class _RowChecker:
    """The checks of every row, in file order, carried from chunk to chunk: NaN, a time that is
    not plausible, not increasing or off the file's step; and the clipping of the samples."""

    def __init__(self, reader: RecordingReader) -> None:
        self.reader = reader
        self.rows = 0  # rows checked
        self.last_s: float | None = None
        self.reference_step_s: float | None = None

    def checked(
        self, raw: Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]
    ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The rows of raw, checked and clipped; at a bad row, the rows before it, then RecordingError."""
        # Rows held until the file's step is known (its first REFERENCE_STEPS steps).
        held_t: list[NDArray[np.float64]] = []
        held_a: list[NDArray[np.float64]] = []
        try:
            yield from self._checked(raw, held_t, held_a)
        except RecordingError:
            if held_t:  # the rows before a bad line are used, also before the file's step is known
                yield from self._check(np.concatenate(held_t), np.concatenate(held_a))
            raise

    def _checked(
        self, raw: Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]], held_t: list[NDArray[np.float64]], held_a: list[NDArray[np.float64]]
    ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        held_n = 0
        for time_s, accel_mps2 in raw:
            if self.reference_step_s is None and held_n + time_s.shape[0] <= REFERENCE_STEPS:
                held_t.append(time_s)  # the file's step is not known yet: wait for its first steps
                held_a.append(accel_mps2)
                held_n += time_s.shape[0]
                continue
            if held_n:
                time_s, accel_mps2 = np.concatenate([*held_t, time_s]), np.concatenate([*held_a, accel_mps2])
                held_t.clear()
                held_a.clear()
                held_n = 0
            yield from self._check(time_s, accel_mps2)
        if held_n:
            time_s, accel_mps2 = np.concatenate(held_t), np.concatenate(held_a)
            held_t.clear()
            held_a.clear()
            yield from self._check(time_s, accel_mps2)

    def _check(self, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64]) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        m = time_s.shape[0]
        nan = np.isnan(time_s) | np.isnan(accel_mps2).any(axis=1)
        far = ~(np.abs(time_s) <= MAX_TIME_S)
        # Steps into each row: from the previous chunk's last time into row 0.
        previous = np.float64(self.last_s) if self.last_s is not None else np.float64(math.nan)
        with np.errstate(invalid="ignore"):
            dt_s = np.diff(time_s, prepend=previous)
            back = dt_s <= 0.0  # False where a time is NaN, and for the very first row
        first_bad = _first(nan | far | back)
        step_known = self.reference_step_s is not None
        if not step_known:
            steps = dt_s[1:first_bad] if self.last_s is None else dt_s[:first_bad]
            if steps.size:
                self.reference_step_s = _median(steps[:REFERENCE_STEPS])
        if self.reference_step_s is not None:
            step_s = self.reference_step_s
            with np.errstate(invalid="ignore"):
                off = np.abs(dt_s - step_s) > TIME_STEP_TOLERANCE * step_s
            first_bad = min(first_bad, _first(off))
            if not step_known and self._off_the_rate(step_s):
                # The rows' step is not the rate the reader was opened with (first to last time):
                # a gap further in. No row is given, as every one would be used at the wrong rate.
                if first_bad < m:
                    self._raise(first_bad, time_s, accel_mps2, dt_s, nan, far, back)
                self.reader.error(
                    f"its first time steps of {step_s:.6g} s ({1.0 / step_s:.6g} Hz) are not its rate from the first to the last "
                    f"time ({self.reader.fs_hz:.6g} Hz): a gap or a jump further in; recordings must be uniformly sampled: "
                    "split the file at the gap"
                )
        good_t, good_a = time_s[:first_bad], accel_mps2[:first_bad]
        if first_bad:
            beyond = (good_a < MIN_ACCEL_MPS2) | (good_a > MAX_ACCEL_MPS2)
            n_beyond = int(np.count_nonzero(beyond))
            if n_beyond:
                good_a = np.clip(good_a, MIN_ACCEL_MPS2, MAX_ACCEL_MPS2)
                self.reader.clipped_samples += n_beyond
            yield good_t, good_a  # the rows before a bad one are used: only the bad row stops the reading
        if first_bad < m:
            self._raise(first_bad, time_s, accel_mps2, dt_s, nan, far, back)
        self.rows += m
        self.last_s = float(time_s[-1])

    def _off_the_rate(self, step_s: float) -> bool:
        """Whether the file's step disagrees with the rate its reader announced (its survey's, when there was one)."""
        fs_hz = self.reader.fs_hz
        if math.isnan(self.reader.start_s) or not (math.isfinite(fs_hz) and fs_hz > 0):
            return False  # _check_whole reads the rows through for a bad one: no rate is announced
        return abs(1.0 / fs_hz - step_s) > TIME_STEP_TOLERANCE * step_s

    def _raise(self, i: int, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], dt_s: NDArray[np.float64],
               nan: NDArray[np.bool_], far: NDArray[np.bool_], back: NDArray[np.bool_]) -> NoReturn:  # fmt: skip
        reader, row = self.reader, self.rows + i
        if nan[i]:
            reader.row_error(row, "a value is NaN (no reading); remove or repair the row")
        if far[i]:
            reader.row_error(
                row,
                f"time_s {float(time_s[i])!r} is no plausible time (beyond +/-{MAX_TIME_S:.0f} s, the year 2100 as "
                "Unix time): time_s must be in seconds",
            )
        previous_s = float(time_s[i - 1]) if i > 0 else self.last_s
        if back[i]:
            reader.row_error(
                row, f"time_s {float(time_s[i])!r} does not increase (previous {previous_s!r}); rows must be in strictly increasing time"
            )
        step_s = self.reference_step_s
        assert step_s is not None
        reader.row_error(
            row,
            f"time step {float(dt_s[i]):.6g} s differs from the file's {step_s:.6g} s ({1.0 / step_s:.6g} Hz); "
            "recordings must be uniformly sampled: split the file at the gap",
        )


def _median(values: NDArray[np.float64]) -> float:
    """np.median of finite values, the same bits (the middle one, or the mean of the two middle
    ones), without the numpy.ma that np.median imports to check for masked arrays."""
    ordered = np.sort(values)
    middle = ordered.size // 2
    return float(ordered[middle] if ordered.size % 2 else (ordered[middle - 1] + ordered[middle]) / 2.0)


def _first(mask: NDArray[np.bool_]) -> int:
    """The index of the first True, or len(mask) if none."""
    i = int(np.argmax(mask)) if mask.size else 0
    return i if mask.size and mask[i] else mask.shape[0]


def open_recording_reader(path: str | Path, min_samples: int = 2) -> RecordingReader:
    """Open a recording (CSV, .csv.gz or Parquet, by its name or its first bytes) for reading.

    RecordingError naming the file for a file that cannot be read, is no recording, holds fewer
    than min_samples rows (a bad row in it named first), or whose times give no finite rate.
    """
    path = Path(path)
    with open_untrusted(path, RECORDING_FILE, RecordingError) as f:
        parquet = path.name.lower().endswith(PARQUET_SUFFIX) or (not f.compressed and os.pread(f.fileno(), 4, 0) == PARQUET_MAGIC)
    if parquet and not parquet_available():
        raise RecordingError(f"{path}: a Parquet recording {NEEDS_PYARROW}")
    reader: RecordingReader = _ParquetReader(path) if parquet else _CsvReader(path)
    reader.open(min_samples)  # type: ignore[attr-defined]
    return reader


def read_recording(path: str | Path, min_samples: int = 2) -> Recording:
    """Read and check a whole recording (CSV, .csv.gz or Parquet) into memory; RecordingError
    naming the file and line on any problem."""
    return open_recording_reader(path, min_samples).read_all()


def read_csv_recording(path: str | Path, min_samples: int = 2) -> Recording:
    """read_recording, by its name from before Parquet recordings (it reads them too)."""
    return read_recording(path, min_samples)


# -- CSV -----------------------------------------------------------------------------------------


class _CsvReader(RecordingReader):
    """A CSV recording, plain or gzip: surveyed at the open, parsed by pyarrow's streaming reader."""

    format = "csv"

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path
        self._header_bytes = 0

    def open(self, min_samples: int) -> None:
        with open_untrusted(self.path, RECORDING_FILE, RecordingError) as f:
            first_chunk = f.read(MAX_LINE_BYTES + 2)
            end = re.search(rb"\r\n|\r|\n", first_chunk)
            header = first_chunk[: end.start()] if end else first_chunk
            if len(header) > MAX_LINE_BYTES:
                f.refuse_line(1, f"longer than {size_text(MAX_LINE_BYTES)}")
            self._header_bytes = end.end() if end else len(first_chunk)
            try:
                text = header.decode("utf-8-sig")
            except UnicodeDecodeError:
                _drain(f)  # a damaged gzip stream inflates to garbage: call it damaged, not text
                self.error(f"not a text file: expected a CSV recording with header '{HEADER}'")
            if text.strip() != HEADER:
                _drain(f)
                shown = text.strip()[:60] or "an empty line"
                self.error(f"line 1: expected the header '{HEADER}', found '{shown}'")
            survey = _survey(f, first_chunk[self._header_bytes :])
        self.n_samples = survey.rows
        self._check_whole(min_samples, _row_time(survey.first), _row_time(survey.last))

    def where(self, row: int) -> str:
        return f"line {self._line_of_row(row)}"

    def _data_lines(self) -> Iterator[tuple[int, bytes]]:
        """(line number, bytes) of every line after the header."""
        with open_untrusted(self.path, RECORDING_FILE, RecordingError) as f:
            _skip(f, self._header_bytes)
            yield from f.lines(first_number=2)

    def _line_of_row(self, row: int) -> int:
        """The file line of data row `row` (blank lines hold no row: count them out)."""
        i = 0
        for number, line in self._data_lines():
            if line:
                if i == row:
                    return number
                i += 1
        raise AssertionError(f"row {row} not found in {self.path}")  # pragma: no cover - rows come from the file

    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        parse, refused = _csv_parser()
        number = 2  # the first line of the block
        with open_untrusted(self.path, RECORDING_FILE, RecordingError) as f:
            _skip(f, self._header_bytes)
            try:
                for block in _line_blocks(f):
                    try:
                        yield from parse(block)
                    except refused as exc:
                        if not block.strip(b"\r\n"):
                            continue  # blank lines alone: pyarrow calls that an empty file
                        # The rows before the bad line are used; then the error names it.
                        offset, problem = self._first_bad_line(block, number, str(exc))
                        if block[:offset].strip(b"\r\n"):
                            yield from parse(block[:offset])
                        self.error(problem)
                    # Line numbers for messages; CRs counted only where there is one (two more
                    # scans of every block cost a tenth of a second per hour of recording).
                    number += block.count(b"\n") + (block.count(b"\r") - block.count(b"\r\n") if b"\r" in block else 0)
            except _LongLine:
                self.error(f"line {number}: longer than {size_text(MAX_LINE_BYTES)}; {RECORDING_FILE.description}: is this the right file?")

    def _first_bad_line(self, block: bytes, number: int, parse_error: str) -> tuple[int, str]:
        """(where in block the first line pyarrow refuses starts, why): its lines scanned one by one."""
        start = 0
        for found in (*_LINE_BREAK.finditer(block), None):
            line = block[start : found.start() if found else len(block)]
            problem = _line_problem(line) if line else None
            if problem is not None:
                return start, f"line {number}: {problem}"
            if found is None:
                break
            start, number = found.end(), number + 1
        cut = parse_error if len(parse_error) <= 200 else parse_error[:197] + "..."
        return len(block), f"cannot parse the rows: {cut}"


CsvParse = Callable[[bytes], Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]]


def _csv_parser() -> tuple[CsvParse, type[Exception]]:
    """The parser of a block of whole lines, and what it raises for a line that is no row:
    pyarrow's CSV reader where it is installed, else numpy's (drivers/csv_rows.py: the same rows
    to the bits, the same lines refused; a gateway installs without pyarrow)."""
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ModuleNotFoundError:

        def parse_numpy(block: bytes) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
            rows = parse_rows(block)
            if rows.shape[0]:
                yield np.ascontiguousarray(rows[:, 0]), np.ascontiguousarray(rows[:, 1:])

        return parse_numpy, RowsError

    # One parse per block of whole lines, in this thread: no reader threads, no read-ahead,
    # nothing of pyarrow's left running when the reading stops at a bad row.
    read_options = pacsv.ReadOptions(column_names=list(COLUMNS), block_size=2 * MAX_LINE_BYTES + 2, use_threads=False)
    parse_options = pacsv.ParseOptions(quote_char=False, double_quote=False, escape_char=False, ignore_empty_lines=True)
    convert_options = pacsv.ConvertOptions(
        column_types=dict.fromkeys(COLUMNS, pa.float64()), null_values=[], strings_can_be_null=False, quoted_strings_can_be_null=False
    )

    def parse_arrow(block: bytes) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        for batch in pacsv.read_csv(pa.py_buffer(block), read_options, parse_options, convert_options).to_batches():
            yield _columns(batch)

    return parse_arrow, pa.ArrowInvalid


def _line_problem(line: bytes) -> str | None:
    """Why a line is no row of four numbers as pyarrow reads them, or None if it is one."""
    try:
        line.decode("utf-8")
    except UnicodeDecodeError as exc:
        cut = " (cut in the middle of a character: the file is truncated)" if exc.reason == "unexpected end of data" else ""
        return f"not UTF-8 text, byte 0x{line[exc.start]:02x} at column {exc.start + 1}{cut}; remove or repair the line"
    cells = line.split(b",")
    if len(cells) != 4:
        return f"expected 4 comma-separated values ({HEADER}), found {len(cells)}"
    for name, cell in zip(COLUMNS, cells, strict=True):
        if not _NUMBER.fullmatch(cell):
            return f"{name} is not a number: '{cell.decode().strip()[:40]}'"
    return None


@dataclass(frozen=True)
class _Survey:
    rows: int  # non-blank lines after the header
    first: bytes | None  # the first of them
    last: bytes | None  # the last of them


class _LongLine(Exception):
    """A line longer than MAX_LINE_BYTES was being read."""


def _line_blocks(f: UntrustedFile, data: bytes = b"") -> Iterator[bytes]:
    """The stream from here (after `data`, already read from it) in blocks of whole lines: each
    ends with a line break but the last, and none holds a line longer than MAX_LINE_BYTES
    (_LongLine once one is that long). A CR ending a read is kept for the next block: it may be
    the first half of a CRLF."""
    tail = b""
    while True:
        chunk = f.read(MAX_LINE_BYTES)
        data = tail + data + chunk if tail else data + chunk
        if not chunk:
            if data:
                yield data
            return
        stop = len(data) - 1 if data.endswith(b"\r") else len(data)
        cut = max(data.rfind(b"\n", 0, stop), data.rfind(b"\r", 0, stop)) + 1
        if cut:
            yield data[:cut]
        tail = data[cut:]
        if len(tail) > MAX_LINE_BYTES:
            raise _LongLine
        data = b""


def _survey(f: UntrustedFile, data: bytes) -> _Survey:
    """Count the rows after the header (lines holding anything) and keep the first and the last:
    the file's length and rate before its samples are parsed. Reads at C speed (a line break is
    CR, LF or both; a blank line holds no row)."""
    rows = 0
    first: bytes | None = None
    last: bytes | None = None
    number = 2  # the line being read: the message about a line too long names it
    try:
        for lines in _line_blocks(f, data):
            n, breaks = _count_lines(lines)
            if n:
                rows += n
                if first is None:
                    found = _NOT_BREAK.search(lines)
                    first = found.group() if found else None
                body = lines.rstrip(b"\r\n")
                last = body[max(body.rfind(b"\n"), body.rfind(b"\r")) + 1 :]
            number += breaks
    except _LongLine:
        f.refuse_line(number, f"longer than {size_text(MAX_LINE_BYTES)}")
    return _Survey(rows, first, last)


def _count_lines(data: bytes) -> tuple[int, int]:
    """(lines holding anything, line breaks) in data, numpy's vector compare over its bytes (a
    CRLF is one line break; so is a lone CR or LF)."""
    if b"\r" not in data and b"\n\n" not in data:
        # What a recorder writes: LF only and no blank line, so every line break but a last one
        # starts a line. One C scan of the bytes instead of numpy's four.
        breaks = data.count(b"\n")
        return (breaks - data.endswith(b"\n") + (data[:1] not in (b"\n", b""))), breaks
    codes = np.frombuffer(data, dtype=np.uint8)
    crlf = data.count(b"\r\n") if data.find(b"\r") >= 0 else -1
    line_break = codes == 10 if crlf < 0 else (codes == 10) | (codes == 13)
    breaks = int(np.count_nonzero(line_break)) - max(crlf, 0)
    starts = int(np.count_nonzero(line_break[:-1] & ~line_break[1:])) + int(not line_break[0])
    return starts, breaks


def _row_time(line: bytes | None) -> float | None:
    """The time of a row as the parser reads it, or None if the row is no row of four numbers."""
    if line is None:
        return None
    cells = line.split(b",")
    if len(cells) != 4 or not _NUMBER.fullmatch(cells[0]):
        return None
    try:
        return float(cells[0])
    except ValueError:  # nan(...): pyarrow's NaN, no time
        return None


def _skip(f: UntrustedFile, n_bytes: int) -> None:
    while n_bytes > 0:
        chunk = f.read(min(n_bytes, 1 << 20))
        if not chunk:
            return
        n_bytes -= len(chunk)


def _drain(f: UntrustedFile) -> None:
    """Read a compressed stream to its end: a damaged one is an error of its own."""
    if f.compressed:
        while f.read(1 << 20):
            pass


def _columns(batch: pa.RecordBatch) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    time_s = _numpy(batch.column(0))
    accel = np.column_stack([_numpy(batch.column(i)) for i in (1, 2, 3)])
    return time_s, accel


def _numpy(column: pa.Array) -> NDArray[np.float64]:
    """A float64 column as a numpy view of its values' buffer (no nulls: refused before, and none
    in the CSV's types). Array.to_numpy gives the same view, after importing pandas (a tenth of a
    second of a command's start-up) to learn that it need not convert."""
    if column.null_count:
        return column.to_numpy(zero_copy_only=False)
    values = np.frombuffer(column.buffers()[1], dtype=np.float64, count=len(column), offset=8 * column.offset)
    values.flags.writeable = False  # as to_numpy's view: the file's values, not a scratch array
    return values


# -- Parquet -------------------------------------------------------------------------------------


class _ParquetReader(RecordingReader):
    """A Parquet recording: its footer checked at the open, read a row group at a time."""

    format = "parquet"

    def __init__(self, path: Path) -> None:
        super().__init__()
        self.path = path

    def where(self, row: int) -> str:
        return f"row {row + 1}"

    def _open_file(self, f: UntrustedFile) -> pq.ParquetFile:
        import pyarrow as pa
        import pyarrow.parquet as pq

        if f.compressed:
            self.error("a Parquet recording compresses its own columns: store it as .parquet, not gzip-compressed")
        try:
            return pq.ParquetFile(
                f, thrift_string_size_limit=_PARQUET_FOOTER_LIMIT, thrift_container_size_limit=_PARQUET_FOOTER_LIMIT
            )
        except (pa.ArrowException, OSError) as exc:
            self.error(f"not a readable Parquet file ({_short(exc)}); {RECORDING_FILE.description}")

    def open(self, min_samples: int) -> None:
        import pyarrow as pa

        with open_untrusted(self.path, RECORDING_FILE, RecordingError) as f:
            pf = self._open_file(f)
            schema = pf.schema_arrow
            if schema.names != list(COLUMNS) or any(t != pa.float64() for t in schema.types):
                found = ", ".join(f"{n} {t}" for n, t in zip(schema.names[:8], schema.types[:8], strict=False))
                self.error(f"expected the float64 columns {', '.join(COLUMNS)}, found {found or 'none'}")
            meta = pf.metadata
            for i in range(meta.num_row_groups):
                group = meta.row_group(i)
                if group.num_rows > MAX_PARQUET_GROUP_ROWS:
                    self.error(
                        f"row group {i} holds {group.num_rows} rows, more than {MAX_PARQUET_GROUP_ROWS}; "
                        f"write it in row groups of at most that (write_parquet_recording uses {PARQUET_GROUP_ROWS})"
                    )
                # The row group's own total, never its columns' metadata: pyarrow 26 aborts the process
                # (a C++ exception let out of RowGroupMetaData.column()) on a column chunk whose
                # statistics carry a definition-level histogram of the wrong size (found by make fuzz).
                declared = group.total_byte_size
                if declared > len(COLUMNS) * (group.num_rows * _PARQUET_BYTES_PER_VALUE + (1 << 16)):
                    self.error(f"row group {i} declares {declared} bytes for {group.num_rows} rows: damaged, or no recording")
            self.n_samples = meta.num_rows
            first_s = last_s = None
            groups = [i for i in range(meta.num_row_groups) if meta.row_group(i).num_rows]
            if groups:
                try:
                    first = pf.read_row_group(groups[0], columns=["time_s"]).column(0)
                    last = pf.read_row_group(groups[-1], columns=["time_s"]).column(0)
                except (pa.ArrowException, OSError) as exc:
                    self.error(f"not a readable Parquet file ({_short(exc)}); {RECORDING_FILE.description}")
                # A footer may claim rows its pages do not hold (found by make fuzz: an IndexError here).
                for i, column in ((groups[0], first), (groups[-1], last)):
                    if len(column) != meta.row_group(i).num_rows:
                        self.error(f"row group {i} holds {len(column)} rows, its footer says {meta.row_group(i).num_rows}: damaged; copy it again")
                first_s = first[0].as_py()
                last_s = last[len(last) - 1].as_py()  # None if null: the rows are read through for it
        self._check_whole(min_samples, first_s, last_s)

    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        import pyarrow as pa

        with open_untrusted(self.path, RECORDING_FILE, RecordingError) as f:
            pf = self._open_file(f)
            row = 0
            for i in range(pf.metadata.num_row_groups):
                try:
                    table = pf.read_row_group(i, use_threads=False)
                except (pa.ArrowException, OSError) as exc:
                    self.error(f"row group {i}: not readable ({_short(exc)}); the recording is damaged: copy it again")
                if table.num_rows:
                    if any(column.null_count for column in table.columns):
                        nulls = np.flatnonzero(np.any([column.is_null().to_numpy(zero_copy_only=False) for column in table.columns], axis=0))
                        self.row_error(row + int(nulls[0]), "a value is missing (null); remove or repair the row")
                    for batch in table.to_batches():
                        yield _columns(batch)
                row += table.num_rows


def _short(exc: BaseException, limit: int = 200) -> str:
    text = str(exc) or type(exc).__name__
    return text if len(text) <= limit else text[: limit - 3] + "..."


# ------------------------------------------------------------------------------------------------
# Writing


def write_recording(path: str | Path, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], *, fsync: bool = False) -> None:
    """Write a recording in the format its name asks for: .parquet, else CSV (.gz: compressed)."""
    if str(path).lower().endswith(PARQUET_SUFFIX):
        write_parquet_recording(path, time_s, accel_mps2, fsync=fsync)
    else:
        write_csv_recording(path, time_s, accel_mps2, fsync=fsync)


def _rows(time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    time_s = np.asarray(time_s, dtype=np.float64)
    accel = np.asarray(accel_mps2, dtype=np.float64)
    if accel.shape != (time_s.shape[0], 3):
        raise ValueError(f"time_s {time_s.shape} and accel_mps2 {accel.shape} do not form a recording")
    return time_s, accel


def write_csv_recording(
    path: str | Path, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], *, fsync: bool = False
) -> None:
    """Write a recording; times with microsecond resolution, accelerations with 6 decimals (1e-6 m/s^2).

    A path ending in .gz is written gzip-compressed (no name and no time stamp in the gzip header:
    the same samples give the same bytes). fsync: on the disk before this returns (a file about
    to be renamed into place must be whole there first).
    """
    path = Path(path)
    time_s, accel = _rows(time_s, accel_mps2)
    rows = np.column_stack([time_s, accel])
    with path.open("wb") as raw:
        if path.name.lower().endswith(".gz"):
            with gzip.GzipFile(filename="", mode="wb", fileobj=raw, compresslevel=GZIP_LEVEL, mtime=0) as packed:
                _write_rows(packed, rows)  # closing the gzip stream writes its trailer, and leaves `raw` open
        else:
            _write_rows(raw, rows)
        if fsync:
            raw.flush()
            os.fsync(raw.fileno())


def _write_rows(f: BinaryIO | gzip.GzipFile, rows: NDArray[np.float64]) -> None:
    f.write((HEADER + "\n").encode("ascii"))
    # Exactly np.savetxt(fmt="%.6f")'s text (the same printf formatting), but one %-format call
    # per chunk of rows instead of one per row: 1.6x faster (3.7 s -> 2.3 s for an hour at 500 Hz
    # here), memory bounded by the chunk. The text is ASCII: digits, signs, points and commas.
    for start in range(0, rows.shape[0], _WRITE_CHUNK_ROWS):
        chunk = rows[start : start + _WRITE_CHUNK_ROWS]
        f.write(((_ROW_FORMAT * chunk.shape[0]) % tuple(chunk.ravel().tolist())).encode("ascii"))


def write_parquet_recording(
    path: str | Path, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], *, fsync: bool = False
) -> None:
    """Write a Parquet recording: the samples exactly (float64), in row groups of PARQUET_GROUP_ROWS.

    The accelerations are dictionary-encoded (a 16-bit converter gives at most 65536 values a
    channel: two bytes a sample before zstd), the times byte-stream-split (their exponent and high
    bytes repeat); both then zstd. The same samples give the same bytes (with the same pyarrow).
    fsync: on the disk before this returns.
    """
    if not parquet_available():
        raise RecordingError(f"{path}: writing a Parquet recording {NEEDS_PYARROW}")
    import pyarrow as pa
    import pyarrow.parquet as pq

    time_s, accel = _rows(time_s, accel_mps2)
    schema = pa.schema([pa.field(name, pa.float64(), nullable=False) for name in COLUMNS])
    table = pa.Table.from_arrays([pa.array(time_s), *(pa.array(np.ascontiguousarray(accel[:, i])) for i in range(3))], schema=schema)
    with Path(path).open("wb") as raw:
        pq.write_table(
            table, raw, row_group_size=PARQUET_GROUP_ROWS, compression="zstd",
            use_dictionary=list(COLUMNS[1:]), use_byte_stream_split=[COLUMNS[0]],
        )  # fmt: skip
        if fsync:
            raw.flush()
            os.fsync(raw.fileno())
