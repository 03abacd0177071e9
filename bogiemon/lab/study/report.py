"""The study's report: README.md, defaults.md and table4.json (and the figures) from a StudyResult."""

from __future__ import annotations

import dataclasses
import math
import os
import time
from collections.abc import Mapping
from typing import Any

from bogiemon.judgement.rules import Threshold
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.lab.study.defaults import (
    DecisionEvidence,
    ThresholdCheck,
    calibrate_thresholds,
    check_thresholds,
    defaults_evidence,
    gated_share,
    judged_values,
)
from bogiemon.lab.study.figures import render_figures
from bogiemon.lab.study.plan import ENVELOPE, HEALTHY, INDICATORS, LABELS, PAPER_INDICATORS, paper_table4
from bogiemon.lab.study.rules import (
    RULE_MAX_FALSE_ALARM,
    RULE_MIN_SHARE,
    RULE_QUANTILE,
    CaseEvidence,
    identify,
    rule_detection_rate,
    rule_false_alarm,
)
from bogiemon.lab.study.run import StudyResult
from bogiemon.lab.study.text import DISCUSSION_FILE, defaults_text, readme_text
from bogiemon.simulator.params import default_parameter_set


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _evidence_json(case: CaseEvidence) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for j, ind in enumerate(INDICATORS):
        out[LABELS[ind]] = {
            "identified": bool(case.identified[j]),
            "min_detection_share": float(case.min_share[j]),
            "per_severity": {
                f"{s.severity:g}": {
                    "detection_share": float(s.detection_share[j]),
                    "auc": float(s.auc[j]),
                    "median_shift": float(s.median_shift[j]),
                    "n_windows": s.n_windows,
                    "n_runs": s.n_runs,
                    "share_per_condition": {c: float(v[j]) for c, v in s.share_per_condition.items()},
                }
                for s in case.severities
            },
        }
    return out


def write_report(
    result: StudyResult,
    out_dir: os.PathLike[str] | str,
    command: str = "bogiemon study -o docs/study",
    confirm_k: int = 3,
    confirm_n: int = 5,
    figures: bool = True,
    configured: Mapping[LoadState, Mapping[str, Threshold]] | None = None,
    min_excitation_rms_mps2: float = 0.3,
) -> dict[str, Any]:
    """Write README.md, defaults.md, table4.json (and the figures) into out_dir; returns the JSON.

    `configured`: the daemon's thresholds (load -> indicator -> levels) for windows of
    result.settings.window_s, checked on the study's runs beside the ones the study derives.
    """
    import json
    from pathlib import Path

    started = time.perf_counter()
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    paper = {k: v for k, v in paper_table4().items() if k.split(".")[1] in result.plan.loads}
    ours = identify(result)
    false_alarm = rule_false_alarm(result)
    detection = rule_detection_rate(result)
    sens = {s.name: identify(result, group=s.name) for s in result.plan.sensitivities}
    sens_fa = {s.name: rule_false_alarm(result, group=s.name) for s in result.plan.sensitivities if s.own_healthy}
    gate = min_excitation_rms_mps2
    defaults = defaults_evidence(result, confirm_k, confirm_n, gate)
    configured_here = {load: configured[LoadState(load)] for load in result.plan.loads if configured and configured.get(LoadState(load))}
    shipped = {
        load: check_thresholds(result, load, result.default_window_s, t, confirm_k, confirm_n, min_excitation_rms_mps2=gate)
        for load, t in configured_here.items()
    }
    # Why the envelope runs are in the thresholds' population: the same rule on the matrix's healthy
    # runs alone, judged on the envelope's healthy runs.
    matrix_only: dict[str, ThresholdCheck] = {}
    if any(r.group == ENVELOPE for r in result.runs):
        w = defaults.chosen_window_s
        for load, e in defaults.chosen.items():
            fit = judged_values(result, w, gate, group="", key=HEALTHY, load=load)
            limits = {n: calibrate_thresholds(fit[:, INDICATORS.index(n)]) for n in e.indicators}
            matrix_only[load] = check_thresholds(result, load, w, limits, confirm_k, confirm_n, frozenset({ENVELOPE}), gate)
    written = render_figures(result, folder) if figures else []

    agreements = {k: [paper[k][j] == bool(ours[k].identified[j]) for j in range(4)] for k in paper if k in ours}
    n_agree = sum(sum(v) for v in agreements.values())
    n_cells = sum(len(v) for v in agreements.values())
    report_s = time.perf_counter() - started
    timing = {
        "study_s": round(result.elapsed_s, 1),
        "report_s": round(report_s, 1),
        "total_s": round(result.elapsed_s + report_s, 1),
        "simulated_s": result.simulated_s,
        "runs": len(result.runs),
        "cpu_count": result.cpu_count,
    }

    doc: dict[str, Any] = {
        "format": "bogiemon-study/1",
        "plan": result.plan.name,
        "command": command,
        "timing": timing,
        "rule": {
            "reference": "per load, speed, track and window length: median m and 99th percentile h of |x - m| over healthy windows",
            "flag": "|x - m| > h",
            "identified": f"detection share >= {RULE_MIN_SHARE} for every severity of the case, pooled over speeds and tracks",
            "quantile": RULE_QUANTILE,
            "min_share": RULE_MIN_SHARE,
            "max_false_alarm": RULE_MAX_FALSE_ALARM,
        },
        "settings": {
            "window_s": result.default_window_s,
            "hop_s": result.settings.hop_s,
            "max_lag_s": result.settings.max_lag_s,
            "fs_hz": result.settings.fs_hz,
            "fault_corner": result.plan.fault_corner.value,
            "conditions": [dataclasses.asdict(c) for c in result.plan.conditions],
            "duration_s": result.plan.duration_s,
            "healthy_runs": result.plan.healthy_runs,
            "fault_runs": result.plan.fault_runs,
            "noise_mps2": result.plan.noise_mps2,
            "stick_stiffness_n_per_m": float(default_parameter_set()["vehicle"]["primary"]["stick_stiffness_n_per_m"]),
        },
        "indicators": [LABELS[i] for i in PAPER_INDICATORS],
        "cases": {
            key: {
                "paper": list(paper[key]),
                "ours": [bool(ours[key].identified[j]) for j in range(4)],
                "agree": agreements[key],
                "severities": [s.severity for s in ours[key].severities],
                "indicators": _evidence_json(ours[key]),
            }
            for key in paper
            if key in ours
        },
        "agreement": {"cells": n_cells, "agree": n_agree},
        "rates": {
            load: {
                "rule_detection_per_window": {LABELS[i]: float(detection[load][j]) for j, i in enumerate(INDICATORS)},
                "rule_false_alarm_per_window_held_out": {LABELS[i]: float(false_alarm[load][j]) for j, i in enumerate(INDICATORS)},
            }
            for load in result.plan.loads
        },
        "sensitivity": {
            name: {
                key: {LABELS[i]: {"identified": bool(ev.identified[j]), "min_detection_share": float(ev.min_share[j])} for j, i in enumerate(INDICATORS)}
                for key, ev in cases.items()
            }
            for name, cases in sens.items()
        },
        "min_excitation_rms_mps2": result.min_excitation_rms_mps2,
    }
    if defaults is not None:
        doc["defaults"] = {
            "window_s": defaults.chosen_window_s,
            "confirm": f"{confirm_k} of {confirm_n}",
            "per_load": {load: _decision_json(e) for load, e in defaults.chosen.items()},
            "by_window_and_set": {
                f"{w:g}s/{name}/{load}": _decision_json(e) for (w, name, load), e in defaults.table.items()
            },
            "eligible_windows": {f"{w:g}": v for w, v in defaults.eligible.items()},
        }
        for load in result.plan.loads:
            e = defaults.chosen[load]
            doc["rates"][load]["defaults_alarm_detection_per_window"] = e.check.fault_alarm_share
            doc["rates"][load]["defaults_alarm_false_alarm_per_window"] = e.check.healthy_alarm_windows / e.check.healthy_windows
            doc["rates"][load]["defaults_held_out_alarm_false_alarm_per_window"] = e.held_out_alarm_windows / e.check.healthy_windows
    for load, c in shipped.items():
        doc["rates"][load]["configured_alarm_detection_per_window"] = c.fault_alarm_share
        doc["rates"][load]["configured_alarm_false_alarm_per_window"] = c.healthy_alarm_windows / c.healthy_windows
        doc["rates"][load]["configured_warning_false_alarm_per_window"] = c.healthy_warning_windows / c.healthy_windows
    doc["envelope"] = {
        "conditions": [dataclasses.asdict(c) for c in result.plan.envelope_conditions],
        "runs_per_load_and_condition": result.plan.envelope_runs,
        "gated_share": {load: gated_share(result, ENVELOPE, result.default_window_s, gate, load=load) for load in result.plan.loads},
        "matrix_only_thresholds_on_envelope_runs": {load: _check_json(c) for load, c in matrix_only.items()},
    }
    doc["configured_thresholds"] = {
        load: {
            "window_s": c.window_s,
            "thresholds": {n: {"center": t.center, "warning": t.warning, "alarm": t.alarm} for n, t in configured[load].items()},  # type: ignore[index]
            **_check_json(c),
        }
        for load, c in shipped.items()
    }
    (folder / "table4.json").write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")

    discussion_path = folder / DISCUSSION_FILE
    discussion = discussion_path.read_text(encoding="utf-8") if discussion_path.is_file() else None
    readme = readme_text(result, paper, ours, agreements, false_alarm, detection, sens, sens_fa, defaults, shipped, gate, written, timing, command, discussion)
    (folder / "README.md").write_text(readme, encoding="utf-8")
    if defaults is not None:
        (folder / "defaults.md").write_text(defaults_text(result, defaults, shipped, matrix_only, gate, timing, command, confirm_k, confirm_n), encoding="utf-8")
    return doc


def _check_json(c: ThresholdCheck) -> dict[str, Any]:
    return {
        "indicators": [LABELS[n] for n in c.indicators],
        "alarm_detection_share": c.fault_alarm_share,
        "healthy_windows": c.healthy_windows,
        "healthy_windows_total": c.healthy_windows_total,
        "healthy_alarm_windows": c.healthy_alarm_windows,
        "healthy_warning_windows": c.healthy_warning_windows,
        "healthy_runs": c.healthy_runs,
        "healthy_confirmed_runs": c.healthy_confirmed_runs,
        "healthy_confirmed_by_condition": c.healthy_confirmed_by_condition,
        "broken_outer_runs": c.broken_outer_runs,
        "broken_outer_confirmed_runs": c.broken_outer_confirmed_runs,
        "broken_outer_median_confirm_s": _json_float(c.broken_outer_median_confirm_s),
        "confirmed_share_per_case": c.confirmed_share_per_case,
    }


def _decision_json(e: DecisionEvidence) -> dict[str, Any]:
    return {
        **_check_json(e.check),
        "thresholds": {
            n: {"center": t.center, "warning": t.warning, "alarm": t.alarm, "robust_sigma": t.robust_sigma, "max_deviation": t.max_deviation}
            for n, t in e.thresholds.items()
        },
        "per_indicator_alarm_detection_share": {LABELS[n]: v for n, v in e.per_indicator_share.items()},
        "held_out_alarm_windows": e.held_out_alarm_windows,
        "held_out_confirmed_runs": e.held_out_confirmed_runs,
        "held_out_confirmed_by_condition": e.held_out_confirmed_by_condition,
    }


