"""The transfer evaluation's plans, its simulated data and its four judgements (issue 16).

    plans = transfer_plans("default")                   # the same plan on wagon models A and B
    data = load_or_simulate_models(plans, config, "build/transfer.pkl")
    judgements = judge_transfer(data, config, {"a": dir_a, "b": dir_b})

Each model's priors (fitted into a folder by lab/modelfit.py) judged by the daemon's default
method on each model's evaluation fleet; lab/robust/transfer.py runs it all, and
lab/robust/transfer_report.py counts the targets and writes the report.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import Corner
from bogiemon.lab.robust.evaluate import daemon_methods, read_cache, reuse, write_cache
from bogiemon.lab.robust.fleet import EvaluationData, EvaluationPlan, simulate_plan
from bogiemon.lab.robust.judge import DaemonMethod, RunResult, judge_runs, with_overrides
from bogiemon.lab.robust.judge import _result as run_result
from bogiemon.lab.robust.report import FULL_SPRINGS, TARE_OUTER
from bogiemon.lab.robust.score import QUIET_ROLES, MethodScore, score_method

Progress = Callable[[float], None]

MODELS = ("a", "b")
COMMISSIONING_RUNS = 10  # per load: what the keeper's commissioning records, 10 min each
FAULT_HORIZON_S = 600.0  # "confirmed within 10 min of running" with a broken spring
TREND_HORIZON_S = 3600.0  # "within an hour of running" for the smaller faults
NOISY = "hiss a2"  # the noisy sensor of the targets (lab/robust/fleet.py SENSOR_DAMAGE)
NOISY_CHANNEL = "a2"

BROKEN_FULL = tuple((k, 0.0) for k in FULL_SPRINGS)
BROKEN_TARE_OUTER = tuple((k, 0.0) for k in TARE_OUTER)
SPRINGS_50 = tuple((k, 0.5) for k in FULL_SPRINGS)
SPRINGS_200 = tuple((k, 2.0) for k in FULL_SPRINGS)
FRICTION_50 = (("type_b.full", 0.5),)
FRICTION_150 = (("type_b.full", 1.5),)


# --------------------------------------------------------------------------------------------
# The plans


def transfer_plan(model: str, size: str = "default") -> EvaluationPlan:
    """The transfer's plan on one wagon model; `size` "quick" (a test's), "default" or "full".

    Only what the targets need: single runs of the broken springs (a lead-in, then 10 min with the
    fault), trend sequences of the smaller faults (an hour of running with the fault over several
    runs), stops, standing and the noisy sensor; the training fleet runs every fault cell (the
    load model learns from faulty windows too, and the diagnosis's bands were chosen on them).
    """
    common: dict[str, Any] = dict(
        model=model, lead_in_s=150.0, fault_s=FAULT_HORIZON_S, fault_cases=BROKEN_FULL + BROKEN_TARE_OUTER,
        trend_cases=SPRINGS_50 + SPRINGS_200 + FRICTION_50 + FRICTION_150, sensor_damages=(NOISY,),
        # As a keeper commissions (issue 26): ten runs per load of what the wagon happened to run.
        calibration_runs=COMMISSIONING_RUNS, designed_commissioning=False,
    )  # fmt: skip
    sizes: dict[str, dict[str, Any]] = {
        # 100 h of healthy test running per model across both loads: the figure.
        "full": dict(
            n_wagons=10, n_training_wagons=8, calibration_s=600.0, healthy_runs=30, healthy_s=600.0,
            fault_runs=3, trend_runs=6, trend_run_s=630.0, training_healthy_runs=30, training_healthy_s=600.0,
            training_fault_runs=2, training_fault_s=300.0, sensor_runs=10, sensor_s=600.0, stop_runs=2, stop_s=600.0,
            standing_runs=1, standing_s=600.0,
        ),
        # What runs in about 35 min on the project's 2-core machine (the full plan takes about 85):
        # 30 h of healthy test running per model, the trend sequences on one diagonal (a corner with
        # a sensor and the one without), 80 min of commissioning per load.
        "default": dict(
            n_wagons=6, n_training_wagons=5, calibration_s=600.0, healthy_runs=15, healthy_s=600.0,
            fault_runs=1, trend_runs=5, trend_run_s=750.0, training_healthy_runs=18, training_healthy_s=600.0,
            training_fault_runs=1, training_fault_s=300.0, sensor_runs=5, sensor_s=600.0, stop_runs=1, stop_s=600.0,
            standing_runs=1, standing_s=300.0, trend_corners=(Corner.LEADING_LEFT, Corner.TRAILING_RIGHT),
        ),
        # A test's: one wagon, short runs, the two corners of one diagonal (the trend on one), few training cells.
        "quick": dict(
            n_wagons=1, n_training_wagons=2, calibration_runs=3, designed_commissioning=True, calibration_s=300.0, healthy_runs=2, healthy_s=300.0,
            fault_runs=1, fault_s=300.0, fault_cases=(("type_a.full.rear_outer", 0.0), ("type_a.tare.rear_outer", 0.0)),
            trend_runs=2, trend_run_s=300.0, trend_cases=FRICTION_50, training_healthy_runs=5, training_healthy_s=300.0,
            training_fault_runs=1, training_fault_s=300.0,
            training_fault_cases=(("type_a.full.rear_outer", 0.0), ("type_a.tare.rear_outer", 0.0), ("type_b.full", 0.5)),
            sensor_runs=1, sensor_s=300.0, stop_runs=1, stop_s=400.0, standing_runs=1, standing_s=200.0,
            corners=(Corner.LEADING_LEFT, Corner.TRAILING_RIGHT), trend_corners=(Corner.LEADING_LEFT,),
        ),
    }  # fmt: skip
    if size not in sizes:
        raise ValueError(f"unknown transfer plan size '{size}'")
    return EvaluationPlan(name=f"transfer-{size}", **{**common, **sizes[size]})


def transfer_plans(size: str = "default") -> dict[str, EvaluationPlan]:
    return {m: transfer_plan(m, size) for m in MODELS}


def healthy_hours(plan: EvaluationPlan) -> float:
    return sum(r.duration_s for r in plan.runs() if r.role == "healthy") / 3600.0


# Simulated seconds of model B per second of model A's (its kernel is slower); only weighs the
# progress fraction.
_COST = {"a": 1.0, "b": 2.7}


def load_or_simulate_models(
    plans: Mapping[str, EvaluationPlan], config: BogiemonConfig, data_file: str | Path | None, progress: Progress | None = None
) -> dict[str, EvaluationData]:
    """Each model's simulated windows: from data_file where it holds that model's plan at these
    settings (its runs that the plan shares reused otherwise; a file of `bogiemon evaluate --data`
    gives model A's), the rest simulated; both written back to the file when one is named."""
    path = Path(data_file) if data_file else None
    cached = read_cache(path) if path is not None and path.exists() else None
    by_model = cached if isinstance(cached, dict) else {} if cached is None else {cached.plan.model: cached}
    weights = {m: _COST.get(m, 1.0) * sum(r.duration_s for r in p.runs()) for m, p in plans.items()}
    total = sum(weights.values()) or 1.0
    out: dict[str, EvaluationData] = {}
    done, simulated = 0.0, False
    for model, plan in plans.items():
        found = reuse(by_model.get(model), plan, config)
        if isinstance(found, EvaluationData):
            out[model] = found
        else:
            base, share = done / total, weights[model] / total
            part = None if progress is None else (lambda f, b=base, s=share: progress(b + s * f))
            out[model] = simulate_plan(plan, config.processing_settings(), config.bogie_geometry(), part, have=found)
            simulated = True
        done += weights[model]
    if path is not None and simulated:
        write_cache(path, out)
    return out


# --------------------------------------------------------------------------------------------
# Judging


def judge_quiet(data: EvaluationData, method: DaemonMethod) -> list[RunResult]:
    """The stops and standing runs, each alone on its commissioned wagon (judge_runs judges the
    healthy, fault, sensor and trend runs)."""
    out = []
    for w in range(len(data.fleet)):
        runs = data.select(role=set(QUIET_ROLES), wagon=w)
        if not runs:
            continue
        calibration: dict[str, list[Any]] = {}
        for r in data.select(role="calibration", wagon=w):
            calibration.setdefault(r.run.load, []).append(r.windows)
        commissioned = method.commission(calibration)
        for r in runs:
            (judged,) = commissioned.judge([r.windows], r.run.load)
            out.append(run_result(r, judged))
    return out


@dataclass(frozen=True)
class Judgement:
    """One of the four: the priors fitted on one model's training fleet, judged on a model's evaluation fleet."""

    priors: str
    evaluated: str
    score: MethodScore

    @property
    def same_model(self) -> bool:
        return self.priors == self.evaluated

    @property
    def label(self) -> str:
        return f"{self.priors.upper()} priors on {self.evaluated.upper()}"


def judge_transfer(
    data: Mapping[str, EvaluationData], config: BogiemonConfig, models_dirs: Mapping[str, str | Path], progress: Progress | None = None
) -> list[Judgement]:
    """The daemon's default method with each model's priors on each model's evaluation fleet,
    ordered by evaluation model: same model first, then the other's priors."""
    pairs = [(p, e) for e in data for p in sorted(models_dirs, key=lambda m: m != e)]
    out = []
    for i, (priors, evaluated) in enumerate(pairs):
        fleet = data[evaluated]
        method = daemon_methods(fleet, with_overrides(config, {"models_dir": str(models_dirs[priors])}), paper=False)[-1]
        part = None if progress is None else (lambda f, i=i: progress((i + f) / len(pairs)))
        judged = judge_runs(fleet, method, part)
        quiet = judge_quiet(fleet, method)
        name = f"{method.name}, priors of model {priors.upper()}"
        out.append(Judgement(priors, evaluated, score_method(fleet, name, method.description, [*judged.runs, *quiet], judged.sequences, FAULT_HORIZON_S)))
    return out
