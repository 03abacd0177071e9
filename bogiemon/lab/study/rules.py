"""The study's identification rule (a tick of Table 4), stated in lab/study/__init__.py before any
result was looked at: the healthy reference, the flagged windows, the detection shares."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from bogiemon.lab.study.plan import HEALTHY, INDICATORS, Condition, table4_cases
from bogiemon.lab.study.run import StudyResult

RULE_QUANTILE = 0.99
RULE_MIN_SHARE = 0.5
RULE_MAX_FALSE_ALARM = 0.03


@dataclass(frozen=True)
class Reference:
    """The healthy windows of one load, speed, track and window length, per indicator."""

    center: NDArray[np.float64]  # median
    limit: NDArray[np.float64]  # RULE_QUANTILE of |x - center|
    n_windows: int

    @classmethod
    def of(cls, healthy: NDArray[np.float64]) -> Reference:
        if len(healthy) == 0:
            raise ValueError("no healthy windows to form a reference")
        center = np.median(healthy, axis=0)
        return cls(center, np.quantile(np.abs(healthy - center), RULE_QUANTILE, axis=0), len(healthy))

    def flags(self, values: NDArray[np.float64]) -> NDArray[np.bool_]:
        return np.abs(values - self.center) > self.limit


def roc_auc(faulty: NDArray[np.float64], healthy: NDArray[np.float64]) -> float:
    """P(a faulty deviation exceeds a healthy one), ties counted half (Mann-Whitney U / (n m))."""
    ranks = stats.rankdata(np.concatenate([faulty, healthy]))
    n_f, n_h = len(faulty), len(healthy)
    return float((ranks[:n_f].sum() - n_f * (n_f + 1) / 2) / (n_f * n_h))


@dataclass(frozen=True)
class SeverityEvidence:
    """One severity of one case: what the rule saw, per indicator (arrays in INDICATORS order)."""

    severity: float
    n_windows: int
    n_runs: int
    detection_share: NDArray[np.float64]  # pooled over the conditions
    share_per_condition: dict[str, NDArray[np.float64]]
    auc: NDArray[np.float64]  # of |x - m|, faulty against healthy, mean over the conditions
    median_shift: NDArray[np.float64]  # median faulty minus healthy median, mean over the conditions


@dataclass(frozen=True)
class CaseEvidence:
    """One row of Table 4: every severity's evidence, and the rule's verdict per indicator."""

    key: str
    severities: tuple[SeverityEvidence, ...]

    @property
    def min_share(self) -> NDArray[np.float64]:
        return np.min([s.detection_share for s in self.severities], axis=0)

    @property
    def identified(self) -> NDArray[np.bool_]:
        return self.min_share >= RULE_MIN_SHARE


def _conditions(result: StudyResult, group: str) -> tuple[Condition, ...]:
    if group == "":
        return result.plan.conditions
    assert result.plan.sensitivity_condition is not None
    return (result.plan.sensitivity_condition,)


def _healthy_group(result: StudyResult, group: str) -> str:
    sens = {s.name: s for s in result.plan.sensitivities}
    return group if group == "" or sens[group].own_healthy else ""


def identify(result: StudyResult, window_s: float | None = None, group: str = "") -> dict[str, CaseEvidence]:
    """Table 4 under the rule (module docstring): the evidence for every case the group ran."""
    w = result.default_window_s if window_s is None else window_s
    conditions = _conditions(result, group)
    healthy_group = _healthy_group(result, group)
    present = {(r.case.key, r.case.severity) for r in result.runs if r.group == group and r.case.key != HEALTHY}
    refs = {
        (load, c): Reference.of(result.values(w, group=healthy_group, key=HEALTHY, load=load, condition=c))
        for load in {k.split(".")[1] for k, _ in present}
        for c in conditions
    }
    out: dict[str, CaseEvidence] = {}
    for key in table4_cases():
        severities = sorted(s for k, s in present if k == key)
        if not severities:
            continue
        load = key.split(".")[1]
        evidence = []
        for sev in severities:
            flagged, n = np.zeros(len(INDICATORS)), 0
            per_condition: dict[str, NDArray[np.float64]] = {}
            aucs: list[list[float]] = []
            shifts: list[NDArray[np.float64]] = []
            for c in conditions:
                ref = refs[(load, c)]
                healthy = result.values(w, group=healthy_group, key=HEALTHY, load=load, condition=c)
                faulty = result.values(w, group=group, key=key, severity=sev, condition=c)
                f = ref.flags(faulty)
                flagged += f.sum(axis=0)
                n += len(faulty)
                per_condition[c.label] = f.mean(axis=0)
                d_f, d_h = np.abs(faulty - ref.center), np.abs(healthy - ref.center)
                aucs.append([roc_auc(d_f[:, j], d_h[:, j]) for j in range(len(INDICATORS))])
                shifts.append(np.median(faulty, axis=0) - ref.center)
            n_runs = int(result.run_mask(group=group, key=key, severity=sev).sum())
            evidence.append(
                SeverityEvidence(sev, n, n_runs, flagged / n, per_condition, np.mean(aucs, axis=0), np.mean(shifts, axis=0))
            )
        out[key] = CaseEvidence(key, tuple(evidence))
    return out


def rule_false_alarm(result: StudyResult, window_s: float | None = None, group: str = "") -> dict[str, NDArray[np.float64]]:
    """Per load, the rule's out-of-sample per-window false-alarm rate per indicator (two-fold over
    the healthy runs by the parity of their number), pooled over the conditions."""
    w = result.default_window_s if window_s is None else window_s
    group = _healthy_group(result, group)
    out = {}
    for load in sorted({r.case.load for r in result.runs if r.group == group and r.case.key == HEALTHY}):
        flagged, n = np.zeros(len(INDICATORS)), 0
        for c in _conditions(result, group):
            for parity in (0, 1):
                ref = Reference.of(result.values(w, group=group, key=HEALTHY, load=load, condition=c, parity=parity))
                judged = result.values(w, group=group, key=HEALTHY, load=load, condition=c, parity=1 - parity)
                flagged += ref.flags(judged).sum(axis=0)
                n += len(judged)
        out[load] = flagged / n
    return out


def rule_detection_rate(result: StudyResult, window_s: float | None = None) -> dict[str, NDArray[np.float64]]:
    """Per load, the share of ALL fault windows of the main matrix that the rule flags, per indicator."""
    w = result.default_window_s if window_s is None else window_s
    out = {}
    for load in result.plan.loads:
        flagged, n = np.zeros(len(INDICATORS)), 0
        for c in result.plan.conditions:
            ref = Reference.of(result.values(w, group="", key=HEALTHY, load=load, condition=c))
            faulty_keys = {k for k in table4_cases() if k.split(".")[1] == load}
            f = ref.flags(result.values(w, group="", key=faulty_keys, condition=c))
            flagged += f.sum(axis=0)
            n += len(f)
        out[load] = flagged / n
    return out
