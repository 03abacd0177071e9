"""Judging the evaluation's runs with the daemon's own methods: each a config run through the
daemon's WindowJudge (sensor health, gating, load state, decision, diagnosis) window by window,
commissioned per wagon with `calibrate`'s own code where the method calibrates; and what each run
and trend sequence showed."""

from __future__ import annotations

import copy
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

from bogiemon.daemon.calibrate import calibrate_windows, combine_loads, fragment
from bogiemon.daemon.config import BogiemonConfig, validate_config
from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.judgement.events import ConfirmedDetails, Event, EventKind, SensorFaultDetails, Trigger
from bogiemon.judgement.verdict import MonitorSettings, WindowJudge
from bogiemon.judgement.vocabulary import LoadSetting
from bogiemon.detection import WindowIndicators
from bogiemon.lab.robust.fleet import HEALTHY, EvaluationData, RunSpec, RunWindows

Progress = Callable[[float], None]


def with_fragment(config: BogiemonConfig, text: str) -> BogiemonConfig:
    """The config with a calibration fragment included (a named load state replaces its set)."""
    data = config.model_dump(mode="json")
    parsed = tomllib.loads(text)
    frag = parsed["decision"]
    for section in ("thresholds", "fused", "load_states"):
        for load, per in frag.get(section, {}).items():
            data["decision"][section][load] = per
    if "load_discriminant" in frag:
        data["decision"]["load_discriminant"] = frag["load_discriminant"]
    data["health"].update(parsed.get("health", {}))  # the structure learned at commissioning
    return validate_config(data, "calibrated config")


def with_overrides(config: BogiemonConfig, decision: Mapping[str, Any]) -> BogiemonConfig:
    data = config.model_dump(mode="json")
    data["decision"].update(copy.deepcopy(dict(decision)))
    return validate_config(data, "method config")


@dataclass(frozen=True)
class Commissioned:
    """A method set up for one wagon (after its commissioning, if it has one)."""

    settings: MonitorSettings
    true_load: bool  # judge each run in its true load state (the paper's method assumes it known)

    def judge(self, runs: Sequence[Sequence[WindowIndicators]], true_load: str) -> list[JudgedRun]:
        """Judge consecutive runs of the wagon, the decision state carried from one to the next
        (the windows restart at each run, as at a stop); one JudgedRun per run, times (the windows'
        and so the events') from its start."""
        settings = replace(self.settings, load=LoadSetting(true_load), load_model=None) if self.true_load else self.settings
        judge = WindowJudge(settings)  # one wagon running on: its decision state carries over
        out = []
        for windows in runs:
            events: list[Event] = []
            loads, ratios, p_full = [], [], []
            for w in windows:
                judged = judge.judge(w)
                loads.append(judged.load)
                ratios.append(None if judged.judgement is None else judged.judgement.alarm_ratio)
                p_full.append(judged.p_full)
                events += judged.events
            out.append(JudgedRun(tuple(events), tuple(loads), tuple(ratios), tuple(p_full)))
        return out


@dataclass(frozen=True)
class DaemonMethod:
    """A detection method as the daemon runs it: a config, calibrated per wagon or not."""

    name: str
    description: str
    config: BogiemonConfig
    calibrated: bool
    true_load: bool = False

    def commission(self, calibration: Mapping[str, Sequence[Sequence[WindowIndicators]]]) -> Commissioned:
        """Set up for one wagon from its calibration runs' windows, per load state (each load from
        its own recordings, as the README's commissioning asks)."""
        config = self.config
        if self.calibrated and calibration:
            parts = []
            for load, runs in sorted(calibration.items()):
                windows = [w for run in runs for w in run]
                numbers = [i for i, run in enumerate(runs) for _ in run]
                parts.append(calibrate_windows(windows, config, load, runs=numbers))
            config = with_fragment(config, fragment(combine_loads(parts, config)))
        return Commissioned(config.monitor_settings(), self.true_load)


@dataclass(frozen=True)
class JudgedRun:
    events: tuple[Event, ...]  # each at the end of the window that caused it, s from the run's start
    loads: tuple[str | None, ...]  # per window: the load state it was judged in (None: not judged)
    # Per window: the judged value as a fraction of its alarm level (>= 1: alarm); None: not judged.
    ratios: tuple[float | None, ...] = ()
    p_full: tuple[float | None, ...] = ()  # per window: the estimated probability of full load (None: not estimated)


@dataclass(frozen=True)
class RunResult:
    """What one method made of one test run."""

    run: RunSpec
    track: str
    reversed: bool
    confirmed_s: float | None  # the first CONFIRMED after the onset (fault runs) or anywhere (others), s from the run's start
    confirmed_before_onset: bool  # a fault run's lead-in confirmed (a false alarm)
    diagnosis: Diagnosis | None  # of that CONFIRMED
    trigger: Trigger | None  # of that CONFIRMED
    sensor_problems: Mapping[str, tuple[str, ...]]  # every problem any SENSOR_FAULT named, per channel
    suspension_events: int  # SUSPECTED and CONFIRMED events
    confirmed_count: int
    suspected_count: int
    loads: tuple[str | None, ...]
    ratios: tuple[float | None, ...]  # per window, as JudgedRun
    p_full: tuple[float | None, ...]  # per window, as JudgedRun
    window_ends_s: tuple[float, ...]  # per window, s from the run's start


@dataclass(frozen=True)
class SequenceResult:
    """What one method made of one trend sequence: a fault that appears and stays while the wagon
    runs on. Times are of running with the fault, across the sequence's runs."""

    first: RunSpec
    runs: int
    fault_running_s: float  # how long the sequence ran with the fault
    confirmed_after_s: float | None  # running time from the onset to the first CONFIRMED after it
    confirmed_before_onset: bool
    trigger: Trigger | None
    diagnosis: Diagnosis | None
    judged_after_onset: int = 0  # windows judged that end after the onset
    events_after_onset: int = 0  # events of any kind after the onset (0 with none judged: silent)


def sequences(data: EvaluationData, wagon: int) -> list[list[RunWindows]]:
    """The wagon's test runs as the evaluation judges them: its healthy runs of each load in order
    as one stretch of running, each trend sequence in order, each fault and sensor run alone."""
    groups: dict[tuple[Any, ...], list[RunWindows]] = {}
    for r in data.runs:
        spec = r.run
        if spec.wagon != wagon or spec.role not in ("healthy", "fault", "sensor", "trend"):
            continue
        if spec.role == "healthy":
            key: tuple[Any, ...] = ("healthy", spec.load)
        elif spec.role == "trend":
            key = ("trend", spec.load, spec.key, spec.severity, spec.corner)
        else:
            key = ("alone", spec.name)
        groups.setdefault(key, []).append(r)
    return [sorted(g, key=lambda r: r.run.number) for g in groups.values()]


@dataclass(frozen=True)
class Judged:
    runs: list[RunResult]  # the healthy, fault and sensor runs
    sequences: list[SequenceResult]  # the trend sequences


def judge_runs(data: EvaluationData, method: DaemonMethod, progress: Progress | None = None) -> Judged:
    """Commission `method` on each wagon's calibration runs, then judge every test run of it."""
    runs: list[RunResult] = []
    seqs: list[SequenceResult] = []
    total = sum(r.run.role in ("healthy", "fault", "sensor", "trend") for r in data.runs) or 1
    done = 0
    for w in range(len(data.fleet)):
        calibration: dict[str, list[tuple[WindowIndicators, ...]]] = {}
        for r in data.select(role="calibration", wagon=w):
            calibration.setdefault(r.run.load, []).append(r.windows)
        commissioned = method.commission(calibration)
        for group in sequences(data, w):
            judged = commissioned.judge([r.windows for r in group], group[0].run.load)
            if group[0].run.role == "trend":
                seqs.append(_sequence_result(group, judged))
            else:
                runs += [_result(r, j) for r, j in zip(group, judged, strict=True)]
            done += len(group)
            if progress is not None:
                progress(done / total)
    return Judged(runs, seqs)


def _sequence_result(group: Sequence[RunWindows], judged: Sequence[JudgedRun]) -> SequenceResult:
    onset = group[0].run.onset_s
    offset = 0.0  # running time at the start of each run, from the sequence's start
    first_after: tuple[float, ConfirmedDetails] | None = None
    before = False
    judged_after = events_after = 0
    for r, j in zip(group, judged, strict=True):
        judged_after += sum(ld is not None and offset + w.end_s > onset for ld, w in zip(j.loads, r.windows, strict=True))
        events_after += sum(offset + e.time_s > onset for e in j.events)
        for e in j.events:
            if not isinstance(e.details, ConfirmedDetails):
                continue
            t = offset + e.time_s
            if t <= onset:
                before = True
            elif first_after is None:
                first_after = (t - onset, e.details)
        offset += r.run.duration_s
    return SequenceResult(
        first=group[0].run,
        runs=len(group),
        fault_running_s=offset - onset,
        confirmed_after_s=first_after[0] if first_after else None,
        confirmed_before_onset=before,
        trigger=first_after[1].trigger if first_after else None,
        diagnosis=first_after[1].diagnosis if first_after else None,
        judged_after_onset=judged_after,
        events_after_onset=events_after,
    )


def _result(r: RunWindows, judged: JudgedRun) -> RunResult:
    onset = r.run.onset_s if r.run.key != HEALTHY else 0.0
    confirmed = [(e.time_s, e.details) for e in judged.events if isinstance(e.details, ConfirmedDetails)]
    after = [(t, d) for t, d in confirmed if t > onset]
    problems: dict[str, set[str]] = {}
    for e in judged.events:
        if isinstance(e.details, SensorFaultDetails):
            for channel, found in e.details.problems.items():
                problems.setdefault(channel, set()).update(found)
    return RunResult(
        run=r.run,
        track=r.conditions.track,
        reversed=r.conditions.reversed,
        confirmed_s=after[0][0] if after else None,
        confirmed_before_onset=any(t <= onset for t, _ in confirmed) if r.run.key != HEALTHY else False,
        diagnosis=after[0][1].diagnosis if after else None,
        trigger=after[0][1].trigger if after else None,
        sensor_problems={c: tuple(sorted(p)) for c, p in problems.items()},
        suspension_events=sum(e.kind in (EventKind.SUSPECTED, EventKind.CONFIRMED) for e in judged.events),
        confirmed_count=len(confirmed),
        suspected_count=sum(e.kind is EventKind.SUSPECTED for e in judged.events),
        loads=judged.loads,
        ratios=judged.ratios,
        p_full=judged.p_full,
        window_ends_s=tuple(w.end_s for w in r.windows),
    )
