"""CSV recordings: the bench's exchange format between the simulator, loggers and `analyze`.

Format: a first line exactly `time_s,a1,a2,a3`, then one row per sampling instant: the time in
seconds from any origin, and the three vertical accelerations in m/s^2 (with or without gravity).
Rows are uniformly sampled and strictly increasing in time; the sample rate is inferred from
time_s. A recording with a gap is two recordings. Times are plausible ones (drivers/base.py:
finite, within +/-MAX_TIME_S) and the rate finite.

A bad row is an error naming its line, never a skipped one: the rows are one uniform time axis,
so a row left out would shift every later sample by a period without a trace. A file cut in the
middle of a UTF-8 character (a logger killed mid-write) is such a bad row.

A recording may be gzip-compressed (`.csv.gz`, what the gateway's recorder writes): it is read
when its name ends in .gz or its first bytes are gzip's magic, with the same checks and messages;
a compressed stream that is cut short or damaged is an error naming the file.

Reading is vectorised (numpy's C parser); only when the fast path finds a problem is the file
scanned line by line, to name the exact line in the error.
"""

from __future__ import annotations

import gzip
import io
import math
import os
import warnings
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, TextIO

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S, Block

HEADER = "time_s,a1,a2,a3"
# A time step may deviate this much (relative) from the file's median step: enough for times
# printed with 6 decimals at 1 kHz, far less than the 100 % of one lost sample.
TIME_STEP_TOLERANCE = 0.01
_ROW_FORMAT = "%.6f,%.6f,%.6f,%.6f\n"
_WRITE_CHUNK_ROWS = 65536
GZIP_MAGIC = b"\x1f\x8b"
# zlib's level 6 (gzip's own default): on 220 s of simulated bogie at 500 Hz (5.1 MB of text) 1.80 MB
# in 0.35 s here, against 1.78 MB in 1.2 s at level 9 and 2.02 MB in 0.06 s at level 1.
GZIP_LEVEL = 6
# What a damaged or cut gzip stream raises while it is read (BadGzipFile is an OSError).
_GZIP_ERRORS = (EOFError, zlib.error, gzip.BadGzipFile)


class RecordingError(ValueError):
    """A recording that cannot be used; the message names the file, the line and the remedy."""


@dataclass(frozen=True)
class Recording:
    """A whole recording in memory."""

    path: Path
    time_s: NDArray[np.float64]  # (n,)
    accel_mps2: NDArray[np.float64]  # (n, 3)
    fs_hz: float

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    def blocks(self, block_n: int) -> list[Block]:
        """The recording cut into consecutive Blocks of block_n samples (the last may be shorter)."""
        return [
            Block(start_s=float(self.time_s[i]), fs_hz=self.fs_hz, accel_mps2=self.accel_mps2[i : i + block_n])
            for i in range(0, self.n_samples, block_n)
        ]


def is_csv_recording_name(path: str | Path) -> bool:
    """Whether a file name is a CSV recording's (.csv, or .csv.gz compressed), not a CAN log's."""
    return str(path).lower().endswith((".csv", ".csv.gz"))


def read_csv_recording(path: str | Path, min_samples: int = 2) -> Recording:
    """Read and validate a CSV recording, plain or gzip-compressed; raise RecordingError naming the
    file and line on any problem."""
    path = Path(path)
    try:
        return _read_csv_recording(path, min_samples)
    except _GZIP_ERRORS as exc:  # from any of the passes over the file: the first read, or a line scan
        raise RecordingError(_gzip_problem(path, exc)) from None


def _gzip_problem(path: Path, exc: BaseException) -> str:
    if isinstance(exc, EOFError):
        return f"{path}: the compressed recording is cut short (its gzip stream ends early: a partial copy or upload?); copy it again"
    return f"{path}: not a readable gzip file ({exc}); the compressed recording is damaged: copy it again"


def _is_gzip(path: Path) -> bool:
    if path.name.lower().endswith(".gz"):
        return True
    with path.open("rb") as f:
        return f.read(len(GZIP_MAGIC)) == GZIP_MAGIC


def _open_bytes(path: Path) -> BinaryIO:
    """The recording's bytes, decompressed if it is gzip."""
    if _is_gzip(path):
        return gzip.open(path, "rb")  # type: ignore[return-value]
    return path.open("rb")


def _open_text(path: Path) -> TextIO:
    return io.TextIOWrapper(_open_bytes(path), encoding="utf-8-sig", newline="")


def _check_whole_stream(path: Path) -> None:
    """Before naming a bad line of a gzip file: read it to its end, so that a damaged stream (which
    may inflate to garbage lines before its checksum fails) is called damaged, not a bad row."""
    if _is_gzip(path):
        with gzip.open(path, "rb") as f:
            while f.read(1 << 20):
                pass


def _read_csv_recording(path: Path, min_samples: int) -> Recording:
    try:
        with _open_text(path) as f:
            header = f.readline()
            if header.strip() != HEADER:
                _check_whole_stream(path)
                shown = header.strip()[:60] or "an empty line"
                raise RecordingError(f"{path}: line 1: expected the header '{HEADER}', found '{shown}'")
            parse_error = ""
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", UserWarning)  # "input contained no data"
                    data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2, comments=None)
            except UnicodeDecodeError:  # a ValueError too: numpy's parser passes it on
                _raise_not_utf8(path)
            except ValueError as exc:
                data, parse_error = None, str(exc)
    except OSError as exc:
        if isinstance(exc, gzip.BadGzipFile):
            raise
        raise RecordingError(f"{path}: cannot read the recording: {exc.strerror or exc}") from None
    except UnicodeDecodeError:  # text is decoded by the chunk: this may be any of the first lines
        _raise_not_utf8(path)

    if data is None or data.shape[1] != 4:
        _raise_first_bad_line(path, parse_error)
    if not np.isfinite(data).all():
        row = int(np.argmax(~np.isfinite(data).all(axis=1)))
        raise RecordingError(f"{path}: line {_line_of_row(path, row)}: a value is NaN or infinite; remove or repair the row")
    n = data.shape[0]
    if n < 2:
        raise RecordingError(f"{path}: holds {n} sample(s); a recording needs at least two rows after the header")

    time_s = np.ascontiguousarray(data[:, 0])
    far = np.flatnonzero(np.abs(time_s) > MAX_TIME_S)
    if far.size:
        row = int(far[0])
        raise RecordingError(
            f"{path}: line {_line_of_row(path, row)}: time_s {float(time_s[row])!r} is no plausible time "
            f"(beyond +/-{MAX_TIME_S:.0f} s, the year 2100 as Unix time): time_s must be in seconds"
        )
    dt_s = np.diff(time_s)
    bad = np.flatnonzero(dt_s <= 0.0)
    if bad.size:
        row = int(bad[0]) + 1
        raise RecordingError(
            f"{path}: line {_line_of_row(path, row)}: time_s {float(time_s[row])!r} does not increase "
            f"(previous {float(time_s[row - 1])!r}); rows must be in strictly increasing time"
        )
    step_s = float(np.median(dt_s))
    bad = np.flatnonzero(np.abs(dt_s - step_s) > TIME_STEP_TOLERANCE * step_s)
    if bad.size:
        row = int(bad[0]) + 1
        raise RecordingError(
            f"{path}: line {_line_of_row(path, row)}: time step {dt_s[row - 1]:.6g} s differs from the file's "
            f"{step_s:.6g} s ({1.0 / step_s:.6g} Hz); recordings must be uniformly sampled: split the file at the gap"
        )
    # The mean step over the whole file is far more precise than any single printed step.
    with np.errstate(over="ignore"):
        fs_hz = float((n - 1) / (time_s[-1] - time_s[0]))
    if not np.isfinite(fs_hz):
        raise RecordingError(
            f"{path}: time steps of {step_s:.6g} s give no finite sample rate: time_s must be in seconds"
        )
    if n < min_samples:
        raise RecordingError(
            f"{path}: {n} samples ({n / fs_hz:.1f} s) is shorter than one analysis window "
            f"({min_samples} samples, {min_samples / fs_hz:.1f} s): use a longer recording or a shorter window_s"
        )
    return Recording(path=path, time_s=time_s, accel_mps2=np.ascontiguousarray(data[:, 1:]), fs_hz=fs_hz)


def write_csv_recording(
    path: str | Path, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], *, fsync: bool = False
) -> None:
    """Write a recording; times with microsecond resolution, accelerations with 6 decimals (1e-6 m/s^2).

    A path ending in .gz is written gzip-compressed (no name and no time stamp in the gzip header:
    the same samples give the same bytes). fsync: on the disk before this returns (a file about
    to be renamed into place must be whole there first).
    """
    path = Path(path)
    time_s = np.asarray(time_s, dtype=np.float64)
    accel = np.asarray(accel_mps2, dtype=np.float64)
    if accel.shape != (time_s.shape[0], 3):
        raise ValueError(f"time_s {time_s.shape} and accel_mps2 {accel.shape} do not form a recording")
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


def _data_lines(path: Path) -> Iterator[tuple[int, str]]:
    """(line number, text) of every non-blank line after the header."""
    with _open_text(path) as f:
        f.readline()
        for number, line in enumerate(f, start=2):
            if line.strip():
                yield number, line.strip()


def _line_of_row(path: Path, row: int) -> int:
    """The file line of data row `row` (numpy skips blank lines, so count them out)."""
    for i, (number, _) in enumerate(_data_lines(path)):
        if i == row:
            return number
    raise AssertionError(f"row {row} not found in {path}")  # pragma: no cover - rows come from the file


def _raise_not_utf8(path: Path) -> None:
    """Raise for the first line that is not UTF-8 text (the header decoded, so a data line)."""
    _check_whole_stream(path)
    with _open_bytes(path) as f:
        for number, raw in enumerate(f, start=1):
            try:
                raw.decode("utf-8")
            except UnicodeDecodeError as exc:
                if number == 1:
                    raise RecordingError(f"{path}: not a text file: expected a CSV recording with header '{HEADER}'") from None
                cut = " (cut in the middle of a character: the file is truncated)" if exc.reason == "unexpected end of data" else ""
                raise RecordingError(
                    f"{path}: line {number}: not UTF-8 text, byte 0x{raw[exc.start]:02x} at column {exc.start + 1}{cut}; "
                    "remove or repair the line"
                ) from None
    raise RecordingError(f"{path}: not UTF-8 text: expected a CSV recording with header '{HEADER}'")  # pragma: no cover


def _raise_first_bad_line(path: Path, parse_error: str) -> None:
    """Scan line by line for the first row that is not four numbers, and raise for it."""
    _check_whole_stream(path)
    n_rows = 0
    for number, text in _data_lines(path):
        n_rows += 1
        cells = text.split(",")
        if len(cells) != 4:
            raise RecordingError(
                f"{path}: line {number}: expected 4 comma-separated values (time_s,a1,a2,a3), found {len(cells)}"
            )
        for name, cell in zip(HEADER.split(","), cells, strict=True):
            try:
                value = float(cell)
            except ValueError:
                raise RecordingError(f"{path}: line {number}: {name} is not a number: '{cell.strip()[:40]}'") from None
            if not math.isfinite(value):
                raise RecordingError(f"{path}: line {number}: {name} is {cell.strip()}; remove or repair the row")
    if n_rows:  # numpy rejected something float() accepts (e.g. "1_000"): pass its words on
        raise RecordingError(f"{path}: cannot parse the rows: {parse_error}")
    raise RecordingError(f"{path}: holds no samples after the header")
