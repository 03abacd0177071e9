"""`bogiemon fleet judge`: each wagon's windows through the daemon's own decision, in time order.

Per wagon, its partitions in date order, each window judged by the WindowJudge that `run` and
`replay` use (sensor health, gating, load state, fused score and trend, k-of-n confirmation,
diagnosis), with the sensors' status bits of the window and the gaps of the last hour counted
as the monitor counts them (daemon/windowing.py): the same events as the gateway, the trend
carried across days. Writes the fleet's events in the daemon's event schema, each wagon's
series, and wagons.json (docs/fleet-formats.md, section 3), with each wagon's standing against
its sisters (fleet/evidence.py).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from bogiemon.daemon.decision import FUSED_SCORE, Mode
from bogiemon.daemon.delivery.schema import encode_event
from bogiemon.daemon.events import Event, EventKind
from bogiemon.daemon.models import coupling_features
from bogiemon.daemon.monitor import WindowJudge
from bogiemon.daemon.windowing import GapMemory
from bogiemon.fleet import rows
from bogiemon.fleet.analyze import SUMMARY_FILE, read_partition, wagon_partitions
from bogiemon.fleet.layout import Fleet, Issue, Wagon, scan_fleet

FORMAT = 1
SERIES_FIELDS = (
    ("time_s", pa.float64()), ("judged", pa.bool_()), ("load", pa.string()), ("score", pa.float64()),
    ("trend", pa.float64()), ("warning", pa.float64()), ("alarm", pa.float64()), ("trend_warning", pa.float64()),
    ("trend_alarm", pa.float64()), ("mode", pa.string()), ("gate", pa.string()), ("sensor_problems", pa.string()),
)  # fmt: skip
SERIES_SCHEMA = pa.schema(SERIES_FIELDS)
NAN = math.nan


class JudgeError(ValueError):
    """The windows dataset or the fleet cannot be judged; the message says which and why."""


@dataclass
class LoadEvidence:
    """A load state's coupling vectors over the wagon's judged windows, for fleet/evidence.py."""

    first_day: list[list[float]] = field(default_factory=list)
    last_day: list[list[float]] = field(default_factory=list)


@dataclass(frozen=True)
class WagonJudged:
    wagon_id: str
    events: tuple[Event, ...]
    series: pa.Table
    mode: str
    sensor_reported: dict[str, list[str]]
    windows: int
    judged: int
    gated: int
    sensor_fault_windows: int
    trend: float | None  # the latest judged window's trend and its alarm level
    trend_alarm: float | None
    days: tuple[str, ...]
    evidence: dict[str, dict[str, list[float] | int]]  # load -> first/last day mean coupling vector, windows
    issues: tuple[Issue, ...]


def judge_wagon(wagon: Wagon, out_dir: str | Path) -> WagonJudged:
    """The daemon's decision over one wagon's analysed days."""
    config = wagon.config
    settings = config.monitor_settings()
    judge = WindowJudge(settings)
    gaps = GapMemory()
    geometry = settings.geometry
    fused = settings.decision.fused
    previous_fs: float | None = None
    last_end_s = -math.inf
    events: list[Event] = []
    series: dict[str, list[Any]] = {name: [] for name, _ in SERIES_FIELDS}
    counts = {"windows": 0, "judged": 0, "gated": 0, "sensor": 0}
    evidence: dict[str, LoadEvidence] = {}
    issues: list[Issue] = []
    days: list[str] = []
    trend = trend_alarm = None
    partitions = wagon_partitions(out_dir, wagon)
    for index, (day, path) in enumerate(partitions):
        try:
            table, meta = read_partition(path)
            windows = rows.from_table(table)
        except (OSError, KeyError, ValueError, pa.ArrowException) as exc:
            issues.append(Issue(str(path), f"partition does not read, day skipped: {exc}"))
            continue
        if windows and windows[0].start_s < last_end_s:
            issues.append(Issue(str(path), "day out of order: its first window starts before the previous day's last one ends; skipped"))
            continue
        days.append(day.date)
        issues += [Issue(str(p), str(r)) for p, r in meta.get("skipped", [])]
        status = rows.status_of(table)
        starts = sorted((float(t), float(fs)) for t, fs in meta.get("segment_starts", []))
        next_start = 0
        last_day = index == len(partitions) - 1
        first_day = len(days) == 1
        for window, window_status in zip(windows, status, strict=True):
            # The gaps of the blocks before this window, as the monitor counted them: a new
            # segment at the same rate is a gap (a recording's first block, a lost stretch), a
            # new rate (or the wagon's first block) is a new core.
            while next_start < len(starts) and starts[next_start][0] <= window.start_s:
                start_s, fs_hz = starts[next_start]
                if previous_fs is not None and fs_hz == previous_fs:
                    gaps.add(start_s)
                previous_fs, next_start = fs_hz, next_start + 1
            judged = judge.judge(window, window_status, gaps.count_before(window.end_s))
            events += judged.events
            counts["windows"] += 1
            health, judgement = judged.health, judged.judgement
            row: dict[str, Any] = {
                "time_s": window.end_s, "judged": judgement is not None, "load": judged.load or "", "score": NAN, "trend": NAN,
                "warning": NAN, "alarm": NAN, "trend_warning": NAN, "trend_alarm": NAN,
                "mode": judge.decider.state.mode.name, "gate": health.gate.value if health.gate is not None else "",
                "sensor_problems": "; ".join(f"{ch} {'/'.join(p.value for p in ps)}" for ch, ps in health.problems.items()),
            }  # fmt: skip
            if judgement is not None:
                counts["judged"] += 1
                load = judged.load or ""
                if FUSED_SCORE in judgement.values and fused is not None and load in fused.baselines:
                    lv = fused.baselines[load].levels
                    row.update(score=judgement.values[FUSED_SCORE], trend=judgement.trend, warning=lv.warning, alarm=lv.alarm,
                               trend_warning=lv.trend_warning, trend_alarm=lv.trend_alarm)  # fmt: skip
                    trend, trend_alarm = judgement.trend, lv.trend_alarm
                else:  # the thresholds method: the worst indicator against its alarm level
                    row.update(score=judgement.alarm_ratio, warning=NAN, alarm=1.0)
                x = coupling_features(window, geometry)
                if x is not None:
                    ev = evidence.setdefault(load, LoadEvidence())
                    if first_day:
                        ev.first_day.append([float(v) for v in x])
                    if last_day:
                        ev.last_day.append([float(v) for v in x])
            elif health.gate is not None or judged.unfamiliar is not None:
                counts["gated"] += 1
                row["gate"] = row["gate"] or "unfamiliar_load"
            else:
                counts["sensor"] += 1
            for name, _ in SERIES_FIELDS:
                series[name].append(row[name])
        if windows:
            last_end_s = windows[-1].end_s
    mean_evidence = {
        load: {
            "first_day": np.mean(ev.first_day, axis=0).tolist() if ev.first_day else [],
            "last_day": np.mean(ev.last_day, axis=0).tolist() if ev.last_day else [],
            "first_day_windows": len(ev.first_day),
            "last_day_windows": len(ev.last_day),
        }
        for load, ev in evidence.items()
    }
    return WagonJudged(
        wagon_id=wagon.wagon_id, events=tuple(events), series=pa.Table.from_pydict(series, schema=SERIES_SCHEMA),
        mode=judge.decider.state.mode.name, sensor_reported=dict(judge.health.state.reported),
        windows=counts["windows"], judged=counts["judged"], gated=counts["gated"], sensor_fault_windows=counts["sensor"],
        trend=_finite(trend), trend_alarm=_finite(trend_alarm), days=tuple(days), evidence=mean_evidence, issues=tuple(issues),
    )  # fmt: skip


def _finite(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def state_of(judged: WagonJudged) -> str:
    if judged.windows == 0:
        return "NO_DATA"
    if judged.mode == Mode.CONFIRMED.name:
        return "CONFIRMED"
    if judged.sensor_reported:
        return "SENSOR_FAULT"
    return judged.mode  # SUSPECTED or NORMAL


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


def fleet_root_of(windows_dir: str | Path) -> Path:
    """The fleet folder a windows dataset was analysed from (its _analysis.json)."""
    path = Path(windows_dir) / SUMMARY_FILE
    try:
        return Path(json.loads(path.read_text(encoding="utf-8"))["root"])
    except (OSError, ValueError, KeyError, TypeError):
        raise JudgeError(f"{windows_dir}: not a windows dataset of `bogiemon fleet analyze` (no readable {SUMMARY_FILE}); name the fleet with --fleet") from None


def judge_fleet(
    windows_dir: str | Path,
    out_dir: str | Path,
    fleet_root: str | Path | None = None,
    client: Any = None,
    progress: Callable[[int, int], None] | None = None,
) -> JudgeSummary:
    """Judge every wagon of the fleet from its windows; writes JUDGED (docs/fleet-formats.md)."""
    from bogiemon.fleet.evidence import fleet_relative

    started = time.perf_counter()
    if not Path(windows_dir).is_dir():
        raise JudgeError(f"{windows_dir}: no such windows dataset (run `bogiemon fleet analyze FLEET -o {windows_dir}` first)")
    fleet = scan_fleet(fleet_root if fleet_root is not None else fleet_root_of(windows_dir))
    judged = _judge_all(fleet, windows_dir, client, progress)
    out = Path(out_dir)
    (out / "series").mkdir(parents=True, exist_ok=True)
    relative = fleet_relative(fleet, judged)
    with open(out / "events.jsonl.tmp", "w", encoding="utf-8") as f:
        for j in judged:
            for seq, event in enumerate(j.events, start=1):
                f.write(encode_event(j.wagon_id, seq, event) + "\n")
    (out / "events.jsonl.tmp").replace(out / "events.jsonl")
    entries = []
    for wagon, j in zip(fleet.wagons, judged, strict=True):
        part = out / "series" / f"wagon={wagon.wagon_id}"
        part.mkdir(parents=True, exist_ok=True)
        pq.write_table(j.series, part / "part-0.parquet", compression="zstd")
        entries.append(_wagon_entry(wagon, j, relative.get(wagon.wagon_id)))
    entries.sort(key=lambda e: (-e["attention"], e["wagon"]))
    issues = (*fleet.issues, *(i for j in judged for i in j.issues))
    document = {
        "format": FORMAT,
        "generated_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "fleet": fleet.name,
        "wagons": entries,
        "inputs": {"wagons": len(fleet.wagons), "recordings": fleet.recordings, "skipped": [i.as_dict() for i in _unique(issues)]},
    }
    tmp = out / "wagons.json.tmp"
    tmp.write_text(json.dumps(document, indent=1, allow_nan=False) + "\n", encoding="utf-8")
    tmp.replace(out / "wagons.json")
    states: dict[str, int] = {}
    for e in entries:
        states[e["state"]] = states.get(e["state"], 0) + 1
    return JudgeSummary(str(out), len(entries), sum(len(j.events) for j in judged), states, time.perf_counter() - started, tuple(_unique(issues)))


def _judge_all(fleet: Fleet, windows_dir: str | Path, client: Any, progress: Callable[[int, int], None] | None) -> list[WagonJudged]:
    if client is None:  # light work (a few hundred microseconds per window): in this process
        out = []
        for i, wagon in enumerate(fleet.wagons):
            out.append(judge_wagon(wagon, windows_dir))
            if progress is not None:
                progress(i + 1, len(fleet.wagons))
        return out
    futures = client.map(judge_wagon, list(fleet.wagons), [str(windows_dir)] * len(fleet.wagons), pure=False)
    return list(client.gather(futures))


def _unique(issues: Sequence[Issue]) -> list[Issue]:
    seen, out = set(), []
    for i in issues:
        if (i.path, i.reason) not in seen:
            seen.add((i.path, i.reason))
            out.append(i)
    return out


ATTENTION = {"CONFIRMED": 1000.0, "SENSOR_FAULT": 500.0, "SUSPECTED": 300.0, "NORMAL": 0.0, "NO_DATA": 50.0}
STANDS_OUT_ATTENTION = 200.0


def _wagon_entry(wagon: Wagon, j: WagonJudged, relative: dict[str, Any] | None) -> dict[str, Any]:
    state = state_of(j)
    last = j.events[-1] if j.events else None
    confirmed = [e for e in j.events if e.kind is EventKind.CONFIRMED]
    diagnosis = None
    if state == "CONFIRMED" and confirmed:
        d = confirmed[-1].details.get("diagnosis") or {}
        diagnosis = {k: d.get(k) for k in ("corner", "kind", "corner_confidence", "kind_confidence")}
    trend_ratio = (j.trend / j.trend_alarm) if j.trend is not None and j.trend_alarm else 0.0
    # Within a state: the trend's share of its alarm level orders the wagons (0..100).
    attention = ATTENTION[state] + min(max(trend_ratio, 0.0), 1.0) * 100.0
    if relative is not None and relative.get("stands_out"):
        attention += STANDS_OUT_ATTENTION
    notes = []
    ran_in = [ld for ld in ("full", "tare") if ld in j.evidence] or (["full", "tare"] if not wagon.commissioned else [])
    missing = [ld for ld in ran_in if ld not in wagon.commissioned]
    if missing:
        notes.append(f"not commissioned for {', '.join(missing)}: judged against the fleet's population baseline, which misses most faults (`bogiemon fleet calibrate {wagon.wagon_id}`)")
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
            "seq": len(j.events),
        },  # fmt: skip
        "diagnosis": diagnosis,
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
        "fleet_relative": relative,
        "notes": notes,
    }
