"""What a recording of samples is: its columns, the converter's range, the bounds of a file that
is read, the formats it is written in, its error and the whole recording in memory (drivers/
recording.py says how the formats hold it; the readers and writers are in recording_csv.py and
recording_parquet.py, the checks of every row in recording_check.py)."""

from __future__ import annotations

import enum
import importlib.util
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import Block
from bogiemon.drivers.files import FileKind
from bogiemon.drivers.quoting import quoted

if TYPE_CHECKING:
    import pyarrow as pa

HEADER = "time_s,a1,a2,a3"
COLUMNS = ("time_s", "a1", "a2", "a3")

# The converter's range (config/bogiemon.dbc: int16 samples, 1 LSB = 16 g / 32768, g = 9.80665
# m/s^2): -16 g .. +16 g - 1 LSB. A sample beyond it is clipped to it at the source boundary.
ACCEL_LSB_MPS2 = 16 * 9.80665 / 32768
MIN_ACCEL_MPS2 = -32768 * ACCEL_LSB_MPS2  # -156.9064 m/s^2
MAX_ACCEL_MPS2 = 32767 * ACCEL_LSB_MPS2  # +156.9016 m/s^2

# A step longer than the file's by more than this (relative) is a gap: samples were lost (one lost
# sample is 100 %). Within it, a logger's jitter (+-0.2 ms at 500 Hz is 10 %): recording_check.py
# resamples such a segment onto its nominal grid.
JITTER_TOLERANCE = 0.25

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

PARQUET_MAGIC = b"PAR1"
MF4_MAGIC = (b"MDF     ", b"UnFinMF ")  # an MF4's identification block: finished, or a logger's unfinished file
PARQUET_SUFFIX = ".parquet"


class RecordingFormat(enum.StrEnum):
    """The formats a recording is written in (`[recorder] format`); read by any of its names."""

    CSV_GZ = "csv.gz"
    PARQUET = "parquet"

    @property
    def suffix(self) -> str:
        return f".{self.value}"


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
    resampled_samples: int = 0  # samples of jittered stretches, interpolated onto the nominal grid

    @property
    def n_samples(self) -> int:
        return int(self.time_s.shape[0])

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    @property
    def start_s(self) -> float:
        return float(self.time_s[0])

    def segments(self) -> list[tuple[int, int]]:
        """(first row, end row) of each stretch without a gap, in order."""
        bounds = [0, *gap_rows(self.time_s, self.fs_hz).tolist(), self.n_samples]
        return list(zip(bounds[:-1], bounds[1:], strict=True))

    def blocks(self, block_n: int) -> list[Block]:
        """The recording cut into consecutive Blocks of at most block_n samples; a block never
        spans a gap, and the first after one says so (gap_before)."""
        return [
            Block(start_s=float(self.time_s[i]), fs_hz=self.fs_hz, accel_mps2=self.accel_mps2[i : min(i + block_n, hi)], gap_before=i == lo and lo > 0)
            for lo, hi in self.segments()
            for i in range(lo, hi, block_n)
        ]  # fmt: skip

    def chunks(self, chunk_n: int = 65536) -> Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None]:
        """(time_s, accel_mps2) in consecutive chunks, as RecordingReader.chunks gives them (none
        spans a gap)."""
        for lo, hi in self.segments():
            for i in range(lo, hi, chunk_n):
                yield self.time_s[i : min(i + chunk_n, hi)], self.accel_mps2[i : min(i + chunk_n, hi)]


def gap_rows(time_s: NDArray[np.float64], fs_hz: float) -> NDArray[np.intp]:
    """The rows of a recording's times (n,) that follow a gap: a step from the row before longer
    than the rate's step and its jitter."""
    return np.flatnonzero(np.diff(time_s) > (1.0 + JITTER_TOLERANCE) / fs_hz) + 1


def follows_gap(previous_s: float | None, first_s: float, fs_hz: float) -> bool:
    """Whether a chunk starting at first_s follows a gap after the sample at previous_s (None: it
    is the first chunk, which starts a segment too)."""
    return previous_s is None or first_s - previous_s > (1.0 + JITTER_TOLERANCE) / fs_hz


def is_sample_recording_name(path: str | Path) -> bool:
    """Whether a file name is a recording of samples (.csv, .csv.gz, .parquet), not a CAN log's."""
    return str(path).lower().endswith((".csv", ".csv.gz", PARQUET_SUFFIX))


def arrow_columns(batch: pa.RecordBatch) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(time_s (m,), accel_mps2 (m, 3)) of a record batch of the four columns, as numpy views."""
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


def short_error(exc: BaseException, limit: int = 200) -> str:
    """An exception's message for a one-line error, cut to `limit` characters and quoted (a
    library's message may quote the file)."""
    return quoted(str(exc) or type(exc).__name__, limit)


def recording_rows(time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """(time_s (n,), accel_mps2 (n, 3)) as float64, or ValueError if they do not form a recording."""
    time_s = np.asarray(time_s, dtype=np.float64)
    accel = np.asarray(accel_mps2, dtype=np.float64)
    if accel.shape != (time_s.shape[0], 3):
        raise ValueError(f"time_s {time_s.shape} and accel_mps2 {accel.shape} do not form a recording")
    return time_s, accel
