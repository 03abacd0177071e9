"""The fuzz suite: every decoder and parser of bogiemon fed generated and mutated inputs, seeded.

Each target has a generator of valid inputs and of mutations of them (bit flips, truncations,
splices, huge, NaN and infinite numbers, wrong types, boundary integers, garbage lines, random
bytes) and runs a fixed number of inputs (100 000 where one takes under a millisecond, 10 000
for a file, a few thousand for a compressed recording, a few hundred where one input is a daemon
on a disk or under reloads), each under a limit of CPU time (WALL_FACTOR times it of wall time for
an input that waits), in worker processes the harness kills when an input hangs in C. Per target
it prints the inputs, the clear errors (the documented exception for bad input: CLEAR_ERRORS
below), the crashes (any other exception), the hangs (over the limit), the silently
wrong results (checked against a plain reference where one exists: cantools per frame, a
byte-by-byte packet parser, Python's csv module, the events committed to a store) and the wall
time, and exits 1 on any crash or hang. Input i of a target is drawn from a random.Random seeded
with (seed, target, i) alone, so a run is reproducible whatever the number of workers. Every
distinct crash (exception type and code site), hang and kind of wrong result is saved with the
smallest input that shows it under bench/fuzz_crashes/<target>/ (bench/fuzz_crashes/README.md).

    make fuzz                                         # every target at full count (see README)
    .venv/bin/python bench/fuzz.py --quick            # a few thousand inputs per target (tests/test_fuzz_quick.py)
    .venv/bin/python bench/fuzz.py --quick --share 0.34   # its first third (make test; the rest in make test-slow)
    .venv/bin/python bench/fuzz.py --target csv,config --inputs 2000 --seed 3 --jobs 1
    .venv/bin/python bench/fuzz.py --replay bench/fuzz_crashes/csv/crash-....json   # its traceback, here
    .venv/bin/python bench/fuzz.py --target csv --index 1234 [--show]   # one generated input, here
"""

from __future__ import annotations

import argparse
import gc
import importlib
import json
import math
import multiprocessing
import multiprocessing.connection
import os
import re
import resource
import signal
import sys
import time
import traceback
import warnings
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any

# Workers fork from this process: no BLAS thread pools to fork, whatever a target imports.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

import fuzz_core  # noqa: E402  (stdlib only: the parent stays light, the targets load in the workers)
from fuzz_progress import SLOT_SIZE, WALL_FACTOR, ProgressSlot, cpu_time_s, install_alarms, stuck  # noqa: E402

REPO = BENCH.parent
sys.path.insert(1, str(REPO))  # the daemon's targets build their signals with tests/daemon/synthetic.py
DEFAULT_CRASH_DIR = BENCH / "fuzz_crashes"
DEFAULT_SEED = 17
# A worker's address space: what it holds after importing the targets, plus this much. An input
# that asks for more (an include of /dev/zero) gets MemoryError instead of the machine's memory.
MEMORY_HEADROOM_BYTES = 2 << 30
REPORT_EVERY_S = 0.5  # a worker reports its counts this often, so a killed worker loses little


@dataclass(frozen=True)
class Spec:
    """A target: its module, how many inputs (full run, --quick), the time limit of one input, the batch size."""

    name: str
    module: str
    inputs: int
    quick: int
    limit_s: float
    batch: int
    what: str


SPECS: tuple[Spec, ...] = (
    Spec("can-hub", "fuzz_can", 100_000, 3000, 2.0, 400, "CanFrameDecoder, hub layout; counts and samples against cantools per frame"),
    Spec("can-per-node", "fuzz_can", 100_000, 3000, 2.0, 400, "CanFrameDecoder, per-node layout; counts and samples against cantools per frame"),
    Spec("serial-parser", "fuzz_serial", 100_000, 3000, 2.0, 500, "PacketParser against a byte-by-byte reference parser"),
    Spec("serial-source", "fuzz_serial", 100_000, 3000, 2.0, 400, "SerialSource over a scripted port that fails and comes back"),
    Spec("csv", "fuzz_csv", 100_000, 3000, 5.0, 400, "read_csv_recording on files against the csv module; the analysis's start"),
    Spec("canlog-log", "fuzz_can", 10_000, 1000, 5.0, 100, "open_replay on candump -L .log files, every frame accounted for"),
    Spec("canlog-asc", "fuzz_can", 10_000, 1000, 5.0, 100, "open_replay on Vector .asc files"),
    Spec("canlog-blf", "fuzz_can", 10_000, 1000, 5.0, 100, "open_replay on Vector .blf files"),
    Spec("canlog-trc", "fuzz_can", 10_000, 1000, 5.0, 100, "open_replay on PEAK .trc files"),
    Spec("canlog-pycsv", "fuzz_can", 10_000, 1000, 5.0, 100, "open_replay on python-can's .csv logs"),
    Spec("canlog-sqlite", "fuzz_sqlite", 10_000, 300, 5.0, 50, "open_replay on python-can's SQLite logs: damaged pages, schemas, views, values"),
    Spec("mf4", "fuzz_mf4", 2000, 100, 30.0, 5, "open_replay on MF4 bus logs and signals: cut, flipped, blocks' sizes, links and record counts"),
    Spec("recording-mapped", "fuzz_mapped", 10_000, 300, 5.0, 50, "replay --columns on other writers' CSV: delimiters, odd columns, time and acceleration units"),
    Spec("config", "fuzz_config", 10_000, 1000, 3.0, 50, "load_config with includes; what it accepts, run must start"),
    Spec("mqtt-schema", "fuzz_mqtt", 100_000, 3000, 2.0, 1000, "EventMessage / StatusMessage on received JSON, and back"),
    Spec("mqtt-listen", "fuzz_mqtt", 100_000, 3000, 5.0, 400, "the listener's per-message handling, --store and the printing"),
    Spec("outbox", "fuzz_mqtt", 10_000, 1000, 5.0, 50, "the publisher reading pending events and status back from a store"),
    Spec("store", "fuzz_store", 10_000, 1000, 5.0, 50, "EventStore on damaged files: events, the first commit"),
    Spec("recording-gz", "fuzz_recordings", 2000, 200, 60.0, 10, "replay's and analyze's reading of .csv.gz: damaged streams, bombs; against gzip and csv"),
    Spec("recording-parquet", "fuzz_recordings", 2000, 200, 60.0, 10, "replay's and analyze's reading of .parquet: lying footers and pages, schemas, nulls; against pyarrow"),
    Spec("recorder-disk", "fuzz_recorder", 300, 20, 60.0, 5, "the recorder beside the event store on a small tmpfs filled to random levels"),
    Spec("reload", "fuzz_reload", 150, 12, 90.0, 3, "the service over a broken spring under random SIGHUP reloads, good, changed and broken"),
    Spec("fleet", "fuzz_fleet", 1000, 8, 30.0, 4, "fleet analyze/judge/report on damaged trees, partitions and JUDGED"),
    Spec("signals", "fuzz_signals", 120, 4, 30.0, 2, "a real `bogiemon run` under floods of SIGHUP while it starts, runs and stops"),
)  # fmt: skip
BY_NAME = {s.name: s for s in SPECS}

# What counts as a clear error for bad input, per target: the documented exception classes, as
# dotted names (a name not defined yet is reported and ignored). Any other exception is a crash.
RECORDING_ERROR = "bogiemon.drivers.recording_format.RecordingError"
DBC_ERROR = "bogiemon.drivers.candb.DbcError"
CONFIG_ERROR = "bogiemon.daemon.config.ConfigError"
STORE_ERROR = "bogiemon.daemon.store.StoreError"
VALIDATION_ERROR = "pydantic.ValidationError"
SCHEMA_ERROR = "bogiemon.daemon.messages.SchemaError"  # the schema's own error, if it gets one
CLEAR_ERRORS: dict[str, tuple[str, ...]] = {
    "can-hub": (),  # a decoder never raises for what is on the bus: it counts bad frames
    "can-per-node": (),
    "serial-parser": (),  # the parser counts CRC errors and garbage
    "serial-source": (),  # a live source counts, reconnects and reports a gap
    "csv": (RECORDING_ERROR, CONFIG_ERROR),
    "canlog-log": (RECORDING_ERROR, DBC_ERROR),
    "canlog-asc": (RECORDING_ERROR, DBC_ERROR),
    "canlog-blf": (RECORDING_ERROR, DBC_ERROR),
    "canlog-trc": (RECORDING_ERROR, DBC_ERROR),
    "canlog-pycsv": (RECORDING_ERROR, DBC_ERROR),
    "canlog-sqlite": (RECORDING_ERROR, DBC_ERROR),
    "mf4": (RECORDING_ERROR, DBC_ERROR),
    "recording-mapped": (RECORDING_ERROR,),
    "config": (CONFIG_ERROR,),
    "mqtt-schema": (VALIDATION_ERROR, SCHEMA_ERROR),
    "mqtt-listen": (),  # the listener counts a bad message (Listener.invalid) and acknowledges it
    "outbox": (STORE_ERROR,),
    "fleet": ("bogiemon.fleet.layout.FleetError", "bogiemon.fleet.judge.JudgeError", "bogiemon.fleet.judged_files.ReportError"),
    "store": (STORE_ERROR,),
    "recording-gz": (RECORDING_ERROR,),
    "recording-parquet": (RECORDING_ERROR,),
    "recorder-disk": (),  # nothing the recorder meets on a full disk is the user's error: it counts and goes on
    "reload": (),  # a bad config on SIGHUP is rejected and logged, never raised
    "signals": (),  # what a signal does is the process's exit status and log, judged by the target
}  # a target without an entry has no clear error: every exception it lets through is a crash


def resolve(names: tuple[str, ...]) -> tuple[tuple[type[BaseException], ...], list[str]]:
    """The classes of dotted names, and the names that do not resolve (yet)."""
    found: list[type[BaseException]] = []
    missing: list[str] = []
    for name in names:
        module, _, attr = name.rpartition(".")
        try:
            cls = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError):
            missing.append(name)
            continue
        found.append(cls)
    return tuple(found), missing


# ---- one input, in a worker ----------------------------------------------------------------------


class Context(fuzz_core.Context):
    """A worker's scratch space, and the figures a target notes of the input it runs: ctx.figures,
    a name to a number (the peak memory of a reading, say), emptied before each input; the report
    gives each one's largest over the run and the input that gave it."""

    def __init__(self, root: Path) -> None:
        super().__init__(root)
        self.figures: dict[str, float] = {}


def _site(tb: TracebackType | None) -> str:
    """The innermost frame in the project's code (not bench/ or tests/), else the innermost of all."""
    frames = traceback.extract_tb(tb)
    if not frames:
        return "?"
    harness = [f for f in frames if not f.filename.startswith(str(BENCH))]  # the alarm handler is no site
    theirs = (str(BENCH), str(REPO / "tests"), str(REPO / ".venv"))
    ours = [f for f in harness if f.filename.startswith(str(REPO)) and not f.filename.startswith(theirs) and "site-packages" not in f.filename]
    frame = (ours or harness or frames)[-1]
    path = Path(frame.filename)
    shown = str(path.relative_to(REPO)) if path.is_relative_to(REPO) else "/".join(path.parts[-2:])
    return f"{shown}:{frame.lineno} in {frame.name}"


def _one_line(text: str, limit: int = 300) -> str:
    line = " ".join(text.split())
    return line if len(line) <= limit else line[: limit - 3] + "..."


@dataclass
class Outcome:
    kind: str  # "ok", "clear", "wrong", "crash", "hang"
    key: str = ""  # clear: the exception; wrong: its kind; crash and hang: exception@site
    exception: str = ""
    site: str = ""
    message: str = ""
    traceback: str = ""


def run_input(target: fuzz_core.Target, data: fuzz_core.Input, ctx: fuzz_core.Context, clear: tuple[type[BaseException], ...], limit_s: float) -> Outcome:
    """One input through its target, classified: limit_s of CPU time, or WALL_FACTOR times that of
    wall time for an input that waits (install_alarms first)."""
    try:
        signal.setitimer(signal.ITIMER_PROF, limit_s)
        signal.setitimer(signal.ITIMER_REAL, WALL_FACTOR * limit_s)
        try:
            verdict = target.run(data, ctx)
        finally:
            signal.setitimer(signal.ITIMER_PROF, 0)
            signal.setitimer(signal.ITIMER_REAL, 0)
    except fuzz_core.InputTimeout as exc:
        site = _site(exc.__traceback__)
        over = f"over the {limit_s:g} s CPU limit" if exc.args == ("cpu",) else f"blocked past {WALL_FACTOR * limit_s:g} s of wall time"
        return Outcome("hang", f"InputTimeout@{site}", "InputTimeout", site, over, traceback.format_exc())
    except BaseException as exc:  # noqa: BLE001 - classifying every exception is the point
        name = type(exc).__qualname__
        if clear and isinstance(exc, clear):
            return Outcome("clear", name, name, message=_one_line(str(exc)))
        site = _site(exc.__traceback__)
        return Outcome("crash", f"{name}@{site}", name, site, _one_line(str(exc)), traceback.format_exc())
    if verdict is None:
        return Outcome("ok")
    kind = verdict.split(":", 1)[0].strip()
    return Outcome("wrong", kind, message=_one_line(verdict))


@dataclass
class Tally:
    """Counts of a stretch of inputs, and per distinct finding its count and smallest example."""

    n: int = 0
    ok: int = 0
    clear: Counter[str] = field(default_factory=Counter)
    findings: dict[str, dict[str, dict[str, Any]]] = field(default_factory=lambda: {"crash": {}, "hang": {}, "wrong": {}})
    run_s: float = 0.0
    max_input_s: float = 0.0
    max_input_index: int = -1
    figures: dict[str, tuple[float, int]] = field(default_factory=dict)  # per name: the largest, and its input

    def note(self, name: str, value: float, index: int) -> None:
        if name not in self.figures or value > self.figures[name][0]:
            self.figures[name] = (value, index)

    def add_finding(self, outcome_kind: str, key: str, count: int, example: dict[str, Any] | None) -> None:
        entry = self.findings[outcome_kind].setdefault(key, {"count": 0, "example": None})
        entry["count"] += count
        if example is not None and (entry["example"] is None or (example["size"], example["index"]) < (entry["example"]["size"], entry["example"]["index"])):
            entry["example"] = example

    def merge(self, other: Tally) -> None:
        self.n += other.n
        self.ok += other.ok
        self.clear.update(other.clear)
        for kind, by_key in other.findings.items():
            for key, entry in by_key.items():
                self.add_finding(kind, key, entry["count"], entry["example"])
        self.run_s += other.run_s
        if other.max_input_s > self.max_input_s:
            self.max_input_s, self.max_input_index = other.max_input_s, other.max_input_index
        for name, (value, index) in other.figures.items():
            self.note(name, value, index)

    @property
    def crashes(self) -> int:
        return sum(e["count"] for e in self.findings["crash"].values())

    @property
    def hangs(self) -> int:
        return sum(e["count"] for e in self.findings["hang"].values())

    @property
    def wrong(self) -> int:
        return sum(e["count"] for e in self.findings["wrong"].values())


def _worker(conn: multiprocessing.connection.Connection, cells: Any, seed: int) -> None:
    """A worker process: runs batches of one target's inputs, reporting counts as it goes."""
    progress = ProgressSlot(cells)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    install_alarms()
    devnull = os.open(os.devnull, os.O_WRONLY)  # what the code under test prints or logs is not ours
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    warnings.simplefilter("ignore")
    import logging

    logging.disable(logging.CRITICAL)
    try:
        modules = {spec.module: importlib.import_module(spec.module) for spec in SPECS}
        targets = {t.name: t for module in modules.values() for t in module.TARGETS}
        clear = {spec.name: resolve(CLEAR_ERRORS.get(spec.name, ()))[0] for spec in SPECS}
        size_kib = int(Path("/proc/self/status").read_text().split("VmSize:")[1].split()[0])
        limit = size_kib * 1024 + MEMORY_HEADROOM_BYTES
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
        ctx = Context(fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-"))
        unavailable: dict[str, str | None] = {}
    except BaseException:  # noqa: BLE001 - a target module that does not import: the harness cannot run
        conn.send(("fatal", traceback.format_exc(), 0))
        return
    # What the imports built lives as long as the worker: the collector leaves it alone from now on
    # (a full collection before each recording's input, for its peak memory, scanned it all; the
    # recording targets' quick runs took half the CPU with it frozen, 16 -> 7.8 s for recording-gz).
    gc.freeze()
    try:
        while True:
            message = conn.recv()
            if message is None:
                return
            name, start, stop, limit_s = message
            target = targets[name]
            if name not in unavailable:  # asked once per worker: a target may need what this machine lacks (root, a mount)
                check = getattr(modules[BY_NAME[name].module], "unavailable", None)
                unavailable[name] = check(name) if check is not None else None
            if unavailable[name] is not None:
                conn.send(("unavailable", unavailable[name], stop))
                continue
            ctx.cache.clear()
            tally, sent_sizes = Tally(), dict[tuple[str, str], int]()
            last_report = time.monotonic()
            for index in range(start, stop):
                progress.begin(index)
                try:
                    data = target.generate(fuzz_core.input_rng(seed, name, index))
                except BaseException:  # noqa: BLE001 - a bug of the harness, not a finding
                    conn.send(("fatal", f"{name}: generating input {index} failed:\n{traceback.format_exc()}", index))
                    return
                ctx.figures = {}
                began = time.perf_counter()
                outcome = run_input(target, data, ctx, clear[name], limit_s)
                took_s = time.perf_counter() - began
                tally.n += 1
                for figure, value in ctx.figures.items():
                    tally.note(figure, value, index)
                tally.run_s += took_s
                if took_s > tally.max_input_s:
                    tally.max_input_s, tally.max_input_index = took_s, index
                if outcome.kind == "ok":
                    tally.ok += 1
                elif outcome.kind == "clear":
                    tally.clear[outcome.key] += 1
                else:
                    text = fuzz_core.dump_input(data)
                    best = sent_sizes.get((outcome.kind, outcome.key))
                    example = None
                    if best is None or len(text) < best:
                        sent_sizes[(outcome.kind, outcome.key)] = len(text)
                        example = {"index": index, "size": len(text), "input": text, "exception": outcome.exception,
                                   "site": outcome.site, "message": outcome.message, "traceback": outcome.traceback}  # fmt: skip
                    tally.add_finding(outcome.kind, outcome.key, 1, example)
                now = time.monotonic()
                if now - last_report >= REPORT_EVERY_S or index == stop - 1:
                    progress.idle()  # between inputs: not running one
                    conn.send(("tally", tally, index + 1))
                    tally, last_report = Tally(), now
            progress.idle()
            conn.send(("done", None, stop))
    finally:
        fuzz_core.remove_scratch(os.getpid())  # forked workers skip atexit


# ---- the parent: workers, the watchdog, the tally ------------------------------------------------


class Worker:
    def __init__(self, mp: Any, seed: int) -> None:
        self.conn, child = mp.Pipe()
        cells = mp.RawArray("d", SLOT_SIZE)
        self.progress = ProgressSlot(cells)
        self.process = mp.Process(target=_worker, args=(child, cells, seed), daemon=True)
        self.process.start()
        child.close()
        self.job: tuple[int, int, int] | None = None  # (start, stop, reported up to)

    def stop(self) -> None:
        try:
            self.conn.send(None)
        except OSError:
            pass
        self.process.join(5)
        if self.process.is_alive():
            self.kill()

    def kill(self) -> None:
        self.process.kill()
        self.process.join()
        fuzz_core.remove_scratch(self.process.pid)


@dataclass
class TargetResult:
    spec: Spec
    inputs: int
    tally: Tally
    wall_s: float
    unresolved: list[str]
    unavailable: str | None = None  # why the target could not run on this machine (nothing was counted)


def run_target(spec: Spec, n_inputs: int, seed: int, workers: list[Worker], mp: Any) -> TargetResult:
    tally = Tally()
    pending: deque[tuple[int, int]] = deque((i, min(i + spec.batch, n_inputs)) for i in range(0, n_inputs, spec.batch))
    # Past the soft limits' signals: stuck where signals do not reach. CPU time as for the soft
    # limit, the wall clock for a worker blocked without using the CPU (WALL_FACTOR).
    hard_limit_s = 2 * spec.limit_s + 10.0
    began = time.monotonic()
    unavailable: str | None = None
    while pending or any(w.job is not None for w in workers):
        for w in workers:
            if w.job is None and pending:
                start, stop = pending.popleft()
                w.job = (start, stop, start)
                w.conn.send((spec.name, start, stop, spec.limit_s))
        busy = [w for w in workers if w.job is not None]
        ready = multiprocessing.connection.wait([w.conn for w in busy], timeout=0.25)
        for i, w in enumerate(workers):
            if w.job is None:
                continue
            start, stop, reported = w.job
            if w.conn in ready:
                try:
                    what, part, next_index = w.conn.recv()
                except (EOFError, OSError):
                    workers[i] = _replace(w, mp, seed, spec, tally, pending, "crash", "the worker process died")
                    continue
                if what == "fatal":
                    raise RuntimeError(f"a fuzz worker failed:\n{part}")
                if what == "tally":
                    tally.merge(part)
                    w.job = (start, stop, next_index)
                elif what == "unavailable":
                    unavailable, w.job = part, None
                    pending.clear()
                else:
                    w.job = None
                continue
            if not w.process.is_alive():
                workers[i] = _replace(w, mp, seed, spec, tally, pending, "crash", "the worker process died")
                continue
            why = stuck(*w.progress.took(time.monotonic(), cpu_time_s(w.process.pid or 0)), hard_limit_s)
            if why is not None:
                workers[i] = _replace(w, mp, seed, spec, tally, pending, "hang", why)
    return TargetResult(spec, n_inputs, tally, time.monotonic() - began, resolve(CLEAR_ERRORS.get(spec.name, ()))[1], unavailable)


def _replace(w: Worker, mp: Any, seed: int, spec: Spec, tally: Tally, pending: deque[tuple[int, int]], kind: str, why: str) -> Worker:
    """A worker stuck in one input or dead: count that input, requeue the rest of its batch, start another."""
    assert w.job is not None
    start, stop, reported = w.job
    index = w.progress.last_index()
    if kind == "crash":
        w.process.join(2)  # it is going: let it tell how
    code = w.process.exitcode
    w.kill()
    if kind == "hang":
        exception, cause = "WorkerKilled", "stuck past the hard limit"
    else:
        exception = "WorkerDied"
        cause = signal.Signals(-code).name if code is not None and code < 0 else f"exit status {code}"
    example = {"index": index, "size": 0, "input": None, "exception": exception, "site": cause,
               "message": f"{why} ({cause})", "traceback": ""}  # fmt: skip
    tally.n += 1
    tally.add_finding(kind, f"{exception}@{cause}", 1, example)
    if index + 1 < stop:
        pending.appendleft((index + 1, stop))
    if reported < index:  # done but not reported before the worker went: run them again
        pending.appendleft((reported, index))
    return Worker(mp, seed)


# ---- the report ---------------------------------------------------------------------------------


def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", text).strip("-")[:90] or "x"


def save_findings(result: TargetResult, seed: int, crash_dir: Path) -> dict[str, dict[str, str]]:
    """Write each finding's smallest example under crash_dir/<target>/ (the old ones go); their file names."""
    folder = crash_dir / result.spec.name
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.json"):
        old.unlink()
    names: dict[str, dict[str, str]] = {"crash": {}, "hang": {}, "wrong": {}}
    for kind, by_key in result.tally.findings.items():
        for key, entry in sorted(by_key.items()):
            example = entry["example"]
            if example is None:
                continue
            file = folder / f"{kind}-{slug(key)}.json"
            shown = file.relative_to(REPO) if file.is_relative_to(REPO) else file
            record = {
                "target": result.spec.name, "outcome": kind, "exception": example["exception"], "site": example["site"],
                "message": example["message"], "count": entry["count"], "seed": seed, "index": example["index"],
                "replay": f".venv/bin/python bench/fuzz.py --replay {shown}",
                "regenerate": f".venv/bin/python bench/fuzz.py --target {result.spec.name} --seed {seed} --index {example['index']}",
                "traceback": example["traceback"].splitlines(),
                "input": json.loads(example["input"]) if example["input"] is not None else None,
            }  # fmt: skip
            file.write_text(json.dumps(record, indent=1, allow_nan=True) + "\n")
            names[kind][key] = str(shown)
    return names


def table(results: list[TargetResult]) -> str:
    head = ("target", "inputs", "ok", "clear errors", "crashes", "distinct", "hangs", "wrong", "wall s", "slowest input ms")
    rows = [head]
    for r in results:
        t = r.tally
        if r.unavailable is not None:
            rows.append((r.spec.name, "not run", *("-" * (len(head) - 2))))
            continue
        rows.append((r.spec.name, f"{t.n:,}".replace(",", " "), str(t.ok), str(sum(t.clear.values())), str(t.crashes),
                     str(len(t.findings["crash"])), str(t.hangs), str(t.wrong), f"{r.wall_s:.1f}", f"{t.max_input_s * 1e3:.1f}"))  # fmt: skip
    widths = [max(len(row[i]) for row in rows) for i in range(len(head))]
    lines = ["| " + " | ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) + " |" for row in rows]
    lines.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(lines)


def details(results: list[TargetResult], saved: dict[str, dict[str, dict[str, str]]]) -> str:
    out = []
    for r in results:
        t = r.tally
        lines = []
        for kind in ("crash", "hang", "wrong"):
            for key, entry in sorted(t.findings[kind].items(), key=lambda kv: -kv[1]["count"]):
                ex = entry["example"] or {}
                what = f"{ex.get('exception', '')} at {ex.get('site', '')}: " if kind != "wrong" else ""
                file = saved.get(r.spec.name, {}).get(kind, {}).get(key, "")
                lines.append(f"  {kind:<5} {entry['count']:>6} x {what}{ex.get('message', '')[:200]}" + (f"\n               -> {file}" if file else ""))
        if r.unavailable is not None:
            lines.append(f"  not run: {r.unavailable}")
        if t.clear:
            lines.append("  clear  " + ", ".join(f"{name} {n}" for name, n in t.clear.most_common()))
        for figure, (value, index) in sorted(t.figures.items()):
            lines.append(f"  {figure}: {value:.4g} at most (input {index})")
        if r.unresolved:
            lines.append("  (clear-error classes not defined yet: " + ", ".join(r.unresolved) + ")")
        if lines:
            out.append(f"{r.spec.name} ({r.spec.what}):\n" + "\n".join(lines))
    return "\n".join(out)


def as_json(results: list[TargetResult], seed: int, quick: bool, jobs: int, wall_s: float) -> dict[str, Any]:
    return {
        "seed": seed, "quick": quick, "jobs": jobs, "wall_s": round(wall_s, 1),
        "targets": {
            r.spec.name: {
                "inputs": r.tally.n, "ok": r.tally.ok, "clear": dict(r.tally.clear), "crashes": r.tally.crashes,
                "distinct_crashes": len(r.tally.findings["crash"]), "hangs": r.tally.hangs, "wrong": r.tally.wrong,
                "wall_s": round(r.wall_s, 2), "run_s": round(r.tally.run_s, 2), "slowest_input_s": round(r.tally.max_input_s, 4),
                "findings": {kind: {key: e["count"] for key, e in by_key.items()} for kind, by_key in r.tally.findings.items()},
                "figures": {name: {"max": value, "input": index} for name, (value, index) in r.tally.figures.items()},
                "planned": r.inputs, "unavailable": r.unavailable,
            }
            for r in results
        },
    }  # fmt: skip


# ---- one input, here ----------------------------------------------------------------------------


def run_here(name: str, data: fuzz_core.Input, show: bool) -> int:
    """Run one input in this process and print what happened (the traceback of a crash)."""
    spec = BY_NAME[name]
    module = importlib.import_module(spec.module)
    target = next(t for t in module.TARGETS if t.name == name)
    if show:
        print(fuzz_core.dump_input(data))
    clear, _ = resolve(CLEAR_ERRORS.get(name, ()))
    install_alarms()
    check = getattr(module, "unavailable", None)
    why = check(name) if check is not None else None
    if why is not None:
        print(f"{name}: not run: {why}")
        return 0
    ctx = Context(fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-"))
    try:
        outcome = run_input(target, data, ctx, clear, spec.limit_s)
    finally:
        fuzz_core.remove_scratch(os.getpid())
    for figure, value in ctx.figures.items():
        print(f"{name}: {figure} {value:.4g}")
    print(f"{name}: {outcome.kind}" + (f" {outcome.key}" if outcome.key else "") + (f": {outcome.message}" if outcome.message else ""))
    if outcome.traceback:
        print(outcome.traceback, end="")
    return 1 if outcome.kind in ("crash", "hang") else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--target", help="comma-separated targets (default: all): " + ", ".join(BY_NAME))
    parser.add_argument("--inputs", type=int, help="inputs per target (default: each target's own count)")
    parser.add_argument("--quick", action="store_true", help="a few thousand inputs per target (the CI run)")
    parser.add_argument("--share", type=float, default=1.0, metavar="F",
                        help="run this share (0 < F <= 1) of each target's count: its first inputs, at least one (make test: a third of --quick)")  # fmt: skip
    parser.add_argument("--seed", type=int, default=DEFAULT_SEED, help=f"the run's seed (default {DEFAULT_SEED})")
    parser.add_argument("--jobs", type=int, default=min(2, os.cpu_count() or 1), help="worker processes (default: 2)")
    parser.add_argument("--crash-dir", type=Path, default=DEFAULT_CRASH_DIR, help="where findings are saved (default bench/fuzz_crashes)")
    parser.add_argument("--json", type=Path, help="also write the figures as JSON here")
    parser.add_argument("--replay", type=Path, metavar="FILE", help="run one saved input in this process and print its traceback")
    parser.add_argument("--index", type=int, help="with one --target: run that generated input in this process")
    parser.add_argument("--show", action="store_true", help="with --index or --replay: print the input too")
    args = parser.parse_args(argv)

    if args.replay is not None:
        record = json.loads(args.replay.read_text())
        if record["input"] is None:  # a worker killed in C kept no copy: the input is regenerated
            return run_here(record["target"], _generate(record["target"], record["seed"], record["index"]), args.show)
        return run_here(record["target"], fuzz_core.load_input(json.dumps(record["input"])), args.show)
    if not 0.0 < args.share <= 1.0:
        parser.error(f"--share {args.share:g}: a share of each target's inputs, more than 0 and at most 1")
    names = args.target.split(",") if args.target else list(BY_NAME)
    unknown = [n for n in names if n not in BY_NAME]
    if unknown:
        parser.error(f"unknown target(s) {', '.join(unknown)}; known: {', '.join(BY_NAME)}")
    if args.index is not None:
        if len(names) != 1:
            parser.error("--index needs exactly one --target")
        return run_here(names[0], _generate(names[0], args.seed, args.index), args.show)

    mp = multiprocessing.get_context("fork")
    workers = [Worker(mp, args.seed) for _ in range(max(1, args.jobs))]
    results: list[TargetResult] = []
    saved: dict[str, dict[str, dict[str, str]]] = {}
    began = time.monotonic()
    load_before = os.getloadavg()[0]
    try:
        for name in names:
            spec = BY_NAME[name]
            n = args.inputs if args.inputs is not None else (spec.quick if args.quick else spec.inputs)
            n = max(1, math.ceil(args.share * n))  # input i is seeded by i alone: a share is the run's first inputs
            result = run_target(spec, n, args.seed, workers, mp)
            results.append(result)
            saved[name] = save_findings(result, args.seed, args.crash_dir)
            t = result.tally
            if result.unavailable is not None:
                print(f"fuzz: {name}: not run: {result.unavailable}", file=sys.stderr, flush=True)
                continue
            print(f"fuzz: {name}: {t.n} inputs, {sum(t.clear.values())} clear errors, {t.crashes} crashes "
                  f"({len(t.findings['crash'])} distinct), {t.hangs} hangs, {t.wrong} wrong, {result.wall_s:.1f} s", file=sys.stderr, flush=True)  # fmt: skip
    except KeyboardInterrupt:
        for w in workers:
            w.kill()
        return 130
    finally:
        for w in workers:
            if w.process.is_alive():
                w.stop()
    wall_s = time.monotonic() - began
    text = (f"bogiemon fuzz: seed {args.seed}, {'quick' if args.quick else 'full'} run{f' (a share of {args.share:g})' if args.share < 1 else ''}, {len(workers)} worker(s), "
            f"{wall_s:.0f} s wall, load average {load_before:.2f} before, {os.getloadavg()[0]:.2f} after\n\n"
            f"{table(results)}\n\n{details(results, saved)}\n")  # fmt: skip
    print(text, end="")
    args.crash_dir.mkdir(parents=True, exist_ok=True)
    (args.crash_dir / "last-run.md").write_text(f"# The last fuzz run\n\n    {' '.join(['bench/fuzz.py', *(argv if argv is not None else sys.argv[1:])])}\n\n{text}")
    if args.json is not None:
        args.json.write_text(json.dumps(as_json(results, args.seed, args.quick, len(workers), wall_s), indent=1) + "\n")
    return 1 if any(r.tally.crashes or r.tally.hangs for r in results) else 0


def _generate(name: str, seed: int, index: int) -> fuzz_core.Input:
    module = importlib.import_module(BY_NAME[name].module)
    target = next(t for t in module.TARGETS if t.name == name)
    return target.generate(fuzz_core.input_rng(seed, name, index))


if __name__ == "__main__":
    sys.exit(main())
