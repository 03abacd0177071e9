"""The robustness report (docs/robust): Markdown, JSON and figures from the methods' scores.

    write_report(data, scores, "docs/robust", command=..., notes=...)

The targets are issue 8's, stated here before any result: each is checked on the default
method's score and reported met or missed, never tuned to. Figures need the `report` extra.
"""

from __future__ import annotations

import json
import math
import os
import statistics
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.drivers.atomic import write_text_atomically
from bogiemon.lab.robust.fleet import DETECTION_HORIZON_S, SENSOR_DAMAGE, EvaluationData, fault_cells
from bogiemon.lab.robust.score import CellScore, MethodScore


@dataclass(frozen=True)
class Target:
    name: str
    cells: tuple[tuple[str, float], ...]  # the (case, severity) cells it pools; () for the others
    goal: float  # the share that meets it (or the largest count, for false alarms)
    unit: str


def _cells(keys: Sequence[str], severities: Sequence[float]) -> tuple[tuple[str, float], ...]:
    return tuple((k, s) for k in keys for s in severities)


FULL_SPRINGS = ("type_a.full.front_outer", "type_a.full.front_inner", "type_a.full.rear_outer", "type_a.full.rear_inner")
TARE_OUTER = ("type_a.tare.front_outer", "type_a.tare.rear_outer")
TARGETS = (
    Target("broken spring (0 %), full load, detected", _cells(FULL_SPRINGS, (0.0,)), 0.99, "share of runs"),
    Target("spring at 50 %, full load, detected", _cells(FULL_SPRINGS, (0.5,)), 0.90, "share of runs"),
    Target("spring at 200 %, full load, detected", _cells(FULL_SPRINGS, (2.0,)), 0.90, "share of runs"),
    Target("broken outer spring, tare, detected", _cells(TARE_OUTER, (0.0,)), 0.90, "share of runs"),
    Target("friction at 50 %, full load, detected", _cells(("type_b.full",), (0.5,)), 0.90, "share of runs"),
    Target("friction at 150 %, full load, detected", _cells(("type_b.full",), (1.5,)), 0.90, "share of runs"),
    Target("corner of a detected broken spring (full; tare outer)", _cells(FULL_SPRINGS + TARE_OUTER, (0.0,)), 0.90, "share of runs"),
)
HEALTHY_ALARMS_GOAL = 0  # confirmed alarms in 100 h of healthy running
LOAD_ACCURACY_GOAL = 0.99


def pooled(score: MethodScore, cells: Sequence[tuple[str, float]], what: str = "detected") -> tuple[int, int]:
    """(numerator, runs) over cells: detected runs, or detected runs with the right corner."""
    present = [score.cell(k, s) for k, s in cells if any(c.key == k and c.severity == s for c in score.cells)]
    if what == "corner":
        return sum(c.corner_right for c in present), sum(c.detected for c in present)
    return sum(c.detected for c in present), sum(c.runs for c in present)


def pooled_sequences(score: MethodScore, cells: Sequence[tuple[str, float]], what: str = "detected") -> tuple[int, int]:
    """As pooled, over the trend sequences."""
    present = [c for c in (score.sequence_cell(k, s) for k, s in cells) if c is not None]
    if what == "corner":
        return sum(c.corner_right for c in present), sum(c.detected for c in present)
    return sum(c.detected for c in present), sum(c.sequences for c in present)


def target_rows(score: MethodScore) -> list[dict[str, Any]]:
    rows = []
    for t in TARGETS:
        what = "corner" if t.name.startswith("corner") else "detected"
        num, den = pooled(score, t.cells, what)
        value = num / den if den else math.nan
        s_num, s_den = pooled_sequences(score, t.cells, what)
        rows.append({
            "target": t.name, "goal": t.goal, "value": value, "count": f"{num} of {den}", "met": bool(value >= t.goal),
            "sequences": s_num / s_den if s_den else math.nan, "sequences_count": f"{s_num} of {s_den}",
        })  # fmt: skip
    rows.append(
        {
            "target": f"confirmed alarms in {score.healthy_hours:.0f} h of healthy running",
            "goal": HEALTHY_ALARMS_GOAL,
            "value": score.healthy_alarms,
            "count": f"{score.healthy_alarm_runs} of {score.healthy_runs} runs",
            "met": score.healthy_alarms <= HEALTHY_ALARMS_GOAL,
        }
    )
    acc = score.load_accuracy()
    rows.append({"target": "load state correct per judged window", "goal": LOAD_ACCURACY_GOAL, "value": acc, "count": "", "met": bool(acc >= LOAD_ACCURACY_GOAL)})
    return rows


# --------------------------------------------------------------------------------------------
# Formatting


def _pct(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.1f} %" if x < 0.995 or x == 1.0 else f"{100 * x:.2f} %"


def _s(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{x:.0f} s"


def case_label(key: str, severity: float) -> str:
    kind, load, *position = key.split(".")
    what = position[0].replace("_", " ") + " coil" if position else "friction"
    return f"{load}, {what}, {100 * severity:g} %"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *("| " + " | ".join(r) + " |" for r in rows)]


def _json_float(x: float) -> float | None:
    return None if not math.isfinite(x) else round(float(x), 6)


def _cell_json(c: CellScore) -> dict[str, Any]:
    return {
        "key": c.key,
        "severity": c.severity,
        "runs": c.runs,
        "detected": c.detected,
        "rate": _json_float(c.rate),
        "median_time_to_confirm_s": _json_float(c.median_time_s),
        "by_corner": {k: {"runs": v[0], "detected": v[1]} for k, v in c.by_corner.items()},
        "corner_right": c.corner_right,
        "kind_right": c.kind_right,
        "unknown_corner": c.unknown_corner,
        "median_alarm_ratio_after_onset": _json_float(c.median_ratio),
    }


def score_json(score: MethodScore) -> dict[str, Any]:
    return {
        "method": score.method,
        "description": score.description,
        "healthy": {
            "runs": score.healthy_runs,
            "hours": round(score.healthy_hours, 3),
            "confirmed": score.healthy_alarms,
            "runs_with_confirmed": score.healthy_alarm_runs,
            "suspected": score.healthy_suspected,
            "confirmed_per_hour": _json_float(score.false_alarms_per_hour),
            "first_confirmed_by": score.healthy_alarm_triggers,
            "lead_in_hours": round(score.lead_in_hours, 3),
            "lead_in_confirmed": score.lead_in_alarms,
            "alarm_ratio_quantiles": {q: _json_float(float(np.quantile(score.healthy_ratios, q))) for q in (0.5, 0.99, 0.999)} if score.healthy_ratios else {},
        },
        "load": {k: {"windows": v[0], "correct": v[1]} for k, v in score.load_windows.items()},
        "load_smallest_margin": _json_float(score.load_margin),
        "cells": [_cell_json(c) for c in score.cells],
        "sensors": [
            {"damage": s.damage, "runs": s.runs, "recognised": s.recognised, "flagged": s.flagged, "suspension_runs": s.suspension_runs, "problems": s.problems}
            for s in score.sensors
        ],
        "targets": [{k: (_json_float(v) if isinstance(v, float) else v) for k, v in row.items()} for row in target_rows(score)],
        "sequences": [
            {"key": c.key, "severity": c.severity, "sequences": c.sequences, "fault_running_s": c.running_s, "detected": c.detected,
             "by_trend": c.by_trend, "median_time_to_confirm_s": _json_float(c.median_time_s), "corner_right": c.corner_right, "kind_right": c.kind_right}
            for c in score.sequence_cells
        ],
        "sequence_lead_in_confirmed": score.sequence_lead_in_alarms,
    }


# --------------------------------------------------------------------------------------------
# Why some faults stay hidden: the healthy spread against the faults' shifts


SPREAD_FEATURES: tuple[tuple[str, str], ...] = (
    ("I4n", "i4_norm"),
    ("C_PR coherency 4-8 Hz", "c_pr_3"),
    ("C_PR coherency 16-32 Hz", "c_pr_5"),
    ("C_BR coherency 16-32 Hz", "c_br_5"),
)
SPREAD_CASES: tuple[tuple[str, float], ...] = (
    ("type_a.full.rear_outer", 0.0), ("type_a.full.front_outer", 0.0), ("type_a.full.rear_outer", 0.5),
    ("type_b.full", 0.5), ("type_a.tare.rear_outer", 0.0), ("type_a.tare.rear_inner", 0.0),
)  # fmt: skip


def _feature(window: Any, name: str, geometry: Any) -> float:
    if hasattr(window, name):
        return float(getattr(window, name))
    from bogiemon.detection.features import COUPLING_NAMES, coupling_vector

    return float(coupling_vector(window.spectra, geometry)[COUPLING_NAMES.index(name)])


def spread_rows(data: EvaluationData) -> list[list[str]]:
    """Per feature and load: the healthy standard deviation within a run, between the runs of one
    wagon, between wagons; and each listed fault's mean shift from its wagon's healthy mean (the
    windows wholly after the onset, largest over the corners)."""
    rows = []
    for label, name in SPREAD_FEATURES:
        for load in ("full", "tare"):
            per_wagon: dict[int, list[np.ndarray]] = {}
            for r in data.select(role={"calibration", "healthy"}, load=load):
                per_wagon.setdefault(r.run.wagon, []).append(np.array([_feature(w, name, data.geometry) for w in r.windows]))
            if not per_wagon:
                continue
            within = np.sqrt(np.mean([v.var() for runs in per_wagon.values() for v in runs]))
            between = np.sqrt(np.mean([np.var([v.mean() for v in runs]) for runs in per_wagon.values()]))
            means = {w: float(np.mean(np.concatenate(runs))) for w, runs in per_wagon.items()}
            wagons = np.std(list(means.values()))
            shifts = []
            for key, sev in SPREAD_CASES:
                if key.split(".")[1] != load:
                    continue
                by_corner: dict[str, list[float]] = {}
                for r in data.select(role="fault", key=key, severity=sev):
                    after = [_feature(w, name, data.geometry) for w in r.windows if w.start_s >= r.run.onset_s]
                    if after:
                        by_corner.setdefault(r.run.corner.value if r.run.corner else "-", []).append(float(np.mean(after)) - means[r.run.wagon])
                if by_corner:
                    largest = max(by_corner.items(), key=lambda kv: abs(float(np.mean(kv[1]))))
                    shifts.append(f"{case_label(key, sev)}: {float(np.mean(largest[1])):+.3f} ({largest[0]})")
            rows.append([label, load, f"{within:.3f}", f"{between:.3f}", f"{wagons:.3f}", "; ".join(shifts)])
    return rows


def direction_rows(data: EvaluationData, load: str = "full") -> list[list[str]]:
    """Per modal pair and octave band: the healthy coherency's standard deviation within a run,
    between runs of one wagon, and the effect of the direction of travel (half the difference of
    a wagon's means in the two directions, rms over wagons): why bounce-pitch is not judged."""
    from bogiemon.detection.features import modal_coherency
    from bogiemon.detection.spectra import JUDGED_BANDS_HZ as BANDS_HZ

    pairs = (("pitch-roll", 1, 2), ("bounce-roll", 0, 2), ("bounce-pitch", 0, 1))
    per_wagon: dict[int, list[tuple[bool, np.ndarray]]] = {}
    for r in data.select(role={"calibration", "healthy"}, load=load):
        # Computed windows always hold their spectra (None only in records built by hand).
        values = np.array([[modal_coherency(w.spectra, data.geometry)[:, i, j].real for _, i, j in pairs] for w in r.windows])  # type: ignore[arg-type]
        per_wagon.setdefault(r.run.wagon, []).append((r.conditions.reversed, values))  # (windows, pairs, bands)
    if not per_wagon:
        return []
    within = np.sqrt(np.mean([v.var(axis=0) for runs in per_wagon.values() for _, v in runs], axis=0))
    between = np.sqrt(np.mean([np.var([v.mean(axis=0) for _, v in runs], axis=0) for runs in per_wagon.values()], axis=0))
    effects = []
    for runs in per_wagon.values():
        ahead = [v.mean(axis=0) for rev, v in runs if not rev]
        back = [v.mean(axis=0) for rev, v in runs if rev]
        if ahead and back:
            effects.append((np.mean(back, axis=0) - np.mean(ahead, axis=0)) / 2)
    direction = np.sqrt(np.mean(np.square(effects), axis=0)) if effects else np.full_like(within, np.nan)
    rows = []
    for p, (name, _, _) in enumerate(pairs):
        for b in range(len(BANDS_HZ) - 1):
            rows.append([name, f"{BANDS_HZ[b]:g}-{BANDS_HZ[b + 1]:g} Hz", f"{within[p, b]:.3f}", f"{between[p, b]:.3f}", f"{direction[p, b]:.3f}"])
    return rows


# --------------------------------------------------------------------------------------------
# Figures


def _in_view(ratios: Sequence[float]) -> np.ndarray:
    """The finite alarm ratios, clipped to the histogram's 1e-2..1e2 axis (a cell may have none)."""
    x = np.asarray(ratios, dtype=np.float64)
    return np.clip(x[np.isfinite(x)], 1e-2, 1e2)


def render_figures(data: EvaluationData, scores: Sequence[MethodScore], default: MethodScore, out_dir: Path) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = out_dir / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    written = []

    # 1. Detection rate against severity, per case and method.
    cases = [k for k in fault_cells() if any(c.key == k for c in default.cells)]
    fig, axes = plt.subplots(2, (len(cases) + 1) // 2, figsize=(4 * ((len(cases) + 1) // 2), 7.5), constrained_layout=True, squeeze=False)
    for ax, key in zip(axes.flat, cases, strict=False):
        for s in scores:
            cs = sorted((c for c in s.cells if c.key == key), key=lambda c: c.severity)
            ax.plot([c.severity for c in cs], [100 * c.rate for c in cs], marker="o", ms=4, lw=2.2 if s is default else 1.0, label=s.method)
        ax.set(title=case_label(key, 1.0).rsplit(",", 1)[0], xlabel="severity (1 = healthy)", ylim=(-3, 103))
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(cases) :]:
        ax.axis("off")
    axes.flat[0].set_ylabel(f"runs confirmed within {DETECTION_HORIZON_S:g} s (%)")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("Detection rate per fault case and severity, every corner of the monitored bogie pooled")
    fig.savefig(folder / "detection_by_severity.png", dpi=80)
    plt.close(fig)
    written.append("figures/detection_by_severity.png")

    # 2. The default method's alarm ratio: healthy windows against the faults' windows.
    fig, ax = plt.subplots(figsize=(11, 5.5), constrained_layout=True)
    bins = np.logspace(-2, 2, 81).tolist()  # matplotlib's stubs take a sequence of edges
    healthy = _in_view(default.healthy_ratios)
    if healthy.size:
        ax.hist(healthy, bins=bins, density=True, histtype="stepfilled", alpha=0.35, color="0.4", label="healthy test runs")
    for key, sev, colour in (("type_a.full.rear_outer", 0.0, "C3"), ("type_b.full", 1.5, "C1"), ("type_a.tare.rear_outer", 0.0, "C2"), ("type_a.tare.rear_inner", 0.0, "C0")):
        ratios = _in_view([x for c in default.cells if c.key == key and c.severity == sev for x in c.ratios])
        if ratios.size:
            ax.hist(ratios, bins=bins, density=True, histtype="step", lw=1.6, color=colour, label=case_label(key, sev))
    ax.axvline(1.0, color="k", lw=1, ls="--")
    ax.set(xscale="log", xlabel="alarm ratio (judged value / alarm level; >= 1 is an alarm window)", ylabel="density",
           title=f"{default.method}: windows wholly after the fault onset, against healthy windows")  # fmt: skip
    ax.legend(fontsize=8)
    fig.savefig(folder / "alarm_ratio.png", dpi=80)
    plt.close(fig)
    written.append("figures/alarm_ratio.png")

    # 3. Time to confirmation of the default method.
    fig, ax = plt.subplots(figsize=(11, 5), constrained_layout=True)
    labels, times = [], []
    for c in default.cells:
        if c.times_s:
            labels.append(case_label(c.key, c.severity))
            times.append(c.times_s)
    if times:
        ax.boxplot(times, orientation="horizontal", tick_labels=labels)
    ax.axvline(DETECTION_HORIZON_S, color="k", lw=1, ls="--")
    ax.tick_params(axis="y", labelsize=6)
    ax.set(xlabel="time from the fault's onset to CONFIRMED (s)", title=f"{default.method}: time to confirmation of the detected runs")
    fig.savefig(folder / "time_to_confirm.png", dpi=80)
    plt.close(fig)
    written.append("figures/time_to_confirm.png")
    return written


# --------------------------------------------------------------------------------------------
# The report


def write_report(
    data: EvaluationData,
    scores: Sequence[MethodScore],
    out_dir: os.PathLike[str] | str,
    command: str,
    elapsed_s: float,
    sections: Mapping[str, Sequence[str]],
    figures: bool = True,
) -> dict[str, Any]:
    """Write README.md, results.json and figures/ into out_dir; the last score is the default method.

    sections: Markdown lines by name ("method", "models", "discussion") written by the caller,
    who knows the daemon's methods; the numbers here come from the scores only.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    default = scores[-1]
    doc = {
        "command": command,
        "plan": data.plan.name,
        "elapsed_s": round(elapsed_s, 1),
        "simulation_s": round(data.elapsed_s, 1),
        "simulated_h": round(data.simulated_s / 3600.0, 1),
        "window_s": data.settings.window_s,
        "hop_s": data.settings.hop_s,
        "detection_horizon_s": DETECTION_HORIZON_S,
        "default_method": default.method,
        "methods": [score_json(s) for s in scores],
    }
    write_text_atomically(out / "results.json", json.dumps(doc, indent=1) + "\n")
    written = render_figures(data, scores, default, out) if figures else []
    write_text_atomically(out / "README.md", "\n".join(_readme(data, scores, command, elapsed_s, sections, written)) + "\n")
    return doc


def _readme(
    data: EvaluationData, scores: Sequence[MethodScore], command: str, elapsed_s: float, sections: Mapping[str, Sequence[str]], figures: Sequence[str]
) -> list[str]:
    plan, default = data.plan, scores[-1]
    names = [s.method for s in scores]
    lines = [
        "# Detection that holds on real wagons: the robustness evaluation",
        "",
        f"Regenerate with `make evaluate` (`{command}`). On this project's 2-core machine the "
        f"{data.simulated_s / 3600:.0f} h of simulated running took {data.elapsed_s / 60:.0f} min to simulate and analyse"
        + (f" (earlier, kept in a data file: `make evaluate DATA=FILE`); this report took {elapsed_s / 60:.0f} min to fit, judge and write."
           if elapsed_s < data.elapsed_s else f"; fitting, judging and writing brought it to {elapsed_s / 60:.0f} min.")
        + " Numbers for programs: [results.json](results.json).",
        "",
        "## The evaluation set",
        "",
        f"- **Fleet**: {plan.n_wagons} simulated wagons for the evaluation and {plan.n_training_wagons} other wagons "
        "for training the shipped models, each drawn from its own seed (lab/robust/wagons.py states every spread): "
        "masses and inertias +/-10 %, coil springs +/-5 % per wagon and per corner, dampers' Fs +/-10 % per wagon and per "
        "corner, stick and side-bearer stiffness +/-10 % and +/-20 %, sensors with gain +/-3 %, bias +/-0.3 m/s^2, "
        "noise 0.005-0.03 m/s^2 and 16-bit quantisation.",
        "- **Runs**: each on one of ERRI low and high level and FRA classes 4, 5 and 6, at a speed drifting within "
        "50-110 km/h, in either direction of travel. Per wagon and load: "
        f"{plan.calibration_runs} commissioning runs of {plan.calibration_s:g} s (the healthy recordings `bogiemon calibrate` "
        f"learns from), then {plan.healthy_runs} healthy test runs of {plan.healthy_s:g} s on other tracks and speeds.",
        f"- **Faults**: every case of the paper's Tables 1 to 3 at every severity, on each of the four corners of the "
        f"monitored bogie (the one without a sensor too), {plan.fault_runs} runs per case, severity and corner, spread over "
        f"the fleet: {plan.lead_in_s:g} s healthy, then the fault appears and the wagon runs {plan.fault_s:g} s with it. "
        f"Detected means CONFIRMED within {DETECTION_HORIZON_S:g} s of running with the fault. The inner coils in tare "
        "(which do not touch the frame) run too, as a control.",
        f"- **Sensors**: {len(SENSOR_DAMAGE)} kinds of sensor damage, {plan.sensor_runs} runs each per load.",
        f"- **Processing**: windows of {data.settings.window_s:g} s every {data.settings.hop_s:g} s at "
        f"{data.settings.fs_hz:g} Hz, the daemon's defaults; each method is the daemon's own judgement "
        "(daemon/monitor.py: WindowJudge) window by window.",
        "",
        "## The methods compared",
        "",
        *_table(["method", "what"], [[f"**{s.method}**" if s is default else s.method, s.description] for s in scores]),
        "",
        *sections.get("method", ()),
        "",
        "## Targets",
        "",
        f"Measured on the default method (**{default.method}**) beside the paper's method (**{scores[0].method}**), "
        f"per fault run: confirmed within {DETECTION_HORIZON_S:g} s of running with the fault. The last column is the "
        f"default method on the trend sequences, where the same wagon runs on with the fault for "
        f"{_minutes(default)} over other tracks and speeds (not a target: what a keeper gets within the hour).",
        "",
        *_table(
            ["target", "goal", default.method, "", scores[0].method, f"{default.method}, within {_minutes(default)}"],
            [
                [row["target"], _goal(row["goal"]), f"{_value(row['value'])} ({row['count']})" if row["count"] else _value(row["value"]),
                 "met" if row["met"] else "**missed**", _value(paper["value"]),
                 f"{_value(row['sequences'])} ({row['sequences_count']})" if "sequences" in row else ""]
                for row, paper in zip(target_rows(default), target_rows(scores[0]), strict=True)
            ],
        ),  # fmt: skip
        "",
        "## Detection rate per fault case and severity",
        "",
        f"Share of runs confirmed within {DETECTION_HORIZON_S:g} s, over every corner; median time to confirmation "
        f"of the default method's detected runs; its median alarm ratio over the windows wholly after the onset "
        f"(judged value / alarm level: below 1 the fault stays under the alarm level).",
        "",
        *_table(
            ["case", "runs", *names, "time (default)", "ratio (default)"],
            [
                [case_label(c.key, c.severity), str(c.runs), *(_pct(s.cell(c.key, c.severity).rate) for s in scores), _s(c.median_time_s), f"{c.median_ratio:.2f}"]
                for c in default.cells
            ],
        ),
        "",
        "## Detection while the wagon runs on",
        "",
        f"The trend sequences: a healthy lead-in, the fault appears, and the same wagon runs on with it for "
        f"{_minutes(default)} over {data.plan.trend_runs} runs of other tracks and speeds, one sequence per case, severity and "
        "corner. Share of sequences confirmed before they end, the median time of running with the fault to CONFIRMED, "
        "and (default method) the share confirmed by the trend rather than by alarm windows, and the diagnosis's right corner.",
        "",
        *_table(
            ["case", "sequences", *names, "time (default)", "by trend (default)", "corner right (default)"],
            [
                [case_label(c.key, c.severity), str(c.sequences),
                 *(_pct(sc.rate) if (sc := s.sequence_cell(c.key, c.severity)) else "-" for s in scores),
                 _s(c.median_time_s), _pct(c.by_trend / c.detected) if c.detected else "-",
                 _pct(c.corner_right / c.detected) if c.detected else "-"]
                for c in default.sequence_cells
            ],
        ),  # fmt: skip
        "",
        "### By corner (default method, single fault runs)",
        "",
        *_corner_table(default),
        "",
        "## False alarms on healthy wagons",
        "",
        f"Each wagon's healthy test runs are judged in order as one stretch of running ({data.plan.healthy_runs} runs of "
        f"{data.plan.healthy_s:g} s per wagon and load, the decision state and the trend carried from run to run); the "
        "lead-ins are the healthy first minutes of the fault runs and sequences.",
        "",
        *_table(
            ["method", "healthy hours", "CONFIRMED", "per hour", "runs with one", "SUSPECTED", "lead-in CONFIRMED", "alarm ratio p99.9"],
            [
                [s.method, f"{s.healthy_hours:.0f}", str(s.healthy_alarms), f"{s.false_alarms_per_hour:.3f}", f"{s.healthy_alarm_runs} of {s.healthy_runs}",
                 str(s.healthy_suspected), f"{s.lead_in_alarms + s.sequence_lead_in_alarms} in {s.lead_in_hours:.0f} h",
                 f"{np.quantile(s.healthy_ratios, 0.999):.2f}" if s.healthy_ratios else "-"]
                for s in scores
            ],
        ),  # fmt: skip
        "",
        "The default method's healthy runs with a CONFIRMED, by what confirmed it: "
        + (", ".join(f"{k} {v}" for k, v in sorted(default.healthy_alarm_triggers.items())) or "none") + ".",
        "",
        "## Load state from the signals",
        "",
        *_table(
            ["method", "full: windows", "full: right", "tare: windows", "tare: right", "all", "smallest margin"],
            [
                [s.method, *(x for ld in ("full", "tare") for x in (str(s.load_windows.get(ld, (0, 0))[0]), _pct(s.load_accuracy(ld)))),
                 _pct(s.load_accuracy()), "given" if not math.isfinite(s.load_margin) else f"{s.load_margin:+.3f}"]
                for s in scores
            ],
        ),  # fmt: skip
        "",
        "The margin is the smallest distance of the estimated P(full) from 0.5 on the right side over every "
        "judged window (0.5 would be certainty; below 0 a window in the wrong state). The paper's method is given the true load.",
        "",
        "## Where is the fault, and what is it",
        "",
        "Of the default method's detected runs: the share whose diagnosis names the right corner and the right kind "
        "(spring softer, spring stiffer, friction), and the share whose corner came out \"unknown\".",
        "",
        *_table(
            ["case", "detected", "corner right", "kind right", "corner unknown"],
            [
                [case_label(c.key, c.severity), str(c.detected), _pct(c.corner_right / c.detected), _pct(c.kind_right / c.detected), _pct(c.unknown_corner / c.detected)]
                for c in default.cells
                if c.detected
            ],
        ),
        "",
        "## Sensor faults are not suspension faults",
        "",
        *_table(
            ["sensor damage", "runs", "recognised", "any sensor fault", "suspension events", "problems named (runs)"],
            [
                [f"{s.damage}: {SENSOR_DAMAGE[s.damage]}", str(s.runs), f"{s.recognised}", f"{s.flagged}", f"{s.suspension_runs}",
                 ", ".join(f"{k} ({v})" for k, v in list(s.problems.items())[:4])]
                for s in default.sensors
            ],
        ),  # fmt: skip
        "",
    ]
    if figures:
        lines += ["## Figures", ""]
        lines += [f"![{f}]({f})" for f in figures]
        lines.append("")
    lines += [
        "## Why some faults stay hidden",
        "",
        "The healthy spread of a few of the judged quantities (standard deviations over the healthy windows: within a "
        "run, between the runs of one wagon on other tracks and speeds, between the wagons' means) beside the mean "
        "shift that some faults cause, at the corner where it is largest:",
        "",
        *_table(["quantity", "load", "within a run", "between runs", "between wagons", "fault shifts"], spread_rows(data)),
        "",
        "### Choosing the features",
        "",
        "The real part of the modal coherency per octave band at full load, healthy windows: its standard deviation "
        "within a run and between the runs of one wagon, and the effect of the direction of travel (the wagon's mean "
        "running one way against the other):",
        "",
        *_table(["pair", "band", "within a run", "between runs", "direction"], direction_rows(data)),
        "",
    ]
    for name in ("models", "discussion"):
        if sections.get(name):
            lines += [*sections[name], ""]
    return lines


def _minutes(score: MethodScore) -> str:
    running = [c.running_s for c in score.sequence_cells]
    return f"{statistics.median(running) / 60:.0f} min" if running else "-"


def _goal(goal: float) -> str:
    return f">= {_pct(goal)}" if isinstance(goal, float) else f"<= {goal}"


def _value(value: float) -> str:
    return _pct(value) if isinstance(value, float) else str(value)


def _corner_table(score: MethodScore) -> list[str]:
    corners = sorted({c for cell in score.cells for c in cell.by_corner})
    rows = []
    for c in score.cells:
        rows.append([case_label(c.key, c.severity), *(_pct(c.by_corner[k][1] / c.by_corner[k][0]) if k in c.by_corner else "-" for k in corners)])
    return _table(["case", *corners], rows)
