"""Fitting the sister prior (config/sister_model.toml, judgement/sister.py) on the training fleets of
BOTH wagon models (lab/sister/plan.py), pooled; the evaluation fleets are never read here.

Per load, over the chosen features (lab/sister/study.py choose_features), each training wagon's
healthy window pairs (both windows judgeable, every feature finite: judgement/sister.py
pair_differences) give the difference d = bogie 2 minus bogie 1:

- WITHIN: the covariance of d around each wagon's own mean difference, pooled over the wagons;
- BETWEEN: the covariance of the wagons' mean differences (their tolerances, their sensors, loaded
  wagons' uneven loads, within 0.5 +/- 0.1 of the carbody on bogie 1), and the population center,
  their mean; the population's spread is WITHIN + BETWEEN;
- commissioned levels, out of sample as lab/modelfit.py fits the fused score's: each training
  wagon commissioned on its first runs (judgement/sister.py learn_baseline, the other wagons'
  within spread as its prior) and its other runs scored against it, divided by the factor the
  commissioning applies, in order; modelfit.score_levels turns the runs' sustained scores into the
  warning and alarm levels (k of n as the config confirms, the tail's once in thousands of runs);
- population levels: every wagon's runs scored against the population of the other wagons;
- THE GUARD (judgement/sister.py commissioning_guard): the distance of a commissioning's mean
  difference from the population center in standard deviations of a healthy one; its margin is
  GUARD_MARGIN times the largest distance any healthy training commissioning reached (each wagon's
  first runs, and each of its runs alone: a commissioning as short as one run), so that none is
  refused; the one-bogie guard's margin likewise from each bogie's distance from the fused
  model's population (config/fused_model.toml). lab/sister/guard.py reports the faults refused.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.daemon import tomlout
from bogiemon.detection import BogieGeometry
from bogiemon.detection.features import WindowFeatures
from bogiemon.drivers.atomic import write_text_atomically
from bogiemon.judgement.models import FusedModel, finite_or_none, whitening_of
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.sister import SISTER_MODEL_FILE, SisterPrior, learn_baseline, mean_distance_sd, pair_differences, population_distance_sd
from bogiemon.lab.modelfit import score_levels
from bogiemon.lab.sister.plan import PairRun, SisterData

GUARD_MARGIN = 1.1


@dataclass(frozen=True)
class WagonRuns:
    """One training wagon in one load: each healthy run's window-pair differences, in order, and
    each bogie's mean coupling vector per run (for the one-bogie guard)."""

    model: str
    wagon: int
    load: str
    runs: list[NDArray[np.float64]]
    couplings: list[tuple[NDArray[np.float64], NDArray[np.float64]]]  # per run: each bogie's windows' couplings (n, 10)
    commissioning_runs: int


def couplings_of(pair: PairRun, geometry: BogieGeometry, health: HealthSettings) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each bogie's judgeable windows' coupling vectors (n_k, 10) of one run."""
    from bogiemon.judgement.health import assess_window  # the judgement's own gate and sensor checks

    out = []
    for windows in pair.windows:
        rows = []
        for w in windows:
            if w.spectra is None or not assess_window(w, health, geometry=geometry).judgeable:
                continue
            x = finite_or_none(WindowFeatures(w.spectra, geometry).coupling)
            if x is not None:
                rows.append(x)
        out.append(np.array(rows) if rows else np.empty((0, 10)))
    return out[0], out[1]


def training_wagons(datas: Mapping[str, SisterData], names: Sequence[str], health: HealthSettings) -> list[WagonRuns]:
    out = []
    for model, data in datas.items():
        groups: dict[tuple[int, str], list[PairRun]] = {}
        for pair in data.select(role="train-healthy"):
            groups.setdefault((pair.run.wagon, pair.run.load), []).append(pair)
        for (wagon, load), pairs in sorted(groups.items()):
            pairs.sort(key=lambda p: p.run.number)
            runs = [pair_differences(p.windows[0], p.windows[1], data.geometry, names, health) for p in pairs]
            couplings = [couplings_of(p, data.geometry, health) for p in pairs]
            out.append(WagonRuns(model, wagon, load, runs, couplings, data.plan.commissioning_runs))
    return out


def _score(rows: NDArray[np.float64], center: NDArray[np.float64], whitening: NDArray[np.float64]) -> NDArray[np.float64]:
    z = (rows - center) @ whitening.T
    return np.einsum("ij,ij->i", z, z)


def fit_load(wagons: Sequence[WagonRuns], names: Sequence[str], fused: FusedModel, confirm_k: int, confirm_n: int, window_s: float, hop_s: float) -> dict[str, Any]:
    """One load's section of the sister model (module docstring)."""
    p = len(names)
    means = [np.concatenate(w.runs).mean(axis=0) for w in wagons]
    residuals = [np.concatenate(w.runs) - m for w, m in zip(wagons, means, strict=True)]
    within = np.cov(np.concatenate(residuals).T).reshape(p, p)
    between = np.cov(np.array(means).T).reshape(p, p)
    center = np.array(means).mean(axis=0)
    overlap = window_s / hop_s
    # The provisional prior of a commissioning: levels of 1 (the scores below are in those units).
    unit = SisterPrior(tuple(names), within, 1.0, 1.0, 1.0, center, within + between, 1.0, 1.0, between, np.inf, window_s=window_s, hop_s=hop_s)
    medians = []
    for w in wagons:
        cal = np.concatenate(w.runs[: w.commissioning_runs])
        b = learn_baseline(cal, unit)
        medians.append(float(np.median(_score(cal, b.center, b.whitening))))
    median = float(np.median(medians))
    scored = []
    for i, w in enumerate(wagons):
        others = np.concatenate([r for j, r in enumerate(residuals) if j != i])
        prior = replace(unit, within_covariance=np.cov(others.T).reshape(p, p), calibration_median_score=median)
        b = learn_baseline(np.concatenate(w.runs[: w.commissioning_runs]), prior)
        scored += [_score(r, b.center, b.whitening) / b.alarm for r in w.runs[w.commissioning_runs :] if len(r)]
    commissioned = score_levels(scored, confirm_k, confirm_n)
    pop_scored = []
    for i, w in enumerate(wagons):
        others_means = np.array([m for j, m in enumerate(means) if j != i])
        others_within = np.cov(np.concatenate([r for j, r in enumerate(residuals) if j != i]).T).reshape(p, p)
        cov = others_within + np.cov(others_means.T).reshape(p, p)
        pop_scored += [_score(r, others_means.mean(axis=0), whitening_of(cov)) for r in w.runs if len(r)]
    population = score_levels(pop_scored, confirm_k, confirm_n)
    # The guards' healthy distances: every commissioning, and every run alone.
    guard, one_bogie = [], []
    for w in wagons:
        stretches = [np.concatenate(w.runs[: w.commissioning_runs])] + [r for r in w.runs if len(r)]
        guard += [mean_distance_sd(s, center, between, within, overlap) for s in stretches]
        for k in range(2):
            stretches_k = [np.concatenate([c[k] for c in w.couplings[: w.commissioning_runs]])] + [c[k] for c in w.couplings if len(c[k])]
            one_bogie += [population_distance_sd(s, fused.population_center, fused.population_covariance) for s in stretches_k]
    return {
        "features": list(names),
        "window_s": window_s,
        "hop_s": hop_s,
        "within_covariance": within.tolist(),
        "warning": commissioned.warning,
        "alarm": commissioned.alarm,
        "calibration_median_score": median,
        "population_center": [float(v) for v in center],
        "population_covariance": (within + between).tolist(),
        "population_warning": population.warning,
        "population_alarm": population.alarm,
        "between_covariance": between.tolist(),
        "guard_margin_sd": GUARD_MARGIN * max(guard),
        "population_guard_margin_sd": GUARD_MARGIN * max(one_bogie),
        "evidence": {
            "wagons": len(wagons),
            "wagons_per_model": {m: sum(w.model == m for w in wagons) for m in sorted({w.model for w in wagons})},
            "window_pairs": int(sum(len(r) for w in wagons for r in w.runs)),
            "commissioned_scored_runs": commissioned.runs,
            "commissioned_largest_sustained": commissioned.largest_sustained,
            "commissioned_tail_level": commissioned.tail,
            "population_scored_runs": population.runs,
            "population_largest_sustained": population.largest_sustained,
            "population_tail_level": population.tail,
            "guard_healthy_stretches": len(guard),
            "guard_largest_healthy_sd": max(guard),
            "population_guard_largest_healthy_sd": max(one_bogie),
        },
    }


def fit_sister_model(
    datas: Mapping[str, SisterData], chosen: Mapping[str, Sequence[str]], health: HealthSettings, fused: Mapping[str, FusedModel], confirm_k: int, confirm_n: int
) -> dict[str, Any]:
    """The whole model: a section per load with features chosen (fit_load), from both models' training wagons."""
    first = next(iter(datas.values()))
    out: dict[str, Any] = {}
    for load, names in chosen.items():
        if not names:
            continue
        mine = [w for w in training_wagons(datas, names, health) if w.load == load]
        if mine:
            out[load] = fit_load(mine, names, fused[load], confirm_k, confirm_n, first.settings.window_s, first.settings.hop_s)
    return out


def write_sister_model(model: Mapping[str, Any], path: str | Path, command: str, description: str) -> Path:
    """config/sister_model.toml with its provenance in the header and in `provenance`."""
    stamp = f"{datetime.now(UTC):%Y-%m-%d}"
    header = [
        "# The sister evidence's prior: the healthy difference between a wagon's two bogies, per load (judgement/sister.py).",
        f"# Fitted by `{command}` (lab/sister/fit.py states every rule) on {stamp},",
        *(f"# {line}" for line in description.splitlines()),
        "# Data, not code: regenerate rather than edit by hand.",
    ]
    body = {"provenance": f"{stamp}: {description.splitlines()[0] if description else ''}", **model}
    path = Path(path)
    write_text_atomically(path, "\n".join(header) + "\n\n" + tomlout.dumps(body))
    return path


SISTER_MODEL_PATH = Path(__file__).resolve().parents[2] / "config" / SISTER_MODEL_FILE  # the shipped one
