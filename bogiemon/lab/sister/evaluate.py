"""Judging the held-out evaluation wagons of both models with the wagon judge (judgement/wagon.py),
with and without the sister evidence, commissioned and not (issue 33, part 3).

Each bogie is judged by the daemon's default method (the shipped config: the fused score, load
estimated) through judgement/wagon.py's WagonJudge, as a gateway on a wagon would:
- COMMISSIONED: each bogie commissioned per load by `calibrate`'s own code on its calibration
  runs (lab/robust/judge.py DaemonMethod.commission), the sister baseline learned from the same
  runs' window pairs (judgement/sister.py learn_baseline);
- UNCOMMISSIONED: the shipped population baselines and, for the sister, the prior
  (config/sister_model.toml, or the model given).
Without the sister evidence the same judges run with no sister baselines: each bogie alone.
A wagon's healthy runs of one load are judged in order as one stretch of running (the decision
state carried over), each fault run alone after a healthy lead-in, each run with a damaged
sensor alone. The uneven wagons are judged
as commissioned at 60/40 (their uneven calibration runs) and, "loading changed", commissioned on
their even runs and then running 60/40.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import WindowIndicators
from bogiemon.judgement.events import EventDetails
from bogiemon.judgement.sister import SisterBaseline, SisterModel, learn_baseline, pair_differences
from bogiemon.judgement.verdict import MonitorSettings, Outcome
from bogiemon.judgement.wagon import WagonJudge, WagonSettings
from bogiemon.lab.robust.judge import DaemonMethod, with_overrides
from bogiemon.lab.sister.plan import PairRun, SisterData

Progress = Callable[[float], None]
MODES = ("commissioned", "uncommissioned")


@dataclass(frozen=True)
class JudgedEvent:
    kind: str
    time_s: float  # the end of its window, s from the run's start
    bogie: str | None
    details: EventDetails


@dataclass(frozen=True)
class JudgedRun:
    """What one configuration made of one run of a wagon."""

    run: PairRun
    commissioning: str  # "even": on the wagon's calibration runs; "uneven": on its 60/40 ones; "none"
    events: tuple[JudgedEvent, ...]
    windows: tuple[int, int]  # per bogie
    judged: tuple[int, int]  # per bogie
    sister_pairs: int  # window pairs that gave sister evidence

    def confirmed_after(self, onset_s: float) -> JudgedEvent | None:
        return next((e for e in self.events if e.kind == "CONFIRMED" and e.time_s > onset_s), None)


@dataclass(frozen=True)
class Configuration:
    model: str
    mode: str  # MODES
    sister: bool
    runs: list[JudgedRun] = field(default_factory=list)

    @property
    def label(self) -> str:
        return f"model {self.model.upper()}, {self.mode}, {'with' if self.sister else 'without'} the sister"


def _split(runs: Sequence[PairRun]) -> tuple[dict[str, list[tuple[WindowIndicators, ...]]], dict[str, list[tuple[WindowIndicators, ...]]]]:
    """Each bogie's calibration windows per load, run by run."""
    out: tuple[dict[str, list[tuple[WindowIndicators, ...]]], dict[str, list[tuple[WindowIndicators, ...]]]] = ({}, {})
    for pair in sorted(runs, key=lambda p: p.run.number):
        for k in range(2):
            out[k].setdefault(pair.run.load, []).append(pair.windows[k])
    return out


def commissioned(config: BogiemonConfig, calibration: Sequence[PairRun], prior: SisterModel) -> tuple[tuple[MonitorSettings, MonitorSettings], dict[str, SisterBaseline]]:
    """Each bogie's settings commissioned on its calibration runs, and the sister baselines they teach."""
    method = DaemonMethod("fused, calibrated", "the daemon's default", with_overrides(config, {"method": "fused"}), calibrated=True)
    per_bogie = _split(calibration)
    settings = (method.commission(per_bogie[0]).settings, method.commission(per_bogie[1]).settings)
    baselines = {}
    geometry, health = config.bogie_geometry(), config.health_settings()
    for load, load_prior in prior.loads.items():
        pairs = [p for p in calibration if p.run.load == load]
        rows = [pair_differences(p.windows[0], p.windows[1], geometry, load_prior.features, health) for p in pairs]
        rows = [r for r in rows if len(r)]
        if rows:
            baselines[load] = learn_baseline(np.concatenate(rows), load_prior)
    return settings, baselines


def judge_runs(settings: WagonSettings, runs: Sequence[PairRun], commissioning: str) -> list[JudgedRun]:
    """Consecutive runs of one wagon judged by one WagonJudge (the state carried from run to run)."""
    judge = WagonJudge(settings)
    out = []
    for pair in runs:
        events: list[JudgedEvent] = []
        windows, judged, sister = [0, 0], [0, 0], 0
        by_start = {round(w.start_s, 6): w for w in pair.windows[1]}
        for w1 in pair.windows[0]:
            w2 = by_start.get(round(w1.start_s, 6))
            if w2 is None:
                continue
            verdict = judge.judge(w1, w2)
            sister += verdict.sister is not None
            for k, v in enumerate(verdict.verdicts):
                windows[k] += 1
                judged[k] += v.outcome is Outcome.JUDGED
            events += [JudgedEvent(e.kind.value, w1.end_s, e.bogie, e.details) for e in verdict.events]
        out.append(JudgedRun(pair, commissioning, tuple(events), (windows[0], windows[1]), (judged[0], judged[1]), sister))
    return out


def _in_order(runs: Sequence[PairRun]) -> list[PairRun]:
    return sorted(runs, key=lambda p: p.run.number)


def evaluate_model(data: SisterData, config: BogiemonConfig, prior: SisterModel, progress: Progress | None = None) -> list[Configuration]:
    """The four configurations (commissioned or not, with or without the sister) on one model's
    evaluation fleet (module docstring)."""
    configurations = [Configuration(data.plan.model, mode, sister) for mode in MODES for sister in (False, True)]
    population = config.monitor_settings()
    for w in range(data.plan.n_wagons):
        setups = {
            "even": commissioned(config, data.select(role="calibration", wagon=w), prior),
            "none": ((population, population), {load: p.baseline() for load, p in prior.loads.items()}),
        }
        if data.select(role="uneven-calibration", wagon=w):
            setups["uneven"] = commissioned(config, data.select(role="uneven-calibration", wagon=w), prior)
        for c in configurations:
            # (commissioning, the runs judged after it): stretches of healthy running, fault runs alone.
            plan: list[tuple[str, list[list[PairRun]]]] = []
            for role in ("healthy", "uneven-healthy"):
                stretches = [_in_order(data.select(role=role, wagon=w, load=load)) for load in data.plan.loads]
                plan.append(("even" if c.mode == "commissioned" else "none", [s for s in stretches if s]))
            alone = data.select(role="fault", wagon=w) + data.select(role="sensor", wagon=w)
            plan.append(("even" if c.mode == "commissioned" else "none", [[r] for r in alone]))
            uneven_faults = [[r] for r in data.select(role="uneven-fault", wagon=w)]
            if c.mode == "commissioned" and "uneven" in setups:
                stretches = [_in_order(data.select(role="uneven-healthy", wagon=w, load=load)) for load in data.plan.loads]
                plan += [("uneven", [s for s in stretches if s] + uneven_faults)]
            elif c.mode == "uncommissioned":
                plan += [("none", uneven_faults)]
            for setup, groups in plan:
                bogies, baselines = setups[setup]
                settings = WagonSettings(bogies, baselines if c.sister else {})
                for group in groups:
                    c.runs.extend(judge_runs(settings, group, setup))
        if progress is not None:
            progress((w + 1) / data.plan.n_wagons)
    return configurations
