"""`bogiemon fleet analyze`: every wagon-day of a fleet through the detection core, on Dask.

One task per wagon-day: its recordings in name order (the recorder's names sort by time), each
opened as `bogiemon replay` opens it (daemon/sources.py), the blocks windowed by the monitor's own
rules (daemon/windowing.py: each recording a new stream) and the windows written as they are, with
the recording, the segment and the sensors' status bits of each, and the segments' starts
(docs/fleet-formats.md, section 2). What the daemon concludes of a window is `fleet judge`'s. A partition whose inputs and analysis
settings have not changed is not redone: a re-run after new days arrive does only the new work,
and an interrupted run resumes (each partition is written under a temporary name and renamed,
so it is either whole or absent, and never holds a row twice).

What a recording cannot give (it does not parse, its rate does not suit the config, it lies
outside its day, it overlaps the one before) is named in the partition and the run's summary,
and the rest goes on.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bogiemon.daemon.analysis import recording_settings
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.sources import open_replay_source
from bogiemon.daemon.windowing import BlockWindows, SegmentStart, Status
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.atomic import final_name_of, write_atomically
from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.fleet import rows
from bogiemon.fleet.layout import Day, Fleet, InputFile, Issue, Wagon, scan_fleet

# 2: the channels' hop RMS range (the non-stationary gate) in every row; 3: the spectra's three
# noise-floor bands above 64 Hz (the sensor noise-floor check); 4: no conclusions in the rows (the
# judge draws them), each segment start says whether it is a gap.
FORMAT = 4
PART_FILE = "part-0.parquet"
METADATA_KEY = b"bogiemon"
SUMMARY_FILE = "_analysis.json"
# CSV recordings are fed in the longest blocks a [source] allows: the windows do not depend on the
# block length (the core takes whole hops), the speed does a little.
CSV_BLOCK_S = 10.0
# Below this a recording's times are no Unix time (a simulator's or a logger's own origin): they are
# placed at the day's midnight UTC (docs/fleet-formats.md).
UNIX_TIME_MIN_S = 1e8
DAY_S = 86_400.0


@dataclass(frozen=True)
class DayTask:
    wagon_id: str
    date: str
    midnight_s: float
    files: tuple[InputFile, ...]
    config: BogiemonConfig
    digest: str
    path: Path  # the partition file


@dataclass(frozen=True)
class DayResult:
    wagon_id: str
    date: str
    windows: int
    recordings: int  # recordings that gave windows or samples
    samples: int
    recorded_s: float  # seconds of samples read
    skipped: tuple[Issue, ...]
    elapsed_s: float
    reused: bool = False


def analysis_digest(config: BogiemonConfig) -> str:
    """What the windows depend on: processing, the sensors' corners and geometry, the clip level."""
    parts = {
        "format": FORMAT,
        "processing": config.processing.model_dump(mode="json"),
        "geometry": config.geometry.model_dump(mode="json"),
        "sensors": config.sensors.model_dump(mode="json"),
        "clip_level_mps2": config.health.clip_level_mps2,
    }
    return hashlib.sha256(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:16]


def partition_path(out_dir: str | Path, wagon_id: str, date: str) -> Path:
    return Path(out_dir) / f"wagon={wagon_id}" / f"date={date}" / PART_FILE


def partition_metadata(path: Path) -> dict[str, Any] | None:
    """The bogiemon metadata of a written partition; None when it is absent or unreadable."""
    try:
        meta = pq.read_schema(path).metadata or {}
        return json.loads(meta[METADATA_KEY])
    except (OSError, KeyError, ValueError, pa.ArrowException):
        return None


def _inputs(files: Sequence[InputFile]) -> list[list[Any]]:
    return [list(f.key) for f in files]


def is_done(task: DayTask) -> bool:
    meta = partition_metadata(task.path)
    return meta is not None and meta.get("format") == FORMAT and meta.get("processing") == task.digest and meta.get("inputs") == _inputs(task.files)


def day_tasks(fleet: Fleet, out_dir: str | Path) -> list[DayTask]:
    out = []
    for wagon in fleet.wagons:
        digest = analysis_digest(wagon.config)
        for day in wagon.days:
            out.append(DayTask(wagon.wagon_id, day.date, day.midnight_s, day.files, wagon.config, digest, partition_path(out_dir, wagon.wagon_id, day.date)))
    return out


# --------------------------------------------------------------------------------------------
# One wagon-day (runs on a Dask worker)


def _blocks(source: Source) -> list[Block]:
    out = []
    while True:
        try:
            block = source.read(1.0)
        except EndOfStream:
            return out
        if block is not None and block.n_samples:
            out.append(block)


class _DayWindows:
    """The monitor's windowing over one day's blocks (daemon/windowing.py): each window with the
    recording and segment it lies in and the sensors' status bits over it; the segments' starts."""

    def __init__(self, config: BogiemonConfig) -> None:
        self.recording = ""
        # The day's own gaps: the judge counts them across days again, from the segment starts.
        self.blocks = BlockWindows(lambda fs_hz: recording_settings(self.recording, fs_hz, config), config.bogie_geometry(),
                                   config.health.clip_level_mps2, keep_starts=True)  # fmt: skip
        self.windows: list[WindowIndicators] = []
        self.recordings: list[str] = []
        self.segments: list[int] = []
        self.status: list[Status] = []

    def new_recording(self, recording: str) -> None:
        """The next blocks are another recording's: a new stream, never a gap."""
        self.recording = recording  # named in the error of a rate the config cannot run at
        self.blocks.new_stream()

    def feed(self, block: Block) -> None:
        for w in self.blocks.feed(block):
            self.windows.append(w.window)
            self.recordings.append(self.recording)
            self.segments.append(w.segment)
            self.status.append(w.status)


def _read(file: InputFile, task: DayTask) -> list[Block]:
    """A recording's blocks on Unix time; raises for what cannot be used (the caller names it)."""
    # Opened as `replay` and `run` open a recording (the config's [source] layout and DBC for a
    # CAN log), in larger blocks for a CSV (fewer calls; the windows do not depend on them).
    source = open_replay_source(file.path, task.config, max_block_s=CSV_BLOCK_S if file.is_samples else None)
    try:
        blocks = _blocks(source)
    finally:
        source.close()
    if not blocks:
        raise ValueError("no samples could be decoded")
    if blocks[0].start_s < UNIX_TIME_MIN_S:
        blocks = [dataclasses.replace(b, start_s=b.start_s + task.midnight_s) for b in blocks]
    first_s = blocks[0].start_s
    if not task.midnight_s <= first_s < task.midnight_s + DAY_S:
        raise _OutOfDay(f"day out of order: its first sample is at {_utc(first_s)}, not on {task.date}")
    return blocks


class _OutOfDay(ValueError):
    pass


def _after(blocks: list[Block], time_s: float) -> list[Block]:
    """The samples of blocks at or after time_s (half a sample's tolerance), the first one after a gap."""
    out = []
    for block in blocks:
        keep = int(np.searchsorted(block.start_s + np.arange(block.n_samples) / block.fs_hz, time_s - 0.5 / block.fs_hz))
        if keep < block.n_samples:
            part = block.accel_mps2[keep:]
            out.append(dataclasses.replace(block, start_s=block.start_s + keep / block.fs_hz, accel_mps2=part, gap_before=block.gap_before or not out))
    return out


def analyze_day(task: DayTask) -> DayResult:
    """Analyse one wagon-day and write its partition (atomically); returns what it did.

    The day's recordings are taken in time order (first sample, the longer first). The recorder's
    snapshots overlap by design (a CONFIRMED one holds most of the SUSPECTED one before it): a
    recording's samples that an earlier one already gave are left out, one wholly covered is
    counted as covered, and the rest of it is analysed as a new segment.
    """
    started = time.perf_counter()
    day = _DayWindows(task.config)
    skipped: list[Issue] = []
    read: list[tuple[float, float, str, InputFile, list[Block]]] = []
    for file in task.files:
        try:
            blocks = _read(file, task)
        except _OutOfDay as exc:
            skipped.append(Issue(str(file.path), str(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - one file of thousands: named, skipped, counted; the rest goes on
            skipped.append(Issue(str(file.path), _unparsable(exc, str(file.path))))
            continue
        read.append((blocks[0].start_s, -blocks[-1].end_s, file.path.name, file, blocks))
    read.sort(key=lambda r: r[:3])
    used = samples = covered = 0
    recorded_s = 0.0
    last_end_s = -math.inf
    for _, _, name, file, blocks in read:
        if blocks[0].start_s < last_end_s:
            blocks = _after(blocks, last_end_s)
            if not blocks:
                covered += 1
                continue
        try:
            day.new_recording(name)
            for block in blocks:
                day.feed(block)
        except Exception as exc:  # noqa: BLE001 - e.g. a rate the config cannot run at
            skipped.append(Issue(str(file.path), _unparsable(exc, str(file.path))))
            continue
        last_end_s = blocks[-1].end_s
        used += 1
        samples += sum(b.n_samples for b in blocks)
        recorded_s += sum(b.n_samples / b.fs_hz for b in blocks)
    table = rows.to_table(day.windows, day.recordings, day.segments, day.status)
    meta = {
        "format": FORMAT,
        "inputs": _inputs(task.files),
        "processing": task.digest,
        "skipped": [[i.path, i.reason] for i in skipped],
        "covered": covered,
        "segment_starts": [[st.start_s, st.fs_hz, st.gap] for st in day.blocks.segment_starts],
        "recorded_s": recorded_s,
    }
    table = table.replace_schema_metadata({METADATA_KEY: json.dumps(meta).encode()})
    _write_atomically(table, task.path)
    return DayResult(task.wagon_id, task.date, len(day.windows), used, samples, recorded_s, tuple(skipped), time.perf_counter() - started)


def _unparsable(exc: BaseException, name: str) -> str:
    reason = str(exc).replace(name, "").strip(": ") or type(exc).__name__
    kind = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
    return f"does not parse: {kind}{' '.join(reason.split())[:300]}"


def _write_atomically(table: pa.Table, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, lambda temporary: pq.write_table(table, temporary, compression="zstd"))


def _utc(time_s: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%SZ", time.gmtime(time_s))


def _reused(task: DayTask) -> DayResult:
    meta = partition_metadata(task.path) or {}
    n = pq.read_metadata(task.path).num_rows
    skipped = tuple(Issue(p, r) for p, r in meta.get("skipped", []))
    return DayResult(task.wagon_id, task.date, n, len(task.files) - len(skipped), 0, float(meta.get("recorded_s", 0.0)), skipped, 0.0, reused=True)


# --------------------------------------------------------------------------------------------
# The fleet, on Dask


@dataclass(frozen=True)
class AnalyzeSummary:
    root: str
    out_dir: str
    wagons: int
    partitions: int
    analysed: int  # partitions (re)done this run
    reused: int
    windows: int
    recorded_s: float  # seconds of recording analysed this run
    elapsed_s: float
    workers: int
    issues: tuple[Issue, ...]  # of the tree and of the recordings
    results: tuple[DayResult, ...]

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("issues", "results")}
        out["issues"] = [i.as_dict() for i in self.issues]
        out["busy_s"] = sum(r.elapsed_s for r in self.results)
        return out


def local_client(n_workers: int | None = None) -> Any:
    """A Dask LocalCluster of one single-threaded process per core (the analysis is numpy's: one
    thread per process keeps the cores busy without BLAS threads fighting over them)."""
    from distributed import Client, LocalCluster

    # The scheduler of a LocalCluster runs in this process: its INFO lines (start, close) are
    # noise on a command line; warnings and errors still show.
    logging.getLogger("distributed").setLevel(logging.WARNING)
    workers = n_workers or os.cpu_count() or 1
    cluster = LocalCluster(
        n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None, silence_logs=40,
        env={"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"},
    )  # fmt: skip
    return Client(cluster)


def analyze_fleet(
    root: str | Path,
    out_dir: str | Path,
    client: Any = None,
    scheduler: str | None = None,
    n_workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    redo: bool = False,
) -> AnalyzeSummary:
    """Analyse every wagon-day not yet done; see the module docstring.

    client: a distributed.Client to use; else one to `scheduler` (tcp://HOST:PORT), else a
    LocalCluster of n_workers (default: one per core) for this run. progress(done, total) is
    called as partitions finish.
    """
    from distributed import Client, as_completed

    started = time.perf_counter()
    fleet = scan_fleet(root)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for stale in out.glob("wagon=*/date=*/.*"):  # a run killed while writing
        if final_name_of(stale.name) == PART_FILE:
            stale.unlink(missing_ok=True)
    tasks = day_tasks(fleet, out)
    todo = [t for t in tasks if redo or not is_done(t)]
    results = [_reused(t) for t in tasks if t not in todo]
    own = None
    if todo:
        if client is None:
            own = Client(scheduler) if scheduler else local_client(n_workers)
            client = own
        futures: list[Any] = []
        try:
            workers = len(client.scheduler_info().get("workers", {}))
            futures = client.map(analyze_day, todo, pure=False)
            done = 0
            for future in as_completed(futures):
                results.append(future.result())
                done += 1
                if progress is not None:
                    progress(done, len(todo))
        except BaseException:
            # Interrupted or failed: no wagon-day not yet started starts after this (on a shared
            # scheduler it would run on unasked). One already running ends and writes its partition
            # whole (atomically), which the next run reuses.
            client.cancel(futures)
            raise
        finally:
            if own is not None:
                cluster = own.cluster
                own.close()
                if cluster is not None:
                    cluster.close()
    else:
        workers = 0
    results.sort(key=lambda r: (r.wagon_id, r.date))
    issues = (*fleet.issues, *(i for r in results for i in r.skipped))
    summary = AnalyzeSummary(
        root=str(Path(root).resolve()), out_dir=str(out), wagons=len(fleet.wagons), partitions=len(tasks), analysed=len(todo),
        reused=len(tasks) - len(todo), windows=sum(r.windows for r in results),
        recorded_s=sum(r.recorded_s for r in results if not r.reused), elapsed_s=time.perf_counter() - started,
        workers=workers, issues=tuple(issues), results=tuple(results),
    )  # fmt: skip
    (out / SUMMARY_FILE).write_text(json.dumps(summary.as_dict(), indent=1) + "\n", encoding="utf-8")
    return summary


def wagon_partitions(out_dir: str | Path, wagon: Wagon) -> list[tuple[Day, Path]]:
    """The written partitions of a wagon's days, in date order (days not analysed left out)."""
    return [(d, p) for d in wagon.days if (p := partition_path(out_dir, wagon.wagon_id, d.date)).is_file()]


def segment_starts_of(meta: dict[str, Any]) -> list[SegmentStart]:
    """The segment starts a partition's metadata lists, in time order; ValueError if malformed."""
    try:
        starts = [SegmentStart(float(t), float(fs), bool(gap)) for t, fs, gap in meta.get("segment_starts", [])]
    except (TypeError, ValueError) as exc:
        raise ValueError(f"segment_starts: expected [start_s, fs_hz, gap] triples ({exc})") from None
    return sorted(starts, key=lambda s: s.start_s)


def read_partition(path: Path) -> tuple[pa.Table, dict[str, Any]]:
    """A partition's windows and metadata; ValueError for one of another format (its columns differ)."""
    table = pq.read_table(path)
    meta = json.loads((table.schema.metadata or {})[METADATA_KEY])
    if meta.get("format") != FORMAT:
        raise ValueError(f"written in format {meta.get('format')!r}, this bogiemon reads {FORMAT}: run `bogiemon fleet analyze` again")
    return table, meta
