"""Fleet-relative evidence: a wagon against its sisters (same type, same load state).

A wagon's own trend cannot see a fault that was there when it was commissioned, nor tell a
wagon that drifts from one that was always a little different. Its sisters can: per load state,
each wagon's mean coupling vector (pitch-roll and bounce-roll coherency in octave bands) is
compared with the other sisters' by a robust z per feature, z = (x - median) / (1.4826 MAD),
and the distance is the RMS of the z over the features. Two vectors per wagon: its baseline (its
commissioning center, else its first analysed day) and its last day. A wagon whose either
distance exceeds STANDS_OUT is listed, with or without an alarm.

STANDS_OUT and the floor on the spread are priors chosen on the simulated fleets (docs/fleet.md
states the distances seen there); a keeper's own fleet sets its spread itself, since it is always
measured among the sisters at hand.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from bogiemon.fleet.judged import WagonJudged
from bogiemon.fleet.layout import Fleet, Wagon

STANDS_OUT = 3.0  # robust standard deviations (RMS over the features)
MIN_SISTERS = 3  # other wagons of the same type and load needed to judge one against them
MIN_WINDOWS = 30  # judged windows behind a vector
# No spread is taken below this (coherency units): a handful of sisters that happen to agree would
# make any difference look huge. 0.05 is the between-wagon standard deviation of the healthy
# couplings on the simulated fleet (0.04 to 0.10 per feature, docs/robust/README.md): a prior.
MIN_SPREAD = 0.05


def robust_distance(x: np.ndarray, others: np.ndarray) -> float:
    """RMS over the features of (x - median of others) / max(1.4826 MAD of others, MIN_SPREAD)."""
    median = np.median(others, axis=0)
    spread = np.maximum(1.4826 * np.median(np.abs(others - median), axis=0), MIN_SPREAD)
    return float(np.sqrt(np.mean(((x - median) / spread) ** 2)))


def _vectors(wagon: Wagon, judged: WagonJudged, load: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    ev = judged.evidence.get(load)
    if ev is None:
        return None, None
    own = wagon.config.decision.fused.get(load)  # type: ignore[call-overload]
    baseline = np.asarray(own.center) if own is not None else (np.asarray(ev["first_day"]) if ev["first_day_windows"] >= MIN_WINDOWS else None)
    recent = np.asarray(ev["last_day"]) if ev["last_day_windows"] >= MIN_WINDOWS else None
    return baseline, recent


def main_load(judged: WagonJudged) -> str | None:
    """The load state the wagon ran in most (judged windows of its last day, then its first)."""
    counts = {ld: int(ev["last_day_windows"]) or int(ev["first_day_windows"]) for ld, ev in judged.evidence.items()}
    return max(counts, key=lambda ld: counts[ld]) if counts else None


def fleet_relative(fleet: Fleet, judged: Sequence[WagonJudged]) -> dict[str, dict[str, Any]]:
    """Per wagon id: baseline_distance, recent_distance, trend_rank, sisters, stands_out, why."""
    by_id = {j.wagon_id: j for j in judged}
    wagons = [w for w in fleet.wagons if w.wagon_id in by_id]
    out: dict[str, dict[str, Any]] = {}
    for wagon in wagons:
        j = by_id[wagon.wagon_id]
        load = main_load(j)
        if load is None:
            continue
        sisters = [w for w in wagons if w is not wagon and w.wagon_type == wagon.wagon_type and main_load(by_id[w.wagon_id]) == load]
        base, recent = _vectors(wagon, j, load)
        entry: dict[str, Any] = {"load": load, "sisters": len(sisters), "baseline_distance": None, "recent_distance": None,
                                 "trend_rank": None, "stands_out": False, "why": ""}  # fmt: skip
        for name, mine, pick in (("baseline_distance", base, 0), ("recent_distance", recent, 1)):
            theirs = [v for v in (_vectors(s, by_id[s.wagon_id], load)[pick] for s in sisters) if v is not None]
            if mine is not None and len(theirs) >= MIN_SISTERS:
                entry[name] = round(robust_distance(mine, np.array(theirs)), 3)
        ratios = [r for r in (_trend_ratio(by_id[s.wagon_id]) for s in sisters) if r is not None]
        mine_ratio = _trend_ratio(j)
        if mine_ratio is not None and len(ratios) >= MIN_SISTERS:
            entry["trend_rank"] = round(sum(r < mine_ratio for r in ratios) / len(ratios), 3)  # share of sisters below it
        worst = max((entry[k] for k in ("baseline_distance", "recent_distance") if entry[k] is not None), default=None)
        if worst is not None and worst > STANDS_OUT:
            which = "its commissioning baseline" if entry["baseline_distance"] == worst else "its last day"
            entry["stands_out"] = True
            entry["why"] = (
                f"stands out of its {len(sisters)} sisters ({wagon.wagon_type}, {load}): the couplings of {which} lie "
                f"{worst:.1f} robust standard deviations from theirs (listed above {STANDS_OUT:g})"
            )
        out[wagon.wagon_id] = entry
    return out


def _trend_ratio(judged: WagonJudged) -> float | None:
    if judged.trend is None or not judged.trend_alarm:
        return None
    return judged.trend / judged.trend_alarm
