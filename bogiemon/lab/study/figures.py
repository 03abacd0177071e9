"""The study's paper-like figures: each indicator against severity, one line per speed and track."""

from __future__ import annotations

import os

import numpy as np

from bogiemon.lab.study.defaults import run_means
from bogiemon.lab.study.plan import HEALTHY, HEALTHY_SEVERITY, INDICATORS, LABELS, table4_cases
from bogiemon.lab.study.run import StudyResult


FIGURES = (
    ("fig3_full_rear_outer.png", "type_a.full.rear_outer", "rear outer coil, full load (cf. the paper's Fig. 3)"),
    ("fig4_tare_rear_outer.png", "type_a.tare.rear_outer", "rear outer coil, tare (cf. the paper's Fig. 4)"),
    ("fig5_full_type_b.png", "type_b.full", "friction damper (Type B), full load (cf. the paper's Fig. 5)"),
)


def render_figures(result: StudyResult, out_dir: os.PathLike[str] | str) -> list[str]:
    """The paper-like figures: each indicator against severity, mean and spread over runs, one line
    per speed and track. Needs the `report` extra (matplotlib); draws headless."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pathlib import Path

    folder = Path(out_dir) / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    rows = table4_cases()
    for name, key, title in FIGURES:
        if key not in rows or key.split(".")[1] not in result.plan.loads:
            continue
        load = key.split(".")[1]
        fig, axes = plt.subplots(2, 4, figsize=(16, 7.5), constrained_layout=True)
        for cond in result.plan.conditions:
            xs, means, spreads = [], [], []
            for sev in sorted({*rows[key], HEALTHY_SEVERITY}):
                where = {"key": HEALTHY, "load": load} if sev == HEALTHY_SEVERITY else {"key": key, "severity": sev}
                per_run = run_means(result, group="", condition=cond, **where)
                xs.append(sev)
                means.append(per_run.mean(axis=0))
                spreads.append(per_run.std(axis=0))
            m, s = np.array(means), np.array(spreads)
            for j in range(len(INDICATORS)):
                axes.flat[j].errorbar(xs, m[:, j], yerr=s[:, j], marker="o", ms=4, capsize=3, lw=1.2, label=cond.label)
        for j, ind in enumerate(INDICATORS):
            ax = axes.flat[j]
            ax.axvline(HEALTHY_SEVERITY, color="0.7", lw=0.8, ls=":")
            ax.set(title=LABELS[ind], xlabel="severity (fraction of nominal; 1 = healthy)")
            ax.grid(alpha=0.3)
        axes.flat[0].set_ylabel("raw")
        axes.flat[4].set_ylabel("normalised")
        axes.flat[3].legend(fontsize=8)
        fig.suptitle(
            f"{title}: fault at {result.plan.fault_corner.value}, {result.default_window_s:g} s windows; "
            "mean over runs of each run's mean, bars +/- 1 std over runs (track realisations)"
        )
        fig.savefig(folder / name, dpi=90)
        plt.close(fig)
        written.append(f"figures/{name}")
    return written


