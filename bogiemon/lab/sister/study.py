"""Where the other bogie is the better reference, feature by feature (issue 33, part 2).

For each feature of judgement/sister.py's VOCABULARY, on each wagon model's TRAINING fleet (the
evaluation wagons stay held out) and each load:

- the healthy spread of one bogie ALONE across windows and runs, around its wagon's own mean (what
  a commissioned wagon's own reference leaves), against the spread of the DIFFERENCE between the
  bogies of aligned windows around the wagon's own mean difference; their ratio (> 1: the
  difference scatters less) and the correlation of the two bogies' values; the same across the
  whole fleet (no wagon's mean removed: what an uncommissioned wagon's prior must allow);
- the fault runs' standard scores: each fault run's mean shift of the faulty bogie's feature from
  its wagon's healthy mean, over the alone spread, against the mean shift of the difference
  (signed towards the faulty bogie) over the difference's spread; the median of their sizes over
  the runs of a fault group (broken springs, the other springs, the dampers), faults on either bogie.

One feature at a time flatters the difference: the sister's score whitens all its features
together, and the healthy tails of a difference decide its levels. So THE CHOICE (choose_features)
is made on the score itself, per load, by forward selection on both models' training fleets: the
feature added at each step is the one whose sister score (judgement/sister.py: the difference
whitened by its healthy spread) puts the most fault windows above the healthy windows' 99.9th
percentile, averaged over both models, the wagon commissioned (its own mean difference, the
other wagons' within spread) and not (the other wagons' population), broken springs and every
fault case; each wagon scored leave-one-wagon-out. It stops when a feature adds less than
MIN_STEP (a share of windows) or after MAX_FEATURES. The evaluation wagons never enter it.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection.features import COUPLING_NAMES
from bogiemon.lab.sister.features import FEATURES, Table

MIN_STEP = 0.005
MAX_FEATURES = 8
HEALTHY_QUANTILE = 0.999
# Indicators whose raw values scale with the running (their logs are in the vocabulary instead).
NOT_CANDIDATES = ("i1", "i2", "i3", "i4")
LOADS = ("full", "tare")
GROUPS = ("broken spring", "other spring", "damper")


def fault_group(key: str, severity: float) -> str:
    if key.startswith("type_b"):
        return "damper"
    return "broken spring" if severity == 0.0 else "other spring"


@dataclass(frozen=True)
class FeatureRow:
    """One feature's measurements on one model's training fleet in one load (module docstring)."""

    model: str
    load: str
    feature: str
    sd_alone: float
    sd_diff: float
    correlation: float
    population_sd_alone: float
    population_sd_diff: float
    z_alone: Mapping[str, float]  # per fault group: the median |standard score| alone
    z_diff: Mapping[str, float]  # as a difference
    windows: int  # healthy window pairs
    healthy_runs: int
    fault_runs: Mapping[str, int]  # per fault group

    @property
    def ratio(self) -> float:
        return self.sd_alone / self.sd_diff

    @property
    def population_ratio(self) -> float:
        return self.population_sd_alone / self.population_sd_diff

    def gain(self, group: str) -> float:
        return self.z_diff[group] / self.z_alone[group] if self.z_alone[group] > 0 else np.inf


def wagon_centred(table: Table) -> tuple[NDArray[np.float64], NDArray[np.float64], dict[int, tuple[NDArray[np.float64], NDArray[np.float64]]]]:
    """(x minus its wagon's mean per bogie, d minus its wagon's mean difference, the means): rows
    with a non-finite feature are left out of the means."""
    x = table.x.copy()
    d = table.d.copy()
    means = {}
    for w in np.unique(table.wagon):
        rows = table.wagon == w
        means[int(w)] = (np.nanmean(table.x[rows], axis=0), np.nanmean(table.d[rows], axis=0))
        x[rows] -= means[int(w)][0]
        d[rows] -= means[int(w)][1]
    return x, d, means


def measure(model: str, healthy: Table, faults: Table) -> list[FeatureRow]:
    """The FeatureRows of one model's training fleet (healthy and fault runs), per load and feature."""
    out = []
    for load in LOADS:
        h = healthy.where(healthy.load == load)
        if len(h.x) == 0:
            continue
        xc, dc, means = wagon_centred(h)
        sd_alone = np.sqrt(np.nanmean(xc**2, axis=(0, 1)))
        sd_diff = np.sqrt(np.nanmean(dc**2, axis=0))
        pop_alone = np.nanstd(h.x, axis=(0, 1))
        pop_diff = np.nanstd(h.d, axis=0)
        f = faults.where((faults.load == load) & faults.faulty)
        scores: dict[str, list[tuple[NDArray[np.float64], NDArray[np.float64]]]] = {g: [] for g in GROUPS}
        for i in np.unique(f.run):
            r = faults.runs[int(i)].run
            if r.wagon not in means:
                continue
            rows = f.run == i
            own = np.nanmean(f.x[rows][:, r.bogie - 1], axis=0) - means[r.wagon][0][r.bogie - 1]
            sign = 1.0 if r.bogie == 2 else -1.0
            diff = sign * (np.nanmean(f.d[rows], axis=0) - means[r.wagon][1])
            scores[fault_group(r.key, r.severity)].append((np.abs(own) / sd_alone, np.abs(diff) / sd_diff))
        for k, name in enumerate(FEATURES):
            valid = np.isfinite(xc[:, 0, k]) & np.isfinite(xc[:, 1, k])
            corr = float(np.corrcoef(xc[valid, 0, k], xc[valid, 1, k])[0, 1]) if valid.sum() > 2 else np.nan
            out.append(
                FeatureRow(
                    model, load, name, float(sd_alone[k]), float(sd_diff[k]), corr, float(pop_alone[k]), float(pop_diff[k]),
                    {g: float(np.median([a[k] for a, _ in v])) if v else np.nan for g, v in scores.items()},
                    {g: float(np.median([b[k] for _, b in v])) if v else np.nan for g, v in scores.items()},
                    int(valid.sum()), len(np.unique(h.run)), {g: len(v) for g, v in scores.items()},
                )  # fmt: skip
            )
    return out


def detection_shares(healthy: Table, faults: Table, names: Sequence[str]) -> tuple[float, float, float, float]:
    """The share of fault windows whose sister score over `names` exceeds the healthy windows'
    HEALTHY_QUANTILE: (broken springs, every case) commissioned, then the same uncommissioned,
    each wagon scored leave-one-wagon-out (module docstring). Tables of one load, finite rows."""
    ii = [FEATURES.index(n) for n in names]
    d_h, d_f = healthy.d[:, ii], faults.d[:, ii]
    own_h, pop_h, own_f, pop_f, broken = [], [], [], [], []
    for w in np.unique(healthy.wagon):
        mine, others = healthy.wagon == w, healthy.wagon != w
        groups = [d_h[others & (healthy.wagon == v)] for v in np.unique(healthy.wagon[others])]
        means = np.array([g.mean(axis=0) for g in groups])
        within = np.atleast_2d(np.cov(np.concatenate([g - g.mean(axis=0) for g in groups]).T))
        between = np.atleast_2d(np.cov(means.T))
        own = np.linalg.inv(np.linalg.cholesky(within))
        pop = np.linalg.inv(np.linalg.cholesky(within + between))
        center, pop_center = d_h[mine].mean(axis=0), means.mean(axis=0)
        own_h.append(_scores(d_h[mine], center, own))
        pop_h.append(_scores(d_h[mine], pop_center, pop))
        for run in np.unique(faults.run[faults.wagon == w]):
            rows = faults.run == run
            own_f.append(_scores(d_f[rows], center, own))
            pop_f.append(_scores(d_f[rows], pop_center, pop))
            broken.append(faults.runs[int(run)].run.severity == 0.0)
    q_own, q_pop = np.quantile(np.concatenate(own_h), HEALTHY_QUANTILE), np.quantile(np.concatenate(pop_h), HEALTHY_QUANTILE)
    hit_own = np.array([np.mean(s > q_own) for s in own_f])
    hit_pop = np.array([np.mean(s > q_pop) for s in pop_f])
    b = np.array(broken)
    return float(hit_own[b].mean()), float(hit_own.mean()), float(hit_pop[b].mean()), float(hit_pop.mean())


def own_shares(healthy: Table, faults: Table) -> tuple[float, float, float, float]:
    """detection_shares of each bogie's own reference, the fused score's couplings (COUPLING_NAMES)
    against the wagon's own mean (commissioned) or the other wagons' (uncommissioned), both
    bogies' healthy windows pooled, the faulty bogie's windows scored: the comparison the
    sister's shares stand beside."""
    ii = [FEATURES.index(n) for n in COUPLING_NAMES]
    own_h, pop_h, own_f, pop_f, broken = [], [], [], [], []
    for w in np.unique(healthy.wagon):
        mine, others = healthy.wagon == w, healthy.wagon != w
        x_o = np.concatenate([healthy.x[others][:, 0][:, ii], healthy.x[others][:, 1][:, ii]])
        w_o = np.concatenate([healthy.wagon[others], healthy.wagon[others]])
        within = np.cov(np.concatenate([x_o[w_o == v] - x_o[w_o == v].mean(axis=0) for v in np.unique(w_o)]).T)
        own, pop = np.linalg.inv(np.linalg.cholesky(within)), np.linalg.inv(np.linalg.cholesky(np.cov(x_o.T)))
        centers = [healthy.x[mine][:, k][:, ii].mean(axis=0) for k in range(2)]
        for k in range(2):
            own_h.append(_scores(healthy.x[mine][:, k][:, ii], centers[k], own))
            pop_h.append(_scores(healthy.x[mine][:, k][:, ii], x_o.mean(axis=0), pop))
        for run in np.unique(faults.run[faults.wagon == w]):
            rows, k = faults.run == run, faults.runs[int(run)].run.bogie - 1
            own_f.append(_scores(faults.x[rows][:, k][:, ii], centers[k], own))
            pop_f.append(_scores(faults.x[rows][:, k][:, ii], x_o.mean(axis=0), pop))
            broken.append(faults.runs[int(run)].run.severity == 0.0)
    q_own, q_pop = np.quantile(np.concatenate(own_h), HEALTHY_QUANTILE), np.quantile(np.concatenate(pop_h), HEALTHY_QUANTILE)
    hit_own = np.array([np.mean(s > q_own) for s in own_f])
    hit_pop = np.array([np.mean(s > q_pop) for s in pop_f])
    b = np.array(broken)
    return float(hit_own[b].mean()), float(hit_own.mean()), float(hit_pop[b].mean()), float(hit_pop.mean())


def _scores(rows: NDArray[np.float64], center: NDArray[np.float64], whitening: NDArray[np.floating[Any]]) -> NDArray[np.float64]:
    z = (rows - center) @ whitening.T
    return np.einsum("ij,ij->i", z, z)


def _finite(table: Table) -> NDArray[np.bool_]:
    return np.all(np.isfinite(table.x.reshape(len(table.x), -1)), axis=1)


@dataclass(frozen=True)
class Step:
    """One step of the forward selection: the features so far and their detection shares per model."""

    load: str
    features: tuple[str, ...]
    score: float
    shares: Mapping[str, tuple[float, float, float, float]]


def choose_features(tables: Mapping[str, tuple[Table, Table]]) -> tuple[dict[str, tuple[str, ...]], list[Step]]:
    """THE CHOICE (module docstring): per load, the sister's features, and the selection's steps.
    tables: per model, its training fleet's healthy and fault tables."""
    chosen: dict[str, tuple[str, ...]] = {}
    steps: list[Step] = []  # per load, first the fused score's own reference (features: its couplings), then each step
    for load in LOADS:
        per_model = {}
        for model, (healthy, faults) in tables.items():
            h = healthy.where((healthy.load == load) & _finite(healthy))
            f = faults.where((faults.load == load) & faults.faulty & _finite(faults))
            if len(h.x) and len(f.x):
                per_model[model] = (h, f)
        if not per_model:
            continue
        own = {m: own_shares(h, f) for m, (h, f) in per_model.items()}
        steps.append(Step(load, COUPLING_NAMES, float(np.mean([x for v in own.values() for x in v])), own))
        names: list[str] = []
        best_score = 0.0
        while len(names) < MAX_FEATURES:
            best: Step | None = None
            for candidate in FEATURES:
                if candidate in names or candidate in NOT_CANDIDATES:
                    continue
                try:
                    shares = {m: detection_shares(h, f, [*names, candidate]) for m, (h, f) in per_model.items()}
                except np.linalg.LinAlgError:  # a feature that repeats another: a singular spread
                    continue
                score = float(np.mean([x for v in shares.values() for x in v]))
                if best is None or score > best.score:
                    best = Step(load, (*names, candidate), score, shares)
            if best is None or best.score < best_score + MIN_STEP:
                break
            names, best_score = list(best.features), best.score
            steps.append(best)
        chosen[load] = tuple(names)
    return chosen, steps


def rows_as_dicts(rows: Sequence[FeatureRow]) -> list[dict[str, Any]]:
    out = []
    for r in rows:
        item = asdict(r)
        item.update(ratio=r.ratio, population_ratio=r.population_ratio, gain={g: r.gain(g) for g in GROUPS})
        out.append(item)
    return out
