"""A wagon-day's partition of the windows dataset (docs/fleet-formats.md section 2), checked before use.

`fleet analyze` writes it; `fleet judge` and `fleet calibrate` read it; all three take it for what
it is only after checking it: its metadata against a schema (pydantic, strict: what `analyze`
writes and nothing else) and a digest, its columns against rows.SCHEMA, its values (no nulls,
finite times in order inside its day's range, segments that its metadata lists, status bits the
sensors have). `check_footer` reads only the file's footer (the metadata and the columns'
statistics: what `analyze` checks of every partition on every run); `read_partition` reads it
whole, its pages' checksums verified. A partition that fails is a PartitionError naming the file
and what is wrong: `analyze` does it again, `judge` names the day and goes on.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, NoReturn

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError

from bogiemon.judgement.windowing import SegmentStart, Status
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.base import MAX_TIME_S, SensorStatus
from bogiemon.fleet import rows
from bogiemon.fleet.layout import FleetError, Issue, day_start_s
from bogiemon.drivers.files import FileKind, UntrustedFile, read_untrusted
from bogiemon.fleet.paths import FIRST_DAY, inside, one_line, open_parquet, parquet_kind, place_of, shown

# 2: the channels' hop RMS range (the non-stationary gate) in every row; 3: the spectra's three
# noise-floor bands above 64 Hz (the sensor noise-floor check); 4: no conclusions in the rows (the
# judge draws them), each segment start says whether it is a gap; 5: the digests of the metadata
# and of the windows, the pages' checksums.
FORMAT = 5
PART_FILE = "part-0.parquet"
METADATA_KEY = b"bogiemon"
# The metadata's own digest beside it, and the windows' digest in it: Parquet checks its pages'
# bytes (written with checksums), not its footer, and a partition rewritten whole by another hand
# has checksums of its own: a changed digit of a segment start or of a window would read as
# another partition.
DIGEST_KEY = b"bogiemon.sha256"
# A day of windows every 10 s is 8 640 rows, about 10 MB; a partition 100 times that is no day's.
MAX_PARTITION_BYTES = 1 << 30
PARTITION_FILE = parquet_kind("partition", "a partition is the Parquet file `bogiemon fleet analyze` writes", MAX_PARTITION_BYTES)
MAX_ITEMS = 1_000_000  # inputs, skipped inputs, segment starts of one day
FIRST_S = day_start_s(FIRST_DAY.isoformat())
ALL_STATUS_BITS = int(SensorStatus.OVER_RANGE | SensorStatus.SENSOR_FAULT)


ANALYSE_AGAIN = "`bogiemon fleet analyze` analyses the day again"


class PartitionError(FleetError):
    """A partition that is not what `fleet analyze` writes (damaged, edited, of another format):
    '<path>: <problem>; <advice>'."""

    def __init__(self, path: str | Path, problem: str, advice: str = ANALYSE_AGAIN) -> None:
        super().__init__(f"{shown(path)}: {problem}; {advice}")
        self.path, self.problem, self.advice = str(path), problem, advice

    def __reduce__(self) -> tuple[Any, ...]:  # it may cross from a Dask worker
        return (PartitionError, (self.path, self.problem, self.advice))


Time = Annotated[float, Field(ge=FIRST_S, le=MAX_TIME_S, allow_inf_nan=False)]
Rate = Annotated[float, Field(gt=0, le=1e6, allow_inf_nan=False)]
Text = Annotated[str, StringConstraints(max_length=4096)]


class PartitionMeta(BaseModel):
    """The metadata `fleet analyze` writes (key `bogiemon`), exactly: a strict schema, no extras."""

    model_config = ConfigDict(frozen=True, extra="forbid", strict=True)

    format: int
    inputs: Annotated[list[tuple[Text, Annotated[int, Field(ge=0)], int]], Field(max_length=MAX_ITEMS)]
    processing: Annotated[str, StringConstraints(max_length=64)]
    skipped: Annotated[list[tuple[Text, Text]], Field(max_length=MAX_ITEMS)]
    covered: Annotated[int, Field(ge=0)]
    segment_starts: Annotated[list[tuple[Time, Rate, bool]], Field(max_length=MAX_ITEMS)]
    recorded_s: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    windows_sha256: Annotated[str, StringConstraints(pattern=r"^[0-9a-f]{64}$")]  # content_digest of its table

    @property
    def starts(self) -> list[SegmentStart]:
        return [SegmentStart(t, fs, gap) for t, fs, gap in self.segment_starts]

    @property
    def issues(self) -> tuple[Issue, ...]:
        return tuple(Issue(p, r) for p, r in self.skipped)

    def as_metadata(self) -> dict[bytes, bytes]:
        """The schema metadata of a partition holding this."""
        text = self.model_dump_json().encode()
        return {METADATA_KEY: text, DIGEST_KEY: _digest(text).encode()}


def _digest(text: bytes) -> str:
    return hashlib.sha256(text).hexdigest()


def content_digest(table: pa.Table) -> str:
    """SHA-256 of a windows table's values, column by column in the schema's order (numbers as
    their bytes, the recordings' names as JSON): the same whatever the table's chunks."""
    digest = hashlib.sha256()
    for name in rows.SCHEMA.names:
        column = table.column(name)
        if name == "recording":
            digest.update(json.dumps(column.to_pylist()).encode())
        else:
            digest.update(np.ascontiguousarray(column.to_numpy()).tobytes())
    return digest.hexdigest()


@dataclass(frozen=True)
class Footer:
    meta: PartitionMeta
    num_rows: int


@dataclass(frozen=True)
class Partition:
    """A checked partition: its metadata and its windows table (rows.SCHEMA)."""

    meta: PartitionMeta
    table: pa.Table

    def windows(self) -> list[WindowIndicators]:
        return rows.from_table(self.table)

    def status(self) -> list[Status]:
        return rows.status_of(self.table)


def partition_path(out_dir: str | Path, wagon_id: str, date: str) -> Path:
    return Path(out_dir) / f"wagon={wagon_id}" / f"date={date}" / PART_FILE


def partition_place(path: Path, out_root: Path) -> str | None:
    """What is at a partition's place when it is no partition file: "missing", "a folder", "a FIFO",
    "a symlink", ..., or that its folders lead out of the dataset (out_root, resolved); else None."""
    place = place_of(path)
    if place is None and not inside(out_root, path):
        return f"a path out of the windows dataset ({shown(out_root)}: '..' and symlinks resolved)"
    return place


def metadata_of(meta_bytes: dict[bytes, bytes], path: Path, midnight_s: float) -> PartitionMeta:
    """A partition's metadata, checked: its digest, its format, its schema, its segment starts in
    time order from the day's midnight on; PartitionError naming what is wrong."""
    text, digest = meta_bytes.get(METADATA_KEY), meta_bytes.get(DIGEST_KEY)
    if text is None:
        _refuse(path, "no bogiemon metadata (not a partition of `bogiemon fleet analyze`)")
    try:
        raw = json.loads(text)
    except (ValueError, RecursionError):
        _refuse(path, "its metadata is not JSON")
    if not isinstance(raw, dict):
        _refuse(path, "its metadata is not a JSON object")
    if raw.get("format") != FORMAT:
        written = shown(repr(raw.get("format")), 20)
        raise PartitionError(path, f"written in format {written}, this bogiemon reads {FORMAT}", "run `bogiemon fleet analyze` again")
    if digest is None or digest.decode("ascii", "replace") != _digest(text):
        _refuse(path, "its metadata does not match its digest (changed after it was written)")
    try:
        meta = PartitionMeta.model_validate_json(text)
    except ValidationError as exc:
        first = exc.errors()[0]
        _refuse(path, f"metadata {'.'.join(str(p) for p in first['loc']) or '(top level)'}: {first['msg']}")
    starts = [t for t, _, _ in meta.segment_starts]
    if starts and (starts[0] < midnight_s or any(b < a for a, b in zip(starts, starts[1:], strict=False))):
        _refuse(path, "metadata segment_starts: not in time order from the day's midnight")
    return meta


def _refuse(path: Path, problem: str) -> NoReturn:
    raise PartitionError(path, problem)


def check_footer(parquet: pq.ParquetFile, path: Path, midnight_s: float) -> Footer:
    """What the footer says, checked (the metadata, the columns, their statistics); PartitionError."""
    meta = metadata_of(dict(parquet.schema_arrow.metadata or {}), path, midnight_s)
    if not parquet.schema_arrow.remove_metadata().equals(rows.SCHEMA):
        _refuse(path, "its columns are not those of a windows partition")
    md = parquet.metadata
    bounds = {"segment": (0, len(meta.segment_starts) - 1), "start_s": (midnight_s, MAX_TIME_S), "end_s": (midnight_s, MAX_TIME_S)}
    bounds |= {name: (0, ALL_STATUS_BITS) for name in rows.STATUS_COLUMNS}
    for g in range(md.num_row_groups):
        group = md.row_group(g)
        if group.num_rows == 0:  # a day whose recordings all were skipped: no values, no statistics
            continue
        for c in range(group.num_columns):
            column = group.column(c)
            name = column.path_in_schema
            stats = column.statistics
            if stats is None or not stats.has_null_count:
                _refuse(path, f"column {name}: no statistics (not written by `bogiemon fleet analyze`)")
            if stats.null_count:
                _refuse(path, f"column {name}: {stats.null_count} null values")
            low, high = bounds.get(name, (None, None))
            if low is not None and stats.has_min_max and not (low <= stats.min and stats.max <= high):
                _refuse(path, f"column {name}: values outside {low:.15g} .. {high:.15g}")
    return Footer(meta, md.num_rows)


class _Unreadable(ValueError):
    """drivers/files.py's refusal of a partition, before it is a PartitionError."""


def _open(path: Path) -> tuple[UntrustedFile, pq.ParquetFile]:
    try:
        return open_parquet(path, PARTITION_FILE, _Unreadable)
    except _Unreadable as exc:
        _refuse(path, str(exc).removeprefix(f"{path}: ").removeprefix(f"{shown(path)}: "))


def read_footer(path: Path, midnight_s: float) -> Footer:
    """The checked footer of the partition at path (a regular file within its size bound)."""
    f, parquet = _open(path)
    with f:
        return check_footer(parquet, path, midnight_s)


def read_partition(path: Path, midnight_s: float) -> Partition:
    """The partition at path, read whole and checked; PartitionError naming the file and what is wrong."""
    f, parquet = _open(path)
    with f:
        footer = check_footer(parquet, path, midnight_s)
        try:
            table = parquet.read(use_threads=False)
        except (OSError, pa.ArrowException) as exc:
            _refuse(path, f"damaged ({one_line(exc, 160)})")
    problem = _table_problem(table, footer.meta)
    if problem is not None:
        _refuse(path, problem)
    if content_digest(table) != footer.meta.windows_sha256:
        _refuse(path, "its windows do not match their digest (changed after they were written)")
    return Partition(footer.meta, table.replace_schema_metadata(None))


def _table_problem(table: pa.Table, meta: PartitionMeta) -> str | None:
    """What is wrong with a table's values (the statistics may not say it all: they skip NaN)."""
    if any(column.null_count for column in table.columns):
        return "null values"
    start_s = table.column("start_s").to_numpy()
    end_s = table.column("end_s").to_numpy()
    segment = table.column("segment").to_numpy()
    if not (np.all(np.isfinite(start_s)) and np.all(np.isfinite(end_s)) and np.all(end_s > start_s)):
        return "a window whose times are not finite or end before they start"
    if np.any(np.diff(start_s) < 0) or np.any(np.diff(segment) < 0):
        return "windows out of time order"
    starts = np.array([t for t, _, _ in meta.segment_starts], dtype=np.float64)
    if len(segment) and (segment[0] < 0 or segment[-1] >= len(starts) or np.any(start_s < starts[segment])):
        return "a window outside the segments its metadata lists"
    for name in rows.STATUS_COLUMNS:
        bits = table.column(name).to_numpy()
        if np.any((bits < 0) | (bits > ALL_STATUS_BITS)):
            return f"column {name}: status bits no sensor reports"
    names = {name for name, _, _ in meta.inputs}
    recordings = set(pc.unique(table.column("recording")).to_pylist())
    if not recordings <= names:
        return "a window of a recording its metadata does not list"
    return None


# ---------------------------------------------------------------------------------------------
# The run's summary: the fleet it came from, and the partitions as the run left them


SUMMARY_FILE = "_analysis.json"
SUMMARY_KIND = FileKind(
    name="analysis summary", description=f"{SUMMARY_FILE} is the JSON summary `bogiemon fleet analyze` writes", max_bytes=1 << 28,
    too_large=f"{SUMMARY_FILE} is the summary of a run: is this the right file?",
)  # fmt: skip
# A file's identity as a run left it: size, modification and change times, inode. Any write to it
# changes the times (a change time cannot be set back), so a partition whose identity is not the
# ledger's is read whole before it is trusted again.
Identity = tuple[int, int, int, int]


class Summary(BaseModel):
    """What of _analysis.json the next steps use (the rest is for people); extras ignored."""

    model_config = ConfigDict(frozen=True, extra="ignore", strict=True)

    root: Annotated[str, StringConstraints(min_length=1, max_length=4096)]
    written: Annotated[dict[Annotated[str, StringConstraints(max_length=200)], tuple[int, int, int, int]], Field(max_length=10 * MAX_ITEMS)] = {}


def identity(path: Path) -> Identity | None:
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)


def read_summary(out_dir: Path, error: type[Exception]) -> Summary:
    """WINDOWS/_analysis.json, checked; error naming it when it is not what analyze writes."""
    path = out_dir / SUMMARY_FILE
    raw = read_untrusted(path, SUMMARY_KIND, error)
    try:
        return Summary.model_validate_json(raw)
    except ValidationError as exc:
        first = exc.errors()[0]
        raise error(f"{shown(path)}: {'.'.join(str(p) for p in first['loc']) or 'the file'}: {first['msg']} (not the summary `bogiemon fleet analyze` writes)") from None


def read_ledger(out_dir: Path) -> dict[str, Identity]:
    """The partitions as the last whole run left them; none when its summary is missing or damaged."""
    try:
        return dict(read_summary(out_dir, _Unreadable).written)
    except _Unreadable:
        return {}
