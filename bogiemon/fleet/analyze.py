"""`bogiemon fleet analyze`: every wagon-day of a fleet through the detection core, on Dask.

One task per wagon-day: its recordings in name order (the recorder's names sort by time), each
opened as `bogiemon replay` opens it (daemon/sources.py), the blocks windowed by the monitor's own
rules (judgement/windowing.py: each recording a new stream) and the windows written as they are, with
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

import contextlib
import dataclasses
import hashlib
import json
import math
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.daemon.analysis import recording_settings
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.sources import open_replay_source
from bogiemon.judgement.windowing import BlockWindows, Status
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.atomic import final_name_of, write_atomically, write_text_atomically
from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.drivers.recording_format import RecordingError, one_bogie
from bogiemon.fleet import rows
from bogiemon.fleet.cluster import DaskRunner, Runner, check_options, dask_runner, local_client
from bogiemon.fleet.layout import Fleet, FleetError, InputFile, Issue, scan_fleet
from bogiemon.fleet.objects import fetch_recording
from bogiemon.fleet.paths import inside, make_room, output_folder, shown, write_parquet
from bogiemon.fleet.windows_files import (
    FORMAT, PART_FILE, SUMMARY_FILE, Footer, PartitionError, PartitionMeta, content_digest, identity, partition_path, partition_place, read_footer,
    read_ledger, read_partition,
)  # fmt: skip

# Kept importable from here: the bench and the tests use them as they did before the split.
__all__ = ["FORMAT", "PART_FILE", "AnalyzeSummary", "DayResult", "DayTask", "analysis_digest", "analyze_day", "analyze_fleet", "day_tasks",
           "local_client", "partition_path"]  # fmt: skip
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
    # Its footer is in order but the file is not as the last run left it: read it whole first,
    # keep it if it is sound, else analyse the day again.
    verify: bool = False


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
    repaired: Issue | None = None  # the partition found damaged and analysed again


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


def _inputs(files: Sequence[InputFile]) -> list[tuple[str, int, int]]:
    return [f.key for f in files]


def is_current(task: DayTask, meta: PartitionMeta) -> bool:
    """Whether a sound partition's windows are those of the day's inputs and settings now."""
    return meta.processing == task.digest and [tuple(i) for i in meta.inputs] == _inputs(task.files)


def is_done(task: DayTask) -> bool:
    """Whether the task's partition is sound and current (read whole: what a test asks)."""
    try:
        return is_current(task, read_partition(task.path, task.midnight_s).meta)
    except PartitionError:
        return False


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
    out: list[Block] = []
    while True:
        try:
            block = source.read(1.0)
        except EndOfStream:
            return out
        if block is not None and block.n_samples:
            out.append(block)


class _DayWindows:
    """The monitor's windowing over one day's blocks (judgement/windowing.py): each window with the
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


class _Unreadable(ValueError):
    """An object-store recording that could not be fetched or read: why, without its URL or its
    local copy's name (the issue names its URL)."""


def _read(file: InputFile, task: DayTask) -> list[Block]:
    """A recording's blocks on Unix time; raises for what cannot be used (the caller names it).
    One in an object store is fetched to a local copy for as long as it is read (fleet/objects.py)."""
    if not file.url:
        return _read_local(file.path, file, task)
    with contextlib.ExitStack() as copies:
        try:
            local = copies.enter_context(fetch_recording(file.url, file.size_bytes))
        except RecordingError as exc:  # too large, gone since the listing, or unreadable
            raise _Unreadable(str(exc).removeprefix(f"{file.url}: ")) from None
        try:
            return _read_local(local, file, task)
        except _OutOfDay:
            raise
        except Exception as exc:  # noqa: BLE001 - named by the caller, as a local file's is
            raise _Unreadable(_unparsable(exc, str(local))) from None


def _read_local(path: Path, file: InputFile, task: DayTask) -> list[Block]:
    # Opened as `replay` and `run` open a recording (the config's [source] layout and DBC for a
    # CAN log), in larger blocks for a CSV (fewer calls; the windows do not depend on them).
    source = open_replay_source(path, task.config, max_block_s=CSV_BLOCK_S if file.is_samples else None)
    one_bogie(source, path, "fleet analyze")  # its windows are one bogie's today
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
    out: list[Block] = []
    for block in blocks:
        keep = int(np.searchsorted(block.start_s + np.arange(block.n_samples) / block.fs_hz, time_s - 0.5 / block.fs_hz))
        if keep < block.n_samples:
            part = block.accel_mps2[keep:]
            out.append(dataclasses.replace(block, start_s=block.start_s + keep / block.fs_hz, accel_mps2=part, gap_before=block.gap_before or not out))
    return out


def analyze_day(task: DayTask) -> DayResult:
    """Analyse one wagon-day and write its partition (atomically); returns what it did.

    With task.verify, the partition there is read whole first and kept if it is sound. The day's
    recordings are taken in time order (first sample, the longer first). The recorder's snapshots
    overlap by design (a CONFIRMED one holds most of the SUSPECTED one before it): a recording's
    samples that an earlier one already gave are left out, one wholly covered is counted as
    covered, and the rest of it is analysed as a new segment.
    """
    started = time.perf_counter()
    repaired = None
    if task.verify:
        try:
            partition = read_partition(task.path, task.midnight_s)
        except PartitionError as exc:
            repaired = Issue(str(task.path), _damaged(exc))
        else:
            return _reused(task, partition.meta, partition.table.num_rows)
    day = _DayWindows(task.config)
    skipped: list[Issue] = []
    read: list[tuple[float, float, str, InputFile, list[Block]]] = []
    for file in task.files:
        try:
            blocks = _read(file, task)
        except _OutOfDay as exc:
            skipped.append(Issue(file.shown, str(exc)))
            continue
        except _Unreadable as exc:
            skipped.append(Issue(file.shown, str(exc)))
            continue
        except Exception as exc:  # noqa: BLE001 - one file of thousands: named, skipped, counted; the rest goes on
            skipped.append(Issue(file.shown, _unparsable(exc, str(file.path))))
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
            skipped.append(Issue(file.shown, _unparsable(exc, str(file.path))))
            continue
        last_end_s = blocks[-1].end_s
        used += 1
        samples += sum(b.n_samples for b in blocks)
        recorded_s += sum(b.n_samples / b.fs_hz for b in blocks)
    table = rows.to_table(day.windows, day.recordings, day.segments, day.status)
    meta = PartitionMeta(
        format=FORMAT, inputs=_inputs(task.files), processing=task.digest, skipped=[(i.path, i.reason) for i in skipped],
        covered=covered, segment_starts=[(st.start_s, st.fs_hz, st.gap) for st in day.blocks.segment_starts], recorded_s=recorded_s,
        windows_sha256=content_digest(table),
    )  # fmt: skip
    try:
        task.path.parent.mkdir(parents=True, exist_ok=True)  # the run made room for it (make_room); a caller of this alone did not
        write_atomically(task.path, lambda temporary: write_parquet(table.replace_schema_metadata(meta.as_metadata()), temporary))
    except OSError as exc:
        raise FleetError(f"{shown(task.path)}: the partition cannot be written ({exc.strerror or exc})") from None
    return DayResult(task.wagon_id, task.date, len(day.windows), used, samples, recorded_s, tuple(skipped), time.perf_counter() - started,
                     repaired=repaired)  # fmt: skip


def _unparsable(exc: BaseException, name: str) -> str:
    reason = str(exc).replace(name, "").strip(": ") or type(exc).__name__
    kind = "" if isinstance(exc, ValueError) else f"{type(exc).__name__}: "
    return f"does not parse: {kind}{' '.join(reason.split())[:300]}"


def _damaged(exc: PartitionError) -> str:
    """Why a partition was analysed again (the path is the issue's)."""
    return f"{exc.problem}: analysed again"


def _utc(time_s: float) -> str:
    return time.strftime("%Y-%m-%d %H:%M:%SZ", time.gmtime(time_s))


def _reused(task: DayTask, meta: PartitionMeta, num_rows: int) -> DayResult:
    return DayResult(task.wagon_id, task.date, num_rows, len(task.files) - len(meta.skipped), 0, meta.recorded_s, meta.issues, 0.0, reused=True)


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
    repaired: tuple[Issue, ...] = ()  # partitions found damaged (or something else in their place), analysed again

    def as_dict(self) -> dict[str, Any]:
        out = {k: v for k, v in dataclasses.asdict(self).items() if k not in ("issues", "results", "repaired")}
        out["issues"] = [i.as_dict() for i in self.issues]
        out["repaired"] = [i.as_dict() for i in self.repaired]
        out["busy_s"] = sum(r.elapsed_s for r in self.results)
        return out


def analyze_fleet(
    root: str | Path,
    out_dir: str | Path,
    client: Any = None,
    scheduler: str | None = None,
    n_workers: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    redo: bool = False,
    runner: Runner | None = None,
) -> AnalyzeSummary:
    """Analyse every wagon-day not yet done; see the module docstring.

    The tasks run on `runner` if given (fleet/cluster.py: InProcess runs them here), else on
    `client` (a distributed.Client), else on a client to `scheduler` (tcp://HOST:PORT), else on a
    LocalCluster of n_workers (default: one per core) for this run. progress(done, total) is
    called as partitions finish. Every partition is checked before it is reused: one whose footer
    is not what analyze writes, or that is not as the last run left it and does not read whole
    and sound, is analysed again and named (AnalyzeSummary.repaired).
    """
    started = time.perf_counter()
    check_options(scheduler, n_workers)
    fleet = scan_fleet(root)
    out = output_folder(out_dir, FleetError, "WINDOWS", fleet.local_inputs).resolve()  # what lies inside it is checked against it
    ledger = read_ledger(out)
    _remove_temporaries(out)
    tasks = day_tasks(fleet, out)
    todo: list[DayTask] = []
    results: list[DayResult] = []
    repaired: list[Issue] = []
    for task in tasks:
        footer, problem = _footer(task, out) if not redo else (None, None)
        if problem is not None:
            repaired.append(Issue(str(task.path), problem))
        if footer is not None and is_current(task, footer.meta):
            if ledger.get(_ledger_key(task, out)) == identity(task.path):
                results.append(_reused(task, footer.meta, footer.num_rows))
                continue
            task = dataclasses.replace(task, verify=True)
        moved = make_room(task.path, out)
        if moved is not None and problem is None:
            repaired.append(Issue(str(task.path), f"{moved}: removed, the day analysed again"))
        todo.append(task)
    workers = 0
    if todo:
        with _runner(runner, client, scheduler, n_workers) as run, contextlib.closing(run.map(analyze_day, todo)) as done:
            workers = run.workers
            for n, result in enumerate(done, start=1):
                results.append(result)
                if result.repaired is not None:
                    repaired.append(result.repaired)
                if progress is not None:
                    progress(n, len(todo))
    results.sort(key=lambda r: (r.wagon_id, r.date))
    issues = (*fleet.issues, *(i for r in results for i in r.skipped))
    analysed = sum(1 for r in results if not r.reused)
    summary = AnalyzeSummary(
        root=fleet.location, out_dir=str(out), wagons=len(fleet.wagons), partitions=len(tasks), analysed=analysed,
        reused=len(tasks) - analysed, windows=sum(r.windows for r in results),
        recorded_s=sum(r.recorded_s for r in results if not r.reused), elapsed_s=time.perf_counter() - started,
        workers=workers, issues=tuple(issues), results=tuple(results), repaired=tuple(repaired),
    )  # fmt: skip
    written = {_ledger_key(t, out): i for t in tasks if (i := identity(t.path)) is not None}
    document = summary.as_dict() | {"written": written}
    try:
        make_room(out / SUMMARY_FILE, out)  # a folder there (WINDOWS is analyze's own) would refuse the rename for good
        write_text_atomically(out / SUMMARY_FILE, json.dumps(document, indent=1) + "\n")
    except OSError as exc:
        raise FleetError(f"{shown(out / SUMMARY_FILE)}: cannot be written ({exc.strerror or exc})") from None
    return summary


def _footer(task: DayTask, out: Path) -> tuple[Footer | None, str | None]:
    """The partition's checked footer, or why there is none worth keeping (None: nothing there yet)."""
    place = partition_place(task.path, out)
    if place == "missing":
        return None, None
    if place is not None:
        return None, f"{place} in the place of the partition: removed, the day analysed again"
    try:
        return read_footer(task.path, task.midnight_s), None
    except PartitionError as exc:
        return None, _damaged(exc)


def _ledger_key(task: DayTask, out: Path) -> str:
    return task.path.relative_to(out).parent.as_posix()


def _remove_temporaries(out: Path) -> None:
    """What a run killed while writing left: hidden temporaries of partitions."""
    for stale in out.glob("wagon=*/date=*/.*"):
        # glob follows a symlinked wagon= or date= folder: what lies outside WINDOWS is not ours to remove
        if final_name_of(stale.name) == PART_FILE and inside(out, stale.parent):
            if stale.is_dir() and not stale.is_symlink():
                shutil.rmtree(stale, ignore_errors=True)
            else:
                stale.unlink(missing_ok=True)


@contextlib.contextmanager
def _runner(runner: Runner | None, client: Any, scheduler: str | None, n_workers: int | None) -> Iterator[Runner]:
    if runner is not None:
        yield runner
    elif client is not None:
        yield DaskRunner(client)
    else:
        with dask_runner(scheduler, n_workers) as dask:
            yield dask
