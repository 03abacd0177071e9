"""Scoring the robustness evaluation: what each detection method made of the evaluation fleet.

    results = judge_runs(data, method)                 # lab/robust/judge.py
    score = score_method(data, method.name, method.description, results)

Every figure of docs/robust comes from here, by rules fixed before the results were looked at:

- DETECTED: a fault run whose fault is CONFIRMED within DETECTION_HORIZON_S of running with it
  (the "2 minutes of running" of issue 8); the time to confirmation is from the onset to the end
  of the window that confirmed it. A CONFIRMED before the onset is a false alarm.
- DETECTED IN A SEQUENCE: a trend sequence (the fault stays while the same wagon runs on over
  several runs) whose fault is CONFIRMED before the sequence ends, by either path; the time is
  of running with the fault.
- FALSE ALARMS: CONFIRMED events in the healthy test runs (and in the fault runs' healthy
  lead-in), per hour of running; SUSPECTED per hour beside them.
- LOAD STATE: the share of judged windows whose load state (configured or estimated) is the run's.
- CORNER AND KIND: of the detected runs, the share whose diagnosis names the fault's corner among
  the corners it names (a diagonal pair: judgement/diagnosis.py) and its kind; "unknown" counts as
  not right, and its share is given; named corners without the fault's are wrong.
- SENSOR FAULTS: a damaged-sensor run is recognised when a SENSOR_FAULT names the expected problem
  on every expected channel; it must never raise SUSPECTED or CONFIRMED. A SENSOR_FAULT in a
  healthy test run is false (per run, as the SUSPECTED runs).
- QUIET RUNS (stops and starts, standing): healthy running that must raise no SUSPECTED or
  CONFIRMED; per role the runs that did, and those with a (false) SENSOR_FAULT.
- The horizon of DETECTED is score_method's `horizon_s` (DETECTION_HORIZON_S unless given); a
  sequence cell also counts its sequences confirmed within any horizon (SequenceCell.within).
"""

from __future__ import annotations

import math
import statistics
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.lab.robust.fleet import DETECTION_HORIZON_S, EXPECTED_PROBLEM, EvaluationData
from bogiemon.lab.robust.judge import RunResult, SequenceResult


@dataclass(frozen=True)
class CellScore:
    """One fault case at one severity, over every corner and run."""

    key: str
    severity: float
    runs: int
    detected: int
    times_s: tuple[float, ...]  # time to confirmation of the detected runs
    by_corner: dict[str, tuple[int, int]]  # corner -> (runs, detected)
    corner_right: int  # detected runs whose diagnosis names the right corner
    kind_right: int
    unknown_corner: int
    # The alarm ratios of the windows wholly after the onset (>= 1: alarm level), every run.
    ratios: tuple[float, ...] = field(repr=False)
    silent: int = 0  # runs with not one window judged after the onset and no event: the monitor fell silent

    @property
    def median_ratio(self) -> float:
        return statistics.median(self.ratios) if self.ratios else math.nan

    @property
    def rate(self) -> float:
        return self.detected / self.runs if self.runs else math.nan

    @property
    def median_time_s(self) -> float:
        return statistics.median(self.times_s) if self.times_s else math.nan


@dataclass(frozen=True)
class SequenceCell:
    """One fault case at one severity over its trend sequences (every corner)."""

    key: str
    severity: float
    sequences: int
    running_s: float  # of running with the fault, per sequence
    detected: int
    by_trend: int  # of those, confirmed by the trend
    times_s: tuple[float, ...]
    corner_right: int
    kind_right: int
    silent: int = 0  # sequences with not one window judged after the onset and no event

    @property
    def rate(self) -> float:
        return self.detected / self.sequences if self.sequences else math.nan

    def within(self, horizon_s: float) -> int:
        """Sequences confirmed within horizon_s of running with the fault."""
        return sum(t <= horizon_s + 1e-9 for t in self.times_s)

    @property
    def median_time_s(self) -> float:
        return statistics.median(self.times_s) if self.times_s else math.nan


@dataclass(frozen=True)
class SensorScore:
    damage: str
    runs: int
    recognised: int  # a SENSOR_FAULT named the expected problem on the expected channels
    flagged: int  # any SENSOR_FAULT at all
    suspension_runs: int  # runs with a SUSPECTED or CONFIRMED (must be 0)
    problems: dict[str, int]  # "a1:inverted" -> runs naming it
    channels_named: int = 0  # a SENSOR_FAULT named every expected channel, whatever the problem


@dataclass(frozen=True)
class QuietScore:
    """The runs of one quiet role ("stops", "standing"): healthy running that must stay quiet."""

    role: str
    runs: int
    hours: float
    suspension_runs: int  # runs with a SUSPECTED or CONFIRMED (must be 0)
    confirmed_runs: int
    sensor_fault_runs: int  # runs with a SENSOR_FAULT (false: the sensors are sound)
    problems: dict[str, int]  # "a1:flat" -> runs naming it
    windows: int
    judged_windows: int


@dataclass(frozen=True)
class MethodScore:
    method: str
    description: str
    cells: tuple[CellScore, ...]
    healthy_runs: int
    healthy_hours: float
    healthy_alarm_runs: int  # healthy runs with a CONFIRMED
    healthy_alarms: int  # CONFIRMED events in healthy runs
    healthy_suspected: int
    healthy_alarm_triggers: dict[str, int]  # what confirmed the healthy runs' first alarms: "windows", "trend"
    lead_in_hours: float
    lead_in_alarms: int  # fault runs CONFIRMED before their onset
    load_windows: dict[str, tuple[int, int]]  # true load -> (judged windows, in the right load state)
    load_margin: float  # the smallest |P(full) - 0.5| on the right side, over every estimated window (NaN: none)
    healthy_ratios: tuple[float, ...] = field(repr=False)  # every judged healthy window's alarm ratio
    sensors: tuple[SensorScore, ...] = ()
    sequence_cells: tuple[SequenceCell, ...] = ()
    sequence_lead_in_alarms: int = 0
    detection_horizon_s: float = DETECTION_HORIZON_S  # of `cells`' DETECTED
    healthy_suspected_runs: int = 0  # healthy runs with a SUSPECTED
    healthy_sensor_fault_runs: int = 0  # healthy runs with a (false) SENSOR_FAULT
    healthy_problems: dict[str, int] = field(default_factory=dict)  # "a1:flat" -> healthy runs naming it
    quiet: tuple[QuietScore, ...] = ()
    load_all_windows: dict[str, int] = field(default_factory=dict)  # true load -> every window, judged or not
    healthy_windows: int = 0
    healthy_judged_windows: int = 0
    healthy_unjudged_runs: int = 0  # healthy runs with not one window judged

    def quiet_role(self, role: str) -> QuietScore | None:
        return next((q for q in self.quiet if q.role == role), None)

    def sensor(self, damage: str) -> SensorScore | None:
        return next((s for s in self.sensors if s.damage == damage), None)

    def sequence_cell(self, key: str, severity: float) -> SequenceCell | None:
        return next((c for c in self.sequence_cells if c.key == key and c.severity == severity), None)

    def cell(self, key: str, severity: float) -> CellScore:
        for c in self.cells:
            if c.key == key and c.severity == severity:
                return c
        raise KeyError((key, severity))

    @property
    def false_alarms_per_hour(self) -> float:
        return self.healthy_alarms / self.healthy_hours if self.healthy_hours else math.nan

    def load_accuracy(self, load: str | None = None) -> float:
        pairs = [v for k, v in self.load_windows.items() if load is None or k == load]
        n = sum(p[0] for p in pairs)
        return sum(p[1] for p in pairs) / n if n else math.nan


def _detected(r: RunResult, horizon_s: float = DETECTION_HORIZON_S) -> bool:
    return r.confirmed_s is not None and r.confirmed_s - r.run.onset_s <= horizon_s + 1e-9


def _named(runs: Sequence[RunResult]) -> dict[str, int]:
    """"a1:flat" -> runs whose SENSOR_FAULTs named it, most named first."""
    named: dict[str, int] = {}
    for r in runs:
        for channel, found in r.sensor_problems.items():
            for p in found:
                named[f"{channel}:{p}"] = named.get(f"{channel}:{p}", 0) + 1
    return dict(sorted(named.items(), key=lambda kv: -kv[1]))


def _faulty_ratios(r: RunResult, window_s: float) -> list[float]:
    return [x for x, end in zip(r.ratios, r.window_ends_s, strict=True) if x is not None and end - window_s >= r.run.onset_s - 1e-9]


def _silent(r: RunResult) -> bool:
    """A fault run with not one window judged after its onset and no event: nothing anyone sees."""
    judged = any(ld is not None and end > r.run.onset_s for ld, end in zip(r.loads, r.window_ends_s, strict=True))
    return not judged and r.suspension_events == 0 and not r.sensor_problems


def named_corners(diagnosis: Diagnosis | None) -> tuple[str, ...]:
    """The corners a diagnosis names (none without one)."""
    return () if diagnosis is None else tuple(c.value for c in diagnosis.corners)


def _sequence_cells(results: Sequence[SequenceResult]) -> list[SequenceCell]:
    cells: dict[tuple[str, float], list[SequenceResult]] = {}
    for r in results:
        cells.setdefault((r.first.key, r.first.severity), []).append(r)
    out = []
    for (key, severity), seqs in sorted(cells.items()):
        found = [r for r in seqs if r.confirmed_after_s is not None]
        corner = [r.first.corner.value if r.first.corner else None for r in found]
        out.append(
            SequenceCell(
                key=key,
                severity=severity,
                sequences=len(seqs),
                running_s=statistics.median(r.fault_running_s for r in seqs),
                detected=len(found),
                by_trend=sum(r.trigger == "trend" for r in found),
                times_s=tuple(float(r.confirmed_after_s) for r in found),  # type: ignore[arg-type]
                corner_right=sum(c in named_corners(r.diagnosis) for r, c in zip(found, corner, strict=True)),
                kind_right=sum(r.diagnosis is not None and r.diagnosis.kind == r.first.kind for r in found),
                silent=sum(r.judged_after_onset == 0 and r.events_after_onset == 0 for r in seqs),
            )
        )
    return out


QUIET_ROLES = ("stops", "standing")
# The runs whose windows count for the load state: running of the wagon with sound sensors.
LOAD_ROLES = ("healthy", "fault", "stops")


def score_method(
    data: EvaluationData,
    method: str,
    description: str,
    results: Sequence[RunResult],
    sequences: Sequence[SequenceResult] = (),
    horizon_s: float = DETECTION_HORIZON_S,
) -> MethodScore:
    """Every figure of one method: `results` are its judged test runs (the quiet roles' too, when
    the plan has them), `sequences` its trend sequences; a fault run is DETECTED when confirmed
    within horizon_s of running with the fault."""
    window_s = data.settings.window_s
    cells: dict[tuple[str, float], list[RunResult]] = {}
    healthy, sensor = [], []
    quiet: dict[str, list[RunResult]] = {}
    load_windows: dict[str, list[int]] = {}
    load_all: dict[str, int] = {}
    for r in results:
        if r.run.role == "fault":
            cells.setdefault((r.run.key, r.run.severity), []).append(r)
        elif r.run.role == "healthy":
            healthy.append(r)
        elif r.run.role == "sensor":
            sensor.append(r)
        elif r.run.role in QUIET_ROLES:
            quiet.setdefault(r.run.role, []).append(r)
        if r.run.role in LOAD_ROLES:
            counts = load_windows.setdefault(r.run.load, [0, 0])
            judged = [ld for ld in r.loads if ld is not None]
            counts[0] += len(judged)
            counts[1] += sum(ld == r.run.load for ld in judged)
            load_all[r.run.load] = load_all.get(r.run.load, 0) + len(r.loads)
    cell_scores = []
    for (key, severity), runs in sorted(cells.items()):
        detected = [r for r in runs if _detected(r, horizon_s)]
        by_corner: dict[str, list[int]] = {}
        for r in runs:
            c = by_corner.setdefault(r.run.corner.value if r.run.corner else "-", [0, 0])
            c[0] += 1
            c[1] += _detected(r, horizon_s)
        diagnoses = [(r, r.diagnosis) for r in detected]
        ratios = [x for r in runs for x in _faulty_ratios(r, window_s)]
        cell_scores.append(
            CellScore(
                key=key,
                severity=severity,
                runs=len(runs),
                detected=len(detected),
                times_s=tuple(float(r.confirmed_s - r.run.onset_s) for r in detected),  # type: ignore[operator]
                by_corner={k: (v[0], v[1]) for k, v in sorted(by_corner.items())},
                corner_right=sum((r.run.corner.value if r.run.corner else None) in named_corners(d) for r, d in diagnoses),
                kind_right=sum(d is not None and d.kind == r.run.kind for r, d in diagnoses),
                unknown_corner=sum(not named_corners(d) for _, d in diagnoses),
                ratios=tuple(ratios),
                silent=sum(_silent(r) for r in runs),
            )
        )
    faults = [r for rs in cells.values() for r in rs]
    return MethodScore(
        method=method,
        description=description,
        cells=tuple(cell_scores),
        healthy_runs=len(healthy),
        healthy_hours=sum(r.run.duration_s for r in healthy) / 3600.0,
        healthy_alarm_runs=sum(r.confirmed_s is not None for r in healthy),
        healthy_alarms=sum(r.confirmed_count for r in healthy),
        healthy_suspected=sum(r.suspected_count for r in healthy),
        healthy_alarm_triggers=dict(Counter(str(r.trigger) for r in healthy if r.confirmed_s is not None)),
        lead_in_hours=(sum(r.run.onset_s for r in faults) + sum(r.first.onset_s for r in sequences)) / 3600.0,
        lead_in_alarms=sum(r.confirmed_before_onset for r in faults),
        load_windows={k: (v[0], v[1]) for k, v in sorted(load_windows.items())},
        load_margin=_load_margin(results),
        healthy_ratios=tuple(x for r in healthy for x in r.ratios if x is not None),
        sensors=tuple(_sensor_scores(sensor)),
        sequence_cells=tuple(_sequence_cells(sequences)),
        sequence_lead_in_alarms=sum(r.confirmed_before_onset for r in sequences),
        detection_horizon_s=horizon_s,
        healthy_suspected_runs=sum(r.suspected_count > 0 for r in healthy),
        healthy_sensor_fault_runs=sum(bool(r.sensor_problems) for r in healthy),
        healthy_problems=_named(healthy),
        quiet=tuple(_quiet_score(role, runs) for role, runs in sorted(quiet.items())),
        load_all_windows=dict(sorted(load_all.items())),
        healthy_windows=sum(len(r.loads) for r in healthy),
        healthy_judged_windows=sum(ld is not None for r in healthy for ld in r.loads),
        healthy_unjudged_runs=sum(all(ld is None for ld in r.loads) for r in healthy),
    )


def _quiet_score(role: str, runs: Sequence[RunResult]) -> QuietScore:
    return QuietScore(
        role=role,
        runs=len(runs),
        hours=sum(r.run.duration_s for r in runs) / 3600.0,
        suspension_runs=sum(r.suspension_events > 0 for r in runs),
        confirmed_runs=sum(r.confirmed_count > 0 for r in runs),
        sensor_fault_runs=sum(bool(r.sensor_problems) for r in runs),
        problems=_named(runs),
        windows=sum(len(r.loads) for r in runs),
        judged_windows=sum(ld is not None for r in runs for ld in r.loads),
    )


def _load_margin(results: Sequence[RunResult]) -> float:
    """How far the estimate stayed from the decision boundary: min over windows of
    (P(full) - 0.5) for loaded runs and (0.5 - P(full)) for empty ones (< 0: a wrong window)."""
    margins = [(p - 0.5) * (1 if r.run.load == "full" else -1) for r in results if r.run.role in ("healthy", "fault") for p in r.p_full if p is not None]
    return min(margins) if margins else math.nan


def _sensor_scores(results: Sequence[RunResult]) -> list[SensorScore]:
    by_damage: dict[str, list[RunResult]] = {}
    for r in results:
        assert r.run.damage is not None
        by_damage.setdefault(r.run.damage, []).append(r)
    out = []
    for damage, runs in by_damage.items():
        problem, channels = EXPECTED_PROBLEM[damage]
        out.append(
            SensorScore(
                damage=damage,
                runs=len(runs),
                recognised=sum(all(problem in r.sensor_problems.get(c, ()) for c in channels) for r in runs),
                flagged=sum(bool(r.sensor_problems) for r in runs),
                suspension_runs=sum(r.suspension_events > 0 for r in runs),
                problems=_named(runs),
                channels_named=sum(all(r.sensor_problems.get(c) for c in channels) for r in runs),
            )
        )
    return out
