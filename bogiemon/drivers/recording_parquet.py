"""Parquet recordings: the reader (the footer checked at the open against the bounds of a row group,
read a row group at a time) and the writer (the samples exactly, float64, zstd)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.columns import ColumnMap
from bogiemon.drivers.files import UntrustedFile
from bogiemon.drivers.parquet_pages import ParquetBoundsError, check_pages, read_footer
from bogiemon.drivers.quoting import quoted
from bogiemon.drivers.recording_check import RecordingReader
from bogiemon.drivers.recording_format import COLUMNS, NEEDS_PYARROW, RECORDING_FILE, RecordingError, arrow_columns, parquet_available, recording_rows, short_error

if TYPE_CHECKING:
    import pyarrow as pa
    import pyarrow.parquet as pq

# Rows per Parquet row group (2.1 min at 500 Hz): a row group is read whole, 2 MiB decoded.
PARQUET_GROUP_ROWS = 65536
# What a row group of a Parquet recording may hold (decoded: 32 MiB) and declare uncompressed per
# value (8 bytes plain, a dictionary of at most as many values again, page headers).
MAX_PARQUET_GROUP_ROWS = 1 << 20
_PARQUET_BYTES_PER_VALUE = 16
_PARQUET_FOOTER_LIMIT = 1 << 20  # thrift strings and containers of the footer: ours are a few KiB


class ParquetRecordingReader(RecordingReader):
    """A Parquet recording: its footer checked at the open, read a row group at a time."""

    format = "parquet"

    def __init__(self, file: UntrustedFile, columns: ColumnMap | None = None) -> None:
        super().__init__(file, columns)
        self._pf: pq.ParquetFile | None = None
        self._names: list[str] = list(COLUMNS)  # the columns read: the time's, then each channel's
        self._time_type: pa.DataType | None = None  # a timestamp column's type (read as seconds)

    def where(self, row: int) -> str:
        return f"row {row + 1}"

    def _open_file(self, f: UntrustedFile) -> pq.ParquetFile:
        import pyarrow as pa
        import pyarrow.parquet as pq

        if f.compressed:
            self.error("a Parquet recording compresses its own columns: store it as .parquet, not gzip-compressed")
        try:
            # The pages' own headers, before pyarrow inflates any (drivers/parquet_pages.py).
            groups = read_footer(f.fileno(), f.size_bytes)
            if groups:
                self._names = self._selected([chunk.name for chunk in groups[0].columns])
            check_pages(f.fileno(), f.size_bytes, groups, self._names, _PARQUET_BYTES_PER_VALUE)
        except ParquetBoundsError as exc:
            self.error(f"not a readable Parquet file ({exc}: damaged, or a compression bomb); {RECORDING_FILE.description}")
        try:
            return pq.ParquetFile(
                f, thrift_string_size_limit=_PARQUET_FOOTER_LIMIT, thrift_container_size_limit=_PARQUET_FOOTER_LIMIT
            )
        except (pa.ArrowException, OSError) as exc:
            self.error(f"not a readable Parquet file ({short_error(exc)}); {RECORDING_FILE.description}")

    def open(self, min_samples: int) -> None:
        import pyarrow as pa

        # The file stays open: every pass reads its row groups through the one descriptor.
        pf = self._pf = self._open_file(self.file)
        schema = pf.schema_arrow
        names = self._names = self._selected(schema.names)
        twice = [name for name in names if schema.names.count(name) != 1]  # nested or repeated names: no column
        if twice:
            self.error(f"the column {quoted(twice[0], 40)} is named {schema.names.count(twice[0])} times in its schema, or is no plain column; {RECORDING_FILE.description}")
        types = [schema.types[schema.names.index(name)] for name in names]
        if not all(pa.types.is_floating(t) or pa.types.is_integer(t) for t in types[1:]) or not (
            pa.types.is_floating(types[0]) or pa.types.is_integer(types[0]) or pa.types.is_timestamp(types[0])
        ):
            found = ", ".join(f"{quoted(n, 40)} {t}" for n, t in zip(names, types, strict=True))
            self.error(f"expected number columns (float, integer; the time also a timestamp), found {found}")
        if pa.types.is_timestamp(types[0]):
            self._time_type = types[0]
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
                first = self._seconds(pf.read_row_group(groups[0], columns=names[:1]).column(0))
                last = self._seconds(pf.read_row_group(groups[-1], columns=names[:1]).column(0))
            except (pa.ArrowException, OSError) as exc:
                self.error(f"not a readable Parquet file ({short_error(exc)}); {RECORDING_FILE.description}")
            # A footer may claim rows its pages do not hold (found by make fuzz: an IndexError here).
            for i, column in ((groups[0], first), (groups[-1], last)):
                if len(column) != meta.row_group(i).num_rows:
                    self.error(f"row group {i} holds {len(column)} rows, its footer says {meta.row_group(i).num_rows}: damaged; copy it again")
            first_s = first[0].as_py()
            last_s = last[len(last) - 1].as_py()  # None if null: the rows are read through for it
        if self._time_type is None:
            self.time_to_s = self.columns.resolved_time_unit(names[0], first_s).to_s
        scale = self.time_to_s
        self._check_whole(min_samples, None if first_s is None else first_s * scale, None if last_s is None else last_s * scale)

    def _selected(self, names: list[str]) -> list[str]:
        """The columns a mapping reads among a file's: the time's, then each channel's."""
        try:
            return self.columns.select(names)
        except ValueError as exc:
            self.error(f"expected the columns time_s, a1, a2, a3 or those of a mapping, found {', '.join(quoted(n, 40) for n in names[:8]) or 'none'}: {exc}")

    def _seconds(self, column: pa.ChunkedArray) -> pa.ChunkedArray:
        """A time column as float64 in its own unit (a timestamp: seconds from the Unix epoch)."""
        import pyarrow as pa
        import pyarrow.compute as pc

        if self._time_type is None:
            return column.cast(pa.float64())
        unit = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[self._time_type.unit]
        return pc.multiply(column.cast(pa.int64()).cast(pa.float64(), safe=False), unit)  # ns of 2025: float64 to 256 ns

    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        import pyarrow as pa

        pf = self._pf
        assert pf is not None, "opened by open_recording_reader"
        row = 0
        for i in range(pf.metadata.num_row_groups):
            try:
                table = pf.read_row_group(i, columns=self._names, use_threads=False)
                table = pa.table([self._seconds(table.column(0)), *(table.column(j).cast(pa.float64()) for j in range(1, table.num_columns))],
                                 names=[f"c{j}" for j in range(table.num_columns)])  # fmt: skip
            except (pa.ArrowException, OSError) as exc:
                self.error(f"row group {i}: not readable ({short_error(exc)}); the recording is damaged: copy it again")
            if table.num_rows:
                if any(column.null_count for column in table.columns):
                    nulls = np.flatnonzero(np.any([column.is_null().to_numpy(zero_copy_only=False) for column in table.columns], axis=0))
                    self.row_error(row + int(nulls[0]), "a value is missing (null); remove or repair the row")
                for batch in table.to_batches():
                    yield arrow_columns(batch)
            row += table.num_rows


def parquet_options() -> dict[str, object]:
    """How a recording's columns are written (the writer's and a streaming ParquetWriter's)."""
    return {"compression": "zstd", "use_dictionary": list(COLUMNS[1:]), "use_byte_stream_split": [COLUMNS[0]]}


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

    time_s, accel = recording_rows(time_s, accel_mps2)
    schema = pa.schema([pa.field(name, pa.float64(), nullable=False) for name in COLUMNS])
    table = pa.Table.from_arrays([pa.array(time_s), *(pa.array(np.ascontiguousarray(accel[:, i])) for i in range(3))], schema=schema)
    with Path(path).open("wb") as raw:
        pq.write_table(table, raw, row_group_size=PARQUET_GROUP_ROWS, **parquet_options())
        if fsync:
            raw.flush()
            os.fsync(raw.fileno())
