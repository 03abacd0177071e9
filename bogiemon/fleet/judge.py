"""`bogiemon fleet judge`: each wagon's windows through the daemon's own decision, in time order.

Per wagon, its partitions in date order, each window given to the gateway's own per-window call
(WindowJudge.judge of judgement/verdict.py: sensor health, gating, load state, fused score and
trend, k-of-n confirmation, diagnosis; its events numbered as the gateway's store numbers them),
with the sensors' status bits of the window and the gaps of the last hour
from the stored segment starts (judgement/windowing.py): the same events as the gateway, the trend
carried across days. Nothing of the decision is restated here: the series is read off each
window's verdict. Writes the fleet's events in the daemon's event schema, each wagon's
series, and wagons.json (docs/fleet-formats.md, section 3), with each wagon's standing against
its sisters (fleet/evidence.py).
"""

from __future__ import annotations

import contextlib
import functools
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from bogiemon.judgement.decision import FUSED_TREND
from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.judgement.events import ConfirmedDetails, Event
from bogiemon.daemon.messages import encode_event
from bogiemon.judgement.models import finite_or_none
from bogiemon.judgement.verdict import Outcome, WindowJudge, WindowVerdict
from bogiemon.judgement.vocabulary import LoadState, Mode
from bogiemon.judgement.windowing import GapMemory
from bogiemon.drivers.atomic import write_atomically, write_text_atomically
from bogiemon.fleet.evidence import fleet_relative
from bogiemon.fleet.judged import MeanEvidence, WagonJudged
from bogiemon.fleet.judged_files import JUDGED_FORMAT, WagonState
from bogiemon.fleet.cluster import DaskRunner, InProcess, Runner
from bogiemon.fleet.layout import Day, Fleet, Issue, Wagon, scan_fleet
from bogiemon.fleet.worklist import DEFAULT_BOGIE
from bogiemon.fleet.paths import make_room, output_folder, shown, write_parquet
from bogiemon.fleet.windows_files import PartitionError, partition_path, partition_place, read_footer, read_partition, read_summary

SERIES_FIELDS = (
    ("time_s", pa.float64()), ("judged", pa.bool_()), ("load", pa.string()), ("score", pa.float64()),
    ("trend", pa.float64()), ("warning", pa.float64()), ("alarm", pa.float64()), ("trend_warning", pa.float64()),
    ("trend_alarm", pa.float64()), ("mode", pa.string()), ("gate", pa.string()), ("sensor_problems", pa.string()),
)  # fmt: skip
SERIES_SCHEMA = pa.schema(SERIES_FIELDS)
SERIES_FILE = "part-0.parquet"
NAN = math.nan


class JudgeError(ValueError):
    """The windows dataset or the fleet cannot be judged; the message says which and why."""


@dataclass
class LoadEvidence:
    """A load state's coupling vectors over the wagon's judged windows, for fleet/evidence.py."""

    first_day: list[list[float]] = field(default_factory=list)
    last_day: list[list[float]] = field(default_factory=list)


class _Series:
    """A wagon's series (SERIES_FIELDS), one row per window verdict, and the coupling vectors of its
    judged windows on its first and last day (fleet/evidence.py)."""

    def __init__(self) -> None:
        self.columns: dict[str, list[Any]] = {name: [] for name, _ in SERIES_FIELDS}
        self.evidence: dict[str, LoadEvidence] = {}
        self.first_day = self.last_day = False
        self.trend: float | None = None  # the latest judged window's trend and its alarm level
        self.trend_alarm: float | None = None

    def __call__(self, verdict: WindowVerdict) -> None:
        j, health = verdict.judgement, verdict.health
        gate = health.gate.value if health.gate is not None else "unfamiliar_load" if verdict.outcome is Outcome.UNFAMILIAR else ""
        row: dict[str, Any] = {
            "time_s": verdict.window.end_s, "judged": j is not None, "load": verdict.load or "", "score": NAN, "trend": NAN,
            "warning": NAN, "alarm": NAN, "trend_warning": NAN, "trend_alarm": NAN, "mode": verdict.mode.value, "gate": gate,
            "sensor_problems": "; ".join(f"{ch} {'/'.join(p.value for p in ps)}" for ch, ps in health.problems.items()),
        }  # fmt: skip
        if j is not None:
            row["score"], row["warning"], row["alarm"] = j.headline()
            trend_limit = j.limits.get(FUSED_TREND)
            if trend_limit is not None:
                row.update(trend=j.trend, trend_warning=trend_limit.warning, trend_alarm=trend_limit.alarm)
                self.trend, self.trend_alarm = j.trend, trend_limit.alarm
            x = finite_or_none(verdict.features.coupling) if verdict.features is not None else None
            if x is not None and verdict.load is not None:
                ev = self.evidence.setdefault(verdict.load, LoadEvidence())
                if self.first_day:
                    ev.first_day.append([float(v) for v in x])
                if self.last_day:
                    ev.last_day.append([float(v) for v in x])
        for name, _ in SERIES_FIELDS:
            self.columns[name].append(row[name])


def judge_wagon(wagon: Wagon, out_dir: str | Path) -> WagonJudged:
    """The daemon's decision over one wagon's analysed days: its windows, in time order, through
    the gateway's own per-window call, its events numbered 1, 2, ... as the gateway's store
    numbers them."""
    series = _Series()
    judge = WindowJudge(wagon.config.monitor_settings())
    events: list[tuple[int, Event]] = []
    gaps = GapMemory()  # the gaps of the day's segment starts, counted across days as the monitor counts them
    last_end_s = -math.inf
    last_data_s: float | None = None  # the newest window's end: how fresh the wagon's data are
    issues: list[Issue] = []
    days: list[str] = []
    # The footers first (cheap), so that the last day to judge is known before the days are read
    # whole, one at a time.
    partitions: list[tuple[Day, Path]] = []
    out_root = Path(out_dir).resolve()
    for day in wagon.days:
        path = partition_path(out_dir, wagon.wagon_id, day.date)
        place = partition_place(path, out_root)
        try:
            if place == "missing":
                raise PartitionError(path, "not analysed yet", "run `bogiemon fleet analyze` first")
            if place is not None:
                raise PartitionError(path, f"{place} in the place of the partition")
            read_footer(path, day.midnight_s)
        except PartitionError as exc:
            issues.append(_not_judged(exc))
            continue
        partitions.append((day, path))
    for index, (day, path) in enumerate(partitions):
        try:
            partition = read_partition(path, day.midnight_s)
        except PartitionError as exc:
            issues.append(_not_judged(exc))
            continue
        windows, status, starts = partition.windows(), partition.status(), partition.meta.starts
        if windows and windows[0].start_s < last_end_s:
            issues.append(Issue(str(path), "day out of order: its first window starts before the previous day's last one ends; skipped"))
            continue
        days.append(day.date)
        issues += partition.meta.issues
        series.first_day, series.last_day = len(days) == 1, index == len(partitions) - 1
        next_start = 0
        for window, window_status in zip(windows, status, strict=True):
            # The starts before the window, as the monitor met them: a block starting a segment
            # arrives before the windows it begins.
            first = next_start
            while next_start < len(starts) and starts[next_start].start_s <= window.start_s:
                next_start += 1
            gaps.add(starts[first:next_start])
            verdict = judge.judge(window, window_status, gaps.count_before(window.end_s))
            events += [(len(events) + 1 + i, e) for i, e in enumerate(verdict.events)]
            series(verdict)
        if windows:
            last_end_s = last_data_s = windows[-1].end_s
    mean_evidence: dict[str, MeanEvidence] = {
        load: {
            "first_day": np.mean(ev.first_day, axis=0).tolist() if ev.first_day else [],
            "last_day": np.mean(ev.last_day, axis=0).tolist() if ev.last_day else [],
            "first_day_windows": len(ev.first_day),
            "last_day_windows": len(ev.last_day),
        }
        for load, ev in series.evidence.items()
    }
    c, coverage = judge.counts, judge.coverage.state
    return WagonJudged(
        diagnosis_now=_diagnosis_now(judge, events),
        wagon_id=wagon.wagon_id, events=tuple(events), series=pa.Table.from_pydict(series.columns, schema=SERIES_SCHEMA),
        mode=judge.mode, sensor_reported=dict(judge.health.state.reported), not_judged=coverage.reported,
        unjudged_running_s=coverage.unjudged_running_s, windows=c.windows, judged=c.judged, gated=c.gated,
        sensor_fault_windows=c.sensor_fault_windows, trend=_finite(series.trend), trend_alarm=_finite(series.trend_alarm),
        days=tuple(days), evidence=mean_evidence, issues=tuple(issues), last_data_s=last_data_s,
    )  # fmt: skip


def _diagnosis_now(judge: WindowJudge, events: Sequence[tuple[int, Event]]) -> dict[str, Any] | None:
    """The diagnosis of an alarm in force at the period's end from all the running since it was
    confirmed: the decision's own diagnosis of its trend's mean shift in the alarm's load state
    (judgement/decision.py trend_diagnosis). The CONFIRMED event's was read off the few windows that
    confirmed it; a day of running later the pitch-roll sign is often clear where it was not then."""
    if judge.mode is not Mode.CONFIRMED:
        return None
    confirmed = next((e.details for _, e in reversed(events) if isinstance(e.details, ConfirmedDetails)), None)
    if confirmed is None:
        return None
    return _diagnosis_entry(judge.decider.trend_diagnosis(confirmed.load).stated())


def _diagnosis_entry(d: Diagnosis) -> dict[str, Any]:
    """A diagnosis as wagons.json holds it (docs/fleet-formats.md)."""
    return {
        "corner": d.corner, "corners": [c.value for c in d.corners], "kind": d.kind, "corner_confidence": d.corner_confidence,
        "kind_confidence": d.kind_confidence,
    }  # fmt: skip


def _not_judged(exc: PartitionError) -> Issue:
    return Issue(exc.path, f"{exc.problem}: day not judged; {exc.advice}")


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def state_of(judged: WagonJudged) -> WagonState:
    """The wagon's state on the fleet page (wagons.json's words: docs/fleet-formats.md)."""
    if judged.windows == 0:
        return WagonState.NO_DATA
    if judged.mode is Mode.CONFIRMED:
        return WagonState.CONFIRMED
    if judged.sensor_reported:
        return WagonState.SENSOR_FAULT
    if judged.not_judged:
        return WagonState.NOT_JUDGED
    return WagonState(judged.mode.name)  # SUSPECTED or NORMAL


# --------------------------------------------------------------------------------------------
# The fleet


@dataclass(frozen=True)
class JudgeSummary:
    out_dir: str
    wagons: int
    events: int
    states: dict[str, int]
    elapsed_s: float
    issues: tuple[Issue, ...]


def fleet_root_of(windows_dir: str | Path) -> str:
    """The fleet (a folder, or an object store's URL) a windows dataset was analysed from (its _analysis.json)."""
    try:
        return read_summary(Path(windows_dir), JudgeError).root
    except JudgeError as exc:
        raise JudgeError(f"{exc}; is {shown(windows_dir)} a windows dataset of `bogiemon fleet analyze`? Or name the fleet with --fleet") from None


def judge_fleet(
    windows_dir: str | Path,
    out_dir: str | Path,
    fleet_root: str | Path | None = None,
    client: Any = None,
    progress: Callable[[int, int], None] | None = None,
) -> JudgeSummary:
    """Judge every wagon of the fleet from its windows; writes JUDGED (docs/fleet-formats.md)."""
    started = time.perf_counter()
    if not Path(windows_dir).is_dir():
        raise JudgeError(f"{shown(windows_dir)}: no such windows dataset (run `bogiemon fleet analyze FLEET -o {shown(windows_dir)}` first)")
    fleet = scan_fleet(fleet_root if fleet_root is not None else fleet_root_of(windows_dir))
    out = output_folder(out_dir, JudgeError, "JUDGED", {"WINDOWS": windows_dir, **fleet.local_inputs}).resolve()  # what lies inside it is checked against it
    judged = _judge_all(fleet, windows_dir, client, progress)
    relative = fleet_relative(fleet, judged)
    entries = []
    try:
        for name in ("events.jsonl", "wagons.json"):
            make_room(out / name, out)  # a folder there (JUDGED is the judge's own) would refuse the rename for good
        write_text_atomically(out / "events.jsonl", "".join(encode_event(j.wagon_id, seq, event) + "\n" for j in judged for seq, event in j.events))
        for wagon, j in zip(fleet.wagons, judged, strict=True):
            series_path = out / "series" / f"wagon={wagon.wagon_id}" / SERIES_FILE
            make_room(series_path, out)
            write_atomically(series_path, functools.partial(write_parquet, j.series))
            entries.append(_wagon_entry(wagon, j, relative.get(wagon.wagon_id)))
        entries.sort(key=lambda e: (-e["attention"], e["wagon"]))
        issues = (*fleet.issues, *(i for j in judged for i in j.issues))
        document = {
            "format": JUDGED_FORMAT,
            "generated_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "fleet": fleet.name,
            "wagons": entries,
            "inputs": {"wagons": len(fleet.wagons), "recordings": fleet.recordings, "skipped": [i.as_dict() for i in _unique(issues)]},
        }
        write_text_atomically(out / "wagons.json", json.dumps(document, indent=1, allow_nan=False) + "\n")
    except OSError as exc:
        raise JudgeError(f"{shown(out)}: JUDGED cannot be written ({exc.strerror or exc})") from None
    states: dict[str, int] = {}
    for e in entries:
        states[e["state"]] = states.get(e["state"], 0) + 1
    return JudgeSummary(str(out), len(entries), sum(len(j.events) for j in judged), states, time.perf_counter() - started, tuple(_unique(issues)))


def _judge_all(fleet: Fleet, windows_dir: str | Path, client: Any, progress: Callable[[int, int], None] | None) -> list[WagonJudged]:
    """Every wagon judged, in the fleet's order: here (light work, a few hundred microseconds per
    window), or on the client's cluster."""
    runner: Runner = InProcess() if client is None else DaskRunner(client)
    done: dict[str, WagonJudged] = {}
    with contextlib.closing(runner.map(functools.partial(judge_wagon, out_dir=str(windows_dir)), fleet.wagons)) as results:
        for judged in results:
            done[judged.wagon_id] = judged
            if progress is not None:
                progress(len(done), len(fleet.wagons))
    return [done[w.wagon_id] for w in fleet.wagons]


def _unique(issues: Sequence[Issue]) -> list[Issue]:
    seen, out = set(), []
    for i in issues:
        if (i.path, i.reason) not in seen:
            seen.add((i.path, i.reason))
            out.append(i)
    return out


ATTENTION = {
    WagonState.CONFIRMED: 1000.0, WagonState.SENSOR_FAULT: 500.0, WagonState.NOT_JUDGED: 400.0, WagonState.SUSPECTED: 300.0,
    WagonState.NORMAL: 0.0, WagonState.NO_DATA: 50.0,
}  # fmt: skip
STANDS_OUT_ATTENTION = 200.0


def _wagon_entry(wagon: Wagon, j: WagonJudged, relative: dict[str, Any] | None) -> dict[str, Any]:
    state = state_of(j)
    last_seq, last = j.events[-1] if j.events else (0, None)
    confirmed = [e.details for _, e in j.events if isinstance(e.details, ConfirmedDetails)]
    diagnosis = None
    if state is WagonState.CONFIRMED and confirmed and (d := confirmed[-1].diagnosis) is not None:
        diagnosis = _diagnosis_entry(d)
    trend_ratio = (j.trend / j.trend_alarm) if j.trend is not None and j.trend_alarm else 0.0
    # Within a state: the trend's share of its alarm level orders the wagons (0..100).
    attention = ATTENTION[state] + min(max(trend_ratio, 0.0), 1.0) * 100.0
    if relative is not None and relative.get("stands_out"):
        attention += STANDS_OUT_ATTENTION
    notes = []
    ran_in = [ld for ld in LoadState if ld in j.evidence] or (list(LoadState) if not wagon.commissioned else [])
    missing = [ld for ld in ran_in if ld not in wagon.commissioned]
    if missing:
        notes.append(f"not commissioned for {', '.join(missing)}: judged against the fleet's population baseline, which misses most faults (`bogiemon fleet calibrate {wagon.wagon_id}`)")
    if j.not_judged:
        notes.append(
            f"not judged for the last {j.unjudged_running_s / 3600:.1f} h of running: the wagon is unlike its commissioning; "
            "inspect it, or commission it again"
        )
    skipped = list(j.issues)
    if skipped:
        notes.append(f"{len(skipped)} input(s) skipped: " + "; ".join(f"{Path(i.path).name}: {i.reason}" for i in skipped[:3]))
    if relative is not None and relative.get("stands_out"):
        notes.append(str(relative["why"]))
    return {
        "wagon": wagon.wagon_id,
        "type": wagon.wagon_type,
        "state": state,
        "attention": round(attention, 3),
        "last_event": None if last is None else {
            "kind": last.kind.value, "time_s": last.time_s, "time_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(last.time_s)),
            "seq": last_seq,
        },  # fmt: skip
        "diagnosis": diagnosis,
        # Per bogie (worklist.bogie_of's names; one bogie judged here: "1").
        "diagnosis_now": {} if j.diagnosis_now is None else {DEFAULT_BOGIE: j.diagnosis_now},
        "sensor_problems": j.sensor_reported,
        "trend": j.trend,
        "trend_alarm": j.trend_alarm,
        "commissioned": list(wagon.commissioned),
        "days": len(j.days),
        "first_day": j.days[0] if j.days else None,
        "last_day": j.days[-1] if j.days else None,
        "windows": j.windows,
        "judged": j.judged,
        "gated": j.gated,
        "sensor_fault_windows": j.sensor_fault_windows,
        "last_data_s": j.last_data_s,
        "sensor_corners": {ch: getattr(wagon.config.sensors, ch).value for ch in ("a1", "a2", "a3")},
        "fleet_relative": relative,
        "notes": notes,
    }
