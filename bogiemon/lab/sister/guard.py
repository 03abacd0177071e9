"""The commissioning guard's numbers (issue 33, part 4): how far a commissioning that holds a fault
stands from the prior, against healthy commissionings, on both models' fleets.

A healthy commissioning: a wagon's commissioning runs (training wagons: their first runs;
evaluation wagons: their calibration runs), and each of its healthy runs alone (a commissioning
as short as one run). A faulty one: a fault run's windows once the fault is on it (training:
every fault case of the paper's tables at two corners of either bogie, 10 minutes with the fault
from the start; evaluation: the broken springs at every corner and the other cases at one
diagonal, the 10 minutes after the lead-in). Each is measured as the calibrate command would
(judgement/sister.py commissioning_guard: its judgeable window pairs' mean difference against the
prior; one_bogie_guard: each bogie's mean couplings against the fused model's population).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from bogiemon.judgement.models import FusedModel
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.sister import SisterModel, commissioning_guard, pair_differences, population_distance_sd
from bogiemon.lab.sister.fit import couplings_of
from bogiemon.lab.sister.plan import PairRun, SisterData
from bogiemon.lab.sister.study import fault_group


@dataclass(frozen=True)
class Stretch:
    """One commissioning the guard judged: which fleet, wagon, load, whether it held a fault (and
    which, on which bogie), its distance from the prior (sister, and each bogie's own)."""

    model: str
    fleet: str  # "training" or "evaluation"
    wagon: int
    load: str
    group: str | None  # fault_group, or None: healthy
    bogie: int  # the faulty bogie (0: healthy)
    windows: int
    sister_sd: float
    sister_refused: bool
    named: int  # the bogie the message names
    own_sd: tuple[float, float]  # each bogie's distance from the fused population
    own_refused: tuple[bool, bool]


def _after_onset(pair: PairRun) -> PairRun:
    """The run's windows that lie wholly after its fault's onset."""
    onset = pair.run.onset_s
    keep = tuple(tuple(w for w in windows if w.start_s >= onset) for windows in pair.windows)
    return PairRun(pair.run, pair.conditions, (keep[0], keep[1]))


def measure(
    data: SisterData, fleet: str, stretches: Sequence[Sequence[PairRun]], prior: SisterModel, fused: Mapping[str, FusedModel], health: HealthSettings
) -> list[Stretch]:
    out = []
    for runs in stretches:
        first = runs[0].run
        load_prior = prior.loads.get(first.load)
        if load_prior is None:
            continue
        rows = [pair_differences(p.windows[0], p.windows[1], data.geometry, load_prior.features, health) for p in runs]
        d = np.concatenate([r for r in rows if len(r)]) if any(len(r) for r in rows) else np.empty((0, len(load_prior.features)))
        if len(d) < 2:
            continue
        couplings = [couplings_of(p, data.geometry, health) for p in runs]
        own = []
        for k in range(2):
            rows_k = np.concatenate([c[k] for c in couplings])
            model = fused[first.load]
            own.append(population_distance_sd(rows_k, model.population_center, model.population_covariance) if len(rows_k) else np.nan)
        verdict = commissioning_guard(d, load_prior, (own[0], own[1]))
        margin = load_prior.population_guard_margin_sd
        out.append(
            Stretch(
                data.plan.model, fleet, first.wagon, first.load, None if first.bogie == 0 else fault_group(first.key, first.severity), first.bogie,
                len(d), verdict.distance_sd, verdict.refused, verdict.bogie or 0, (own[0], own[1]), (own[0] > margin, own[1] > margin),
            )  # fmt: skip
        )
    return out


def guard_stretches(data: SisterData) -> dict[str, list[list[PairRun]]]:
    """The healthy and faulty commissionings of one model's fleets (module docstring), by fleet."""
    out: dict[str, list[list[PairRun]]] = {"training": [], "evaluation": []}
    groups: dict[tuple[int, str], list[PairRun]] = {}
    for pair in data.select(role="train-healthy"):
        groups.setdefault((pair.run.wagon, pair.run.load), []).append(pair)
    for runs in groups.values():
        runs.sort(key=lambda p: p.run.number)
        out["training"] += [runs[: data.plan.commissioning_runs]] + [[r] for r in runs]
    out["training"] += [[p] for p in data.select(role="train-fault")]
    groups = {}
    for pair in data.select(role={"calibration", "healthy"}):
        groups.setdefault((pair.run.wagon, pair.run.load), []).append(pair)
    for runs in groups.values():
        calibration = sorted((p for p in runs if p.run.role == "calibration"), key=lambda p: p.run.number)
        out["evaluation"] += [calibration] + [[r] for r in runs]
    out["evaluation"] += [[_after_onset(p)] for p in data.select(role="fault")]
    return out


def guard_study(datas: Mapping[str, SisterData], prior: SisterModel, fused: Mapping[str, FusedModel], health: HealthSettings) -> list[Stretch]:
    out = []
    for data in datas.values():
        for fleet, stretches in guard_stretches(data).items():
            out += measure(data, fleet, stretches, prior, fused, health)
    return out
