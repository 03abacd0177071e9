"""Recordings of samples: the bench's exchange format between the simulator, loggers, the gateway's
recorder and every command that reads one (`analyze`, `replay`, `calibrate`, `play`, the fleet).

Two formats hold the same thing, one row per sampling instant: the time in seconds from any origin
and the three vertical accelerations in m/s^2 (with or without gravity).

- CSV: a first line `time_s,a1,a2,a3` (or the columns of a mapping), then rows of four numbers; plain (`.csv`) or
  gzip-compressed (`.csv.gz`, what the recorder writes: read when the name ends in .gz or the first
  bytes are gzip's magic). Written with 6 decimals.
- Parquet (`.parquet`, or a file starting with Parquet's magic): four float64 columns `time_s`,
  `a1`, `a2`, `a3`; the samples exactly as given (no decimals lost), compressed (zstd, the
  accelerations dictionary-encoded: a 16-bit converter's samples take a fraction of their text).
  Any writer's file with these columns is read (pyarrow, pandas, DuckDB, polars).

Other writers' files are read through a column mapping (drivers/columns.py: which column is the
time and in what unit, which are a1, a2, a3, a gain and offset each, the unit of the accelerations;
a CSV's delimiter by the sniffer; Parquet's float, integer and timestamp columns). A file whose
static levels say another unit than the mapping's (1 instead of 9.81: g) is refused at the open,
naming the unit it looks like: nothing is judged in a wrong unit.

Rows are strictly increasing in time, on the file's nominal grid: the rate of its steps, snapped
to the whole hertz (recording_check.py). A step within 25 % of the grid's is a logger's jitter:
the segment is resampled onto the grid and counted; a longer one is a gap (counted, listed, and a
new segment: no chunk spans it); a shorter one is a stray row, an error naming its line. Times are
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

This module picks the reader or the writer by the file's name or its first bytes, and names what
the others define: recording_format.py (the columns, the converter's range, the bounds, Recording),
recording_check.py (RecordingReader and the checks of every row), recording_csv.py and
recording_parquet.py (each format's reader and writer).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.columns import ColumnMap
from bogiemon.drivers.files import UntrustedFile, open_untrusted
from bogiemon.drivers.recording_check import REFERENCE_STEPS, TIME_STEP_TOLERANCE, RecordingReader
from bogiemon.drivers.recording_csv import GZIP_LEVEL, CsvRecordingReader, write_csv_recording
from bogiemon.drivers.recording_format import (
    ACCEL_LSB_MPS2,
    COLUMNS,
    HEADER,
    MAX_ACCEL_MPS2,
    MAX_INFLATE_RATIO,
    MAX_LINE_BYTES,
    MAX_RECORDING_BYTES,
    MF4_MAGIC,
    MIN_ACCEL_MPS2,
    NEEDS_PYARROW,
    PARQUET_MAGIC,
    PARQUET_SUFFIX,
    RECORDING_FILE,
    Recording,
    RecordingError,
    RecordingFormat,
    follows_gap,
    parquet_available,
    is_sample_recording_name,
)
from bogiemon.drivers.recording_parquet import MAX_PARQUET_GROUP_ROWS, PARQUET_GROUP_ROWS, ParquetRecordingReader, write_parquet_recording

__all__ = [
    "ACCEL_LSB_MPS2", "COLUMNS", "GZIP_LEVEL", "HEADER", "MAX_ACCEL_MPS2", "MAX_INFLATE_RATIO", "MAX_LINE_BYTES",
    "MAX_PARQUET_GROUP_ROWS", "MAX_RECORDING_BYTES", "MIN_ACCEL_MPS2", "NEEDS_PYARROW", "PARQUET_GROUP_ROWS", "PARQUET_MAGIC", "PARQUET_SUFFIX",
    "RECORDING_FILE", "REFERENCE_STEPS", "TIME_STEP_TOLERANCE", "Recording", "RecordingError", "RecordingFormat",
    "RecordingReader", "follows_gap", "is_sample_recording_name", "open_recording_reader", "parquet_available", "read_csv_recording", "read_recording",
    "write_csv_recording", "write_parquet_recording", "write_recording",
]  # fmt: skip


def open_recording_reader(path: str | Path | UntrustedFile, min_samples: int = 2, columns: ColumnMap | None = None) -> RecordingReader:
    """Open a recording (CSV, .csv.gz or Parquet, by its name or its first bytes) for reading.

    path: a name, or a file already opened by open_untrusted (read through its descriptor, never
    by its name again). The reader holds the file open until close(). columns: which columns are
    the time and the channels, in which units (default: bogiemon's own, in s and m/s^2); a file
    whose levels say another unit than the mapping's is refused, naming the unit it looks like.

    RecordingError naming the file for a file that cannot be read, is no recording, holds fewer
    than min_samples rows (a bad row in it named first), or whose times give no finite rate.
    """
    f = path.reopen(RECORDING_FILE) if isinstance(path, UntrustedFile) else open_untrusted(path, RECORDING_FILE, RecordingError)
    try:
        parquet = f.path.name.lower().endswith(PARQUET_SUFFIX) or (not f.compressed and f.head(4) == PARQUET_MAGIC)
        reader: RecordingReader
        if not f.compressed and f.head(8) in MF4_MAGIC:
            from bogiemon.drivers.recording_mf4 import Mf4RecordingReader  # asammdf, for MF4 only

            reader = Mf4RecordingReader(f, columns)
        else:
            if parquet and not parquet_available():
                raise RecordingError(f"{f.path}: a Parquet recording {NEEDS_PYARROW}")
            reader = ParquetRecordingReader(f, columns) if parquet else CsvRecordingReader(f, columns)
        reader.open(min_samples)
    except BaseException:
        f.close()
        raise
    return reader


def read_recording(path: str | Path, min_samples: int = 2, columns: ColumnMap | None = None) -> Recording:
    """Read and check a whole recording (CSV, .csv.gz or Parquet) into memory; RecordingError
    naming the file and line on any problem."""
    reader = open_recording_reader(path, min_samples, columns)
    try:
        return reader.read_all()
    finally:
        reader.close()


def read_csv_recording(path: str | Path, min_samples: int = 2) -> Recording:
    """read_recording, by its name from before Parquet recordings (it reads them too)."""
    return read_recording(path, min_samples)


def write_recording(path: str | Path, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], *, fsync: bool = False) -> None:
    """Write a recording in the format its name asks for: .parquet, else CSV (.gz: compressed)."""
    if str(path).lower().endswith(PARQUET_SUFFIX):
        write_parquet_recording(path, time_s, accel_mps2, fsync=fsync)
    else:
        write_csv_recording(path, time_s, accel_mps2, fsync=fsync)

