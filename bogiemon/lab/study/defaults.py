"""The study's evidence for the daemon's defaults: thresholds, indicators, window length.

The thresholds are the daemon's own rule (judgement/rules.py: fit_threshold, at the study's false-alarm
targets) and every run is judged with the daemon's levels and k-of-n confirmation (rules.Level,
rules.first_confirmation); lab/study/__init__.py states the selection rules.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.rules import Level, Threshold, ThresholdFit, first_confirmation, fit_threshold
from bogiemon.lab.study.plan import HEALTHY, INDICATORS, NORMALISED, RAW, THRESHOLD_GROUPS, table4_cases
from bogiemon.lab.study.run import StudyResult

# The defaults rules (lab/study/__init__.py): the per-window false-alarm targets of the thresholds.
WARNING_RATE = 1e-2
ALARM_RATE = 1e-4
SELECTION_MIN_GAIN = 0.02
SELECTION_MAX_INDICATORS = 3
WINDOW_TIE = 0.02

def calibrate_thresholds(values: NDArray[np.float64], warning_rate: float = WARNING_RATE, alarm_rate: float = ALARM_RATE) -> ThresholdFit:
    """daemon/calibrate.py's thresholds for one indicator from healthy windows: the daemon's own
    threshold rule (judgement/rules.py) at the study's false-alarm targets."""
    return fit_threshold(values, warning_rate, alarm_rate)


@dataclass(frozen=True)
class ThresholdCheck:
    """What one set of thresholds does at one load and window length: to the healthy runs of some
    groups, and to the main matrix's fault runs; alarm and warning windows, and the daemon's k-of-n
    confirmation, run by run."""

    load: str
    window_s: float
    indicators: tuple[str, ...]
    fault_alarm_share: float  # fault windows (every case, severity, speed, track) with any indicator at alarm
    healthy_windows: int  # judged (at or above the excitation gate)
    healthy_windows_total: int
    healthy_alarm_windows: int
    healthy_warning_windows: int
    healthy_runs: int
    healthy_confirmed_runs: int
    healthy_confirmed_by_condition: dict[str, int]  # only the conditions with a confirmed run
    broken_outer_runs: int  # full load only: front or rear outer coil broken (severity 0)
    broken_outer_confirmed_runs: int
    broken_outer_median_confirm_s: float  # end of the confirming window from the run's start
    confirmed_share_per_case: dict[str, float]  # 'key@severity' -> share of its runs confirmed


def windows_by_run(
    result: StudyResult, window_s: float, mask_runs: NDArray[np.bool_], min_excitation_rms_mps2: float = 0.0
) -> dict[int, NDArray[np.float64]]:
    """Each matching run's windows in time order; windows the daemon would gate for weak excitation
    are left out (they are not judged and do not enter the k-of-n history)."""
    table = result.windows[window_s]
    keep = mask_runs[table.run] & (table.excitation_mps2 >= min_excitation_rms_mps2)
    runs, positions, values = table.run[keep], table.position[keep], table.values[keep]
    out: dict[int, NDArray[np.float64]] = {}
    for r in np.unique(runs):
        sel = runs == r
        out[int(r)] = values[sel][np.argsort(positions[sel])]
    return out


def at_level(values: NDArray[np.float64], thresholds: Mapping[str, Threshold], level: Level = Level.ALARM) -> NDArray[np.bool_]:
    """Windows with any of the thresholded indicators at `level` or above (the daemon's levels)."""
    hits = [t.levels(values[:, INDICATORS.index(n)]) >= level for n, t in thresholds.items()]
    return np.any(hits, axis=0) if hits else np.zeros(len(values), dtype=bool)


def _confirmations(
    result: StudyResult,
    window_s: float,
    mask: NDArray[np.bool_],
    thresholds: Mapping[str, Threshold],
    confirm_k: int,
    confirm_n: int,
    min_excitation_rms_mps2: float = 0.0,
) -> dict[int, int | None]:
    """Per run: the index (among its judged windows) of the window that confirms, None if none does."""
    return {
        run: first_confirmation(at_level(v, thresholds), confirm_k, confirm_n)
        for run, v in windows_by_run(result, window_s, mask, min_excitation_rms_mps2).items()
    }


def judged_values(result: StudyResult, window_s: float, min_excitation_rms_mps2: float, **where: Any) -> NDArray[np.float64]:
    table = result.windows[window_s]
    keep = result.run_mask(**where)[table.run] & (table.excitation_mps2 >= min_excitation_rms_mps2)
    return table.values[keep]


def check_thresholds(
    result: StudyResult,
    load: str,
    window_s: float,
    thresholds: Mapping[str, Threshold],
    confirm_k: int = 3,
    confirm_n: int = 5,
    healthy_groups: frozenset[str] = THRESHOLD_GROUPS,
    min_excitation_rms_mps2: float = 0.3,
) -> ThresholdCheck:
    """Judge the healthy runs of `healthy_groups` and the main matrix's fault runs of `load` with
    `thresholds` as the daemon would: windows below its excitation gate are not judged, the others
    advance a k-of-n history per run."""
    gate, groups = min_excitation_rms_mps2, set(healthy_groups)
    faulty_keys = {r.case.key for r in result.runs if r.group == "" and r.case.load == load and r.case.key != HEALTHY}
    healthy = judged_values(result, window_s, gate, group=groups, key=HEALTHY, load=load)
    faulty = judged_values(result, window_s, gate, group="", key=faulty_keys)
    healthy_mask = result.run_mask(group=groups, key=HEALTHY, load=load)
    healthy_confirm = _confirmations(result, window_s, healthy_mask, thresholds, confirm_k, confirm_n, gate)
    by_condition: dict[str, int] = {}
    for run, found in healthy_confirm.items():
        if found is not None:
            label = result.runs[run].condition.label
            by_condition[label] = by_condition.get(label, 0) + 1
    per_case: dict[str, float] = {}
    for key in sorted(faulty_keys):
        for sev in sorted({r.case.severity for r in result.runs if r.group == "" and r.case.key == key}):
            mask = result.run_mask(group="", key=key, severity=sev)
            confirmed = list(_confirmations(result, window_s, mask, thresholds, confirm_k, confirm_n, gate).values())
            per_case[f"{key}@{sev:g}"] = sum(c is not None for c in confirmed) / len(confirmed)
    broken_keys = {"type_a.full.front_outer", "type_a.full.rear_outer"} & faulty_keys
    broken_mask = result.run_mask(group="", key=broken_keys, severity=0.0)
    broken = list(_confirmations(result, window_s, broken_mask, thresholds, confirm_k, confirm_n, gate).values()) if broken_keys else []
    # The matrix's windows are all above the gate (StudyResult.min_excitation_rms_mps2), so the
    # confirming window's index among the judged ones gives its end time.
    confirm_s = [window_s + c * result.settings.hop_s for c in broken if c is not None]
    table = result.windows[window_s]
    return ThresholdCheck(
        load=load,
        window_s=window_s,
        indicators=tuple(thresholds),
        fault_alarm_share=float(at_level(faulty, thresholds).mean()) if len(faulty) else math.nan,
        healthy_windows=len(healthy),
        healthy_windows_total=int(healthy_mask[table.run].sum()),
        healthy_alarm_windows=int(at_level(healthy, thresholds).sum()),
        healthy_warning_windows=int(at_level(healthy, thresholds, Level.WARNING).sum()),
        healthy_runs=len(healthy_confirm),
        healthy_confirmed_runs=sum(c is not None for c in healthy_confirm.values()),
        healthy_confirmed_by_condition=by_condition,
        broken_outer_runs=len(broken),
        broken_outer_confirmed_runs=sum(c is not None for c in broken),
        broken_outer_median_confirm_s=float(np.median(confirm_s)) if confirm_s else math.nan,
        confirmed_share_per_case=per_case,
    )


def gated_share(result: StudyResult, group: str, window_s: float, min_excitation_rms_mps2: float, **where: Any) -> float:
    """The share of a group's windows the daemon would not judge (weak excitation)."""
    table = result.windows[window_s]
    sel = result.run_mask(group=group, **where)[table.run]
    return float(np.mean(table.excitation_mps2[sel] < min_excitation_rms_mps2)) if sel.any() else math.nan


@dataclass(frozen=True)
class DecisionEvidence:
    """Indicators selected among candidates at one load and window length, their calibrated
    thresholds, and what they do."""

    load: str
    window_s: float
    indicators: tuple[str, ...]
    thresholds: dict[str, ThresholdFit]
    per_indicator_share: dict[str, float]  # each candidate alone, at its own thresholds
    check: ThresholdCheck
    held_out_alarm_windows: int  # thresholds from half the healthy runs, judged on the other half
    held_out_confirmed_runs: int
    held_out_confirmed_by_condition: dict[str, int]


def decision_evidence(
    result: StudyResult,
    load: str,
    window_s: float,
    candidates: Sequence[str] = INDICATORS,
    confirm_k: int = 3,
    confirm_n: int = 5,
    min_excitation_rms_mps2: float = 0.3,
    healthy_groups: frozenset[str] = THRESHOLD_GROUPS,
) -> DecisionEvidence:
    """Thresholds from the load's healthy windows (all speeds and tracks of `healthy_groups`),
    forward selection of the indicators among `candidates` (module docstring), and the k-of-n
    confirmation they give (on the healthy runs of THRESHOLD_GROUPS, whatever they came from)."""
    gate, groups = min_excitation_rms_mps2, set(healthy_groups)
    faulty_keys = {k for k in table4_cases() if k.split(".")[1] == load}
    healthy = judged_values(result, window_s, gate, group=groups, key=HEALTHY, load=load)
    faulty = judged_values(result, window_s, gate, group="", key=faulty_keys)
    thresholds = {n: calibrate_thresholds(healthy[:, INDICATORS.index(n)]) for n in INDICATORS}

    def share(names: Sequence[str]) -> float:
        return float(at_level(faulty, {n: thresholds[n] for n in names}).mean())

    per_indicator = {n: share([n]) for n in candidates}
    chosen: list[str] = [max(candidates, key=lambda n: per_indicator[n])]
    while len(chosen) < SELECTION_MAX_INDICATORS:
        rest = [n for n in candidates if n not in chosen]
        if not rest:
            break
        best = max(rest, key=lambda n: share([*chosen, n]))
        if share([*chosen, best]) - share(chosen) < SELECTION_MIN_GAIN:
            break
        chosen.append(best)
    selected = {n: thresholds[n] for n in chosen}
    held_out_alarms = 0
    held_out_by_condition: dict[str, int] = {}
    for parity in (0, 1):
        fit = judged_values(result, window_s, gate, group=groups, key=HEALTHY, load=load, parity=parity)
        refit = {n: calibrate_thresholds(fit[:, INDICATORS.index(n)]) for n in chosen}
        judged = result.run_mask(group=groups, key=HEALTHY, load=load, parity=1 - parity)
        held_out_alarms += int(at_level(judged_values(result, window_s, gate, group=groups, key=HEALTHY, load=load, parity=1 - parity), refit).sum())
        for run, found in _confirmations(result, window_s, judged, refit, confirm_k, confirm_n, gate).items():
            if found is not None:
                label = result.runs[run].condition.label
                held_out_by_condition[label] = held_out_by_condition.get(label, 0) + 1
    return DecisionEvidence(
        load=load,
        window_s=window_s,
        indicators=tuple(chosen),
        thresholds=selected,
        per_indicator_share=per_indicator,
        check=check_thresholds(result, load, window_s, selected, confirm_k, confirm_n, min_excitation_rms_mps2=gate),
        held_out_alarm_windows=held_out_alarms,
        held_out_confirmed_runs=sum(held_out_by_condition.values()),
        held_out_confirmed_by_condition=held_out_by_condition,
    )


@dataclass(frozen=True)
class DefaultsEvidence:
    """Every window length x candidate set (raw, normalised, all) x load, and the choice."""

    table: dict[tuple[float, str, str], DecisionEvidence]  # (window_s, candidate set, load) -> evidence
    eligible: dict[float, bool]
    chosen_window_s: float
    chosen: dict[str, DecisionEvidence]  # load -> the defaults
    confirm_k: int
    confirm_n: int


CANDIDATE_SETS: dict[str, tuple[str, ...]] = {"raw": RAW, "normalised": NORMALISED, "all": INDICATORS}


def defaults_evidence(result: StudyResult, confirm_k: int = 3, confirm_n: int = 5, min_excitation_rms_mps2: float = 0.3) -> DefaultsEvidence:
    """The defaults rules of the module docstring over the plan's window lengths."""
    table = {
        (w, name, load): decision_evidence(result, load, w, cands, confirm_k, confirm_n, min_excitation_rms_mps2)
        for w in result.plan.window_lengths_s
        for name, cands in CANDIDATE_SETS.items()
        for load in result.plan.loads
    }

    def ok(e: DecisionEvidence) -> bool:
        return e.check.healthy_confirmed_runs == 0 and e.check.broken_outer_confirmed_runs == e.check.broken_outer_runs

    eligible = {w: all(ok(table[(w, "all", load)]) for load in result.plan.loads) for w in result.plan.window_lengths_s}
    score = {w: float(np.mean([table[(w, "all", load)].check.fault_alarm_share for load in result.plan.loads])) for w in eligible}
    candidates = [w for w in sorted(eligible) if eligible[w]] or sorted(eligible)
    best = max(score[w] for w in candidates)
    chosen_w = min(w for w in candidates if score[w] >= best - WINDOW_TIE)
    chosen = {load: table[(chosen_w, "all", load)] for load in result.plan.loads}
    return DefaultsEvidence(table, eligible, chosen_w, chosen, confirm_k, confirm_n)


# --------------------------------------------------------------------------------------------
# Per-run means, for the figures


def run_means(result: StudyResult, window_s: float | None = None, **where: Any) -> NDArray[np.float64]:
    """(runs, 8): each matching run's mean over its windows."""
    w = result.default_window_s if window_s is None else window_s
    by_run = windows_by_run(result, w, result.run_mask(**where))
    return np.array([v.mean(axis=0) for v in by_run.values()]) if by_run else np.empty((0, len(INDICATORS)))


