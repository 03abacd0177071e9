"""`bogiemon convert`: any file a replay reads (a recording of samples, a CAN log of any format)
written as a recording (CSV, .csv.gz, Parquet) or as a candump -L log, streaming: a block of
samples at a time, so that memory does not grow with the file.

The samples are those the replay source gives (drivers/replay.py: a CAN log decoded with the
DBC, a recording mapped and checked), with their times: a gap stays a gap (the times jump; in a
candump log the counter jumps with them, as the sensor's would). A candump log is encoded with the
DBC's layout (drivers/player.py: clipped to the converter's range, as the sensor would), so a
recording on the codec's grid comes back from it bit for bit.
"""

from __future__ import annotations

import gzip
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO, Protocol

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.drivers.recording_csv import GZIP_LEVEL, format_rows
from bogiemon.drivers.recording_format import COLUMNS, HEADER, PARQUET_SUFFIX, RecordingError

if TYPE_CHECKING:  # cantools loads with a candump output only
    from bogiemon.drivers.candb import CanLayout

OUTPUT_SUFFIXES = (".csv", ".csv.gz", PARQUET_SUFFIX, ".log")


class _Writer(Protocol):
    def write(self, block: Block) -> None: ...
    def close(self) -> None: ...


@dataclass(frozen=True)
class ConvertStats:
    samples: int
    segments: int
    fs_hz: float


def output_kind(path: str | Path) -> str:
    """'csv', 'parquet' or 'candump' by the output's name; RecordingError naming the choices."""
    name = str(path).lower()
    if name.endswith((".csv", ".csv.gz")):
        return "csv"
    if name.endswith(PARQUET_SUFFIX):
        return "parquet"
    if name.endswith(".log"):
        return "candump"
    raise RecordingError(f"{path}: convert writes a recording (.csv, .csv.gz, .parquet) or a candump -L log (.log): name the output so")


def convert(source: Source, out: str | Path, layout: CanLayout | None = None, progress: Callable[[float], None] | None = None,
            channel: str = "can0") -> ConvertStats:  # fmt: skip
    """Write every block of source to out (its kind by its name), then close the source; the
    output appears whole or not at all (written beside it, then renamed)."""
    kind = output_kind(out)
    out = Path(out)
    partial = out.with_name(f".{out.name}.partial")
    writer: _Writer
    if kind == "csv":
        writer = _CsvWriter(partial, out.name.lower().endswith(".gz"))
    elif kind == "parquet":
        writer = _ParquetWriter(partial)
    else:
        if layout is None:
            raise RecordingError(f"{out}: a candump log is encoded with a DBC layout")
        writer = _CandumpWriter(partial, layout, channel)
    samples = segments = 0
    fs_hz = 0.0
    try:
        try:
            while True:
                block = source.read(1.0)
                if block is None or not block.n_samples:
                    continue
                segments += block.gap_before or samples == 0
                samples += block.n_samples
                fs_hz = block.fs_hz
                writer.write(block)
                if progress is not None:
                    progress(getattr(source, "fraction_read", 0.0))
        except EndOfStream:
            pass
        writer.close()
        if samples == 0:
            raise RecordingError(f"{out}: nothing to write: no samples came from the input")
        os.replace(partial, out)
    finally:
        source.close()
        if partial.exists():
            partial.unlink()
    return ConvertStats(samples, segments, fs_hz)


def _times(block: Block) -> NDArray[np.float64]:
    return block.start_s + np.arange(block.n_samples) / block.fs_hz


class _CsvWriter:
    def __init__(self, path: Path, compressed: bool) -> None:
        self._raw = path.open("wb")
        self._f: BinaryIO | gzip.GzipFile = gzip.GzipFile(filename="", mode="wb", fileobj=self._raw, compresslevel=GZIP_LEVEL, mtime=0) if compressed else self._raw
        self._f.write((HEADER + "\n").encode("ascii"))

    def write(self, block: Block) -> None:
        self._f.write(format_rows(np.column_stack([_times(block), block.accel_mps2])))

    def close(self) -> None:
        if self._f is not self._raw:
            self._f.close()
        self._raw.close()


class _ParquetWriter:
    def __init__(self, path: Path) -> None:
        import pyarrow as pa
        import pyarrow.parquet as pq

        from bogiemon.drivers.recording_parquet import parquet_options

        self._schema = pa.schema([pa.field(name, pa.float64(), nullable=False) for name in COLUMNS])
        self._writer = pq.ParquetWriter(str(path), self._schema, **parquet_options())

    def write(self, block: Block) -> None:
        import pyarrow as pa

        columns = [pa.array(_times(block)), *(pa.array(np.ascontiguousarray(block.accel_mps2[:, i])) for i in range(3))]
        self._writer.write_table(pa.Table.from_arrays(columns, schema=self._schema))

    def close(self) -> None:
        self._writer.close()


class _CandumpWriter:
    """candump -L lines: '(1764500000.000000) can0 100#0011223344556677' (an extended identifier
    in 8 hex digits), the counter following the samples' times across a gap."""

    def __init__(self, path: Path, layout: CanLayout, channel: str) -> None:
        self._f = path.open("w", encoding="ascii")
        self._layout = layout
        self._channel = channel
        self._first_s: float | None = None

    def write(self, block: Block) -> None:
        from bogiemon.drivers.player import encode_instants

        if self._first_s is None:
            self._first_s = block.start_s
        first_counter = round((block.start_s - self._first_s) * block.fs_hz)
        instants = encode_instants(self._layout, block.accel_mps2, first_counter=first_counter)
        lines = []
        for time_s, frames in zip(_times(block).tolist(), instants, strict=True):
            for frame_id, extended, payload in frames:
                ident = f"{frame_id:08X}" if extended else f"{frame_id:03X}"
                lines.append(f"({time_s:.6f}) {self._channel} {ident}#{payload.hex().upper()}\n")
        self._f.write("".join(lines))

    def close(self) -> None:
        self._f.close()
