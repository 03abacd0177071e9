"""The sister study's tables, figures and results file (docs/wagon/: tables.md, figures/, results.json)."""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.drivers.atomic import write_text_atomically
from bogiemon.lab.sister.evaluate import Configuration
from bogiemon.lab.sister.guard import Stretch
from bogiemon.lab.sister.score import TARGETS, healthy, met, select, sensor_runs
from bogiemon.detection.features import COUPLING_NAMES
from bogiemon.lab.sister.study import GROUPS, FeatureRow, Step, rows_as_dicts


def _f(x: float, digits: int = 2) -> str:
    return "-" if not math.isfinite(x) else f"{x:.{digits}f}"


def feature_table(rows: Sequence[FeatureRow], chosen: Mapping[str, Sequence[str]]) -> list[str]:
    """Markdown: per model and load, each feature's spreads, correlation and fault scores."""
    out = []
    for model in sorted({r.model for r in rows}):
        for load in ("full", "tare"):
            mine = [r for r in rows if r.model == model and r.load == load]
            if not mine:
                continue
            r0 = mine[0]
            faults = ", ".join(f"{g} {r0.fault_runs[g]}" for g in GROUPS)
            out += [
                f"### Model {model.upper()}, {load} ({r0.windows} healthy window pairs of {r0.healthy_runs} runs; fault runs: {faults})",
                "",
                "| feature | spread alone / difference | correlation | across the fleet | " + " | ".join(f"{g}: z alone -> difference" for g in GROUPS) + " |",
                "|---|---|---|---|" + "---|" * len(GROUPS),
            ]
            for r in mine:
                mark = " **(sister)**" if r.feature in chosen.get(load, ()) else ""
                zs = " | ".join(f"{_f(r.z_alone[g], 1)} -> {_f(r.z_diff[g], 1)}" for g in GROUPS)
                out.append(f"| {r.feature}{mark} | {_f(r.ratio)} | {_f(r.correlation)} | {_f(r.population_ratio)} | {zs} |")
            out.append("")
    return out


def selection_table(steps: Sequence[Step]) -> list[str]:
    """Markdown: the forward selection, per load: the fused score's own reference first, then each step."""
    models = sorted({m for s in steps for m in s.shares})
    out = [
        "| load | features | " + " | ".join(f"{m.upper()}: {what}" for m in models for what in ("broken, commissioned", "all, commissioned", "broken, uncommissioned", "all, uncommissioned")) + " |",
        "|---|---|" + "---|" * (4 * len(models)),
    ]
    for s in steps:
        label = "each bogie's own couplings (the fused score)" if s.features == COUPLING_NAMES else "sister: " + ", ".join(s.features)
        cells = [f"{100 * x:.0f} %" for m in models for x in s.shares[m]]
        out.append(f"| {s.load} | {label} | " + " | ".join(cells) + " |")
    return out + [""]


def evaluation_table(configurations: Sequence[Configuration]) -> list[str]:
    """Markdown: every target against each configuration."""
    models = sorted({c.model for c in configurations})
    out = []
    for model in models:
        mine = [c for c in configurations if c.model == model]
        out += [f"### Model {model.upper()}", "", "| target | goal | " + " | ".join(f"{c.mode}, {'sister' if c.sister else 'alone'}" for c in mine) + " |"]
        out.append("|---|---|" + "---|" * len(mine))
        for t in TARGETS:
            cells = []
            for c in mine:
                count = t.measure(c)
                ok = met(t, count)
                cells.append(f"{count.text()} ({_f(100 * count.share, 1)} %){'' if ok is None else (' ok' if ok else ' **no**')}")
            goal = f"{'<=' if t.at_most else '>='} {100 * t.goal:g} %"
            out.append(f"| {t.name} | {goal} | " + " | ".join(cells) + " |")
        out.append("")
        out += uneven_lines(mine)
    return out


def uneven_lines(configurations: Sequence[Configuration]) -> list[str]:
    """Markdown: the wagons loaded 60/40, as commissioned at 60/40, commissioned even, and not at all."""
    out = ["| 60/40 loading | " + " | ".join(f"{c.mode}, {'sister' if c.sister else 'alone'}" for c in configurations) + " |"]
    out.append("|---|" + "---|" * len(configurations))
    rows: list[tuple[str, str, str | None]] = [
        ("healthy, commissioned at 60/40: CONFIRMED / runs with a SUSPECTED", "uneven-healthy", "uneven"),
        ("healthy, commissioned even, now 60/40: CONFIRMED / runs with a SUSPECTED", "uneven-healthy", "even"),
        ("healthy, uncommissioned: CONFIRMED / runs with a SUSPECTED", "uneven-healthy", "none"),
    ]
    for label, role, setup in rows:
        cells = []
        for c in configurations:
            h = healthy(select(c, role, setup))
            cells.append(f"{h.confirmed} / {h.suspected_runs} of {h.runs}" if h.runs else "-")
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    from bogiemon.lab.sister.score import confirmed  # the count of confirmed faults

    for label, setup in (("broken springs, commissioned at 60/40: confirmed on their bogie", "uneven"), ("broken springs, uncommissioned: confirmed on their bogie", "none")):
        cells = [confirmed(select(c, "uneven-fault", setup)).text() for c in configurations]
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    out += ["", "| a damaged sensor on one bogie | " + " | ".join(f"{c.mode}, {'sister' if c.sister else 'alone'}" for c in configurations) + " |"]
    out.append("|---|" + "---|" * len(configurations))
    found = [sensor_runs(select(c, "sensor")) for c in configurations]
    for label, attr in (
        ("runs with a suspension event on either bogie", "suspension"), ("of them on the healthy bogie", "other_bogie"),
        ("the sensor fault reported on the damaged bogie", "reported"),
    ):  # fmt: skip
        out.append(f"| {label} | " + " | ".join(f"{getattr(f, attr)}/{f.runs}" for f in found) + " |")
    return out + [""]


def guard_table(stretches: Sequence[Stretch]) -> list[str]:
    """Markdown: per model and fleet, the healthy commissionings' largest distance and the share of
    faulty ones refused, per fault group, by the sister guard and the one-bogie guard."""
    out = ["| model | fleet | healthy: largest sister sd (refused) | healthy: largest own sd (refused) | " + " | ".join(f"{g}: refused by the sister / alone" for g in GROUPS) + " |"]
    out.append("|---|---|---|---|" + "---|" * len(GROUPS))
    for model in sorted({s.model for s in stretches}):
        for fleet in ("training", "evaluation"):
            mine = [s for s in stretches if s.model == model and s.fleet == fleet]
            if not mine:
                continue
            ok = [s for s in mine if s.group is None]
            own_max = max((max(x for x in s.own_sd if math.isfinite(x)) for s in ok), default=math.nan)
            cells = []
            for g in GROUPS:
                bad = [s for s in mine if s.group == g]
                own = sum(s.own_refused[s.bogie - 1] for s in bad)
                cells.append(f"{sum(s.sister_refused for s in bad)}/{len(bad)} / {own}/{len(bad)}" if bad else "-")
            out.append(
                f"| {model.upper()} | {fleet} | {_f(max(s.sister_sd for s in ok), 1)} ({sum(s.sister_refused for s in ok)}/{len(ok)}) | "
                f"{_f(own_max, 1)} ({sum(any(s.own_refused) for s in ok)}/{len(ok)}) | " + " | ".join(cells) + " |"
            )
    return out + [""]


def write_report(
    out_dir: str | Path,
    rows: Sequence[FeatureRow],
    chosen: Mapping[str, Sequence[str]],
    steps: Sequence[Step],
    configurations: Sequence[Configuration],
    stretches: Sequence[Stretch],
    header: Sequence[str],
    extra: Mapping[str, Any],
) -> list[Path]:
    """docs/wagon/tables.md, results.json and figures/*.png."""
    out = Path(out_dir)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    lines = [*header, "", "## Features: the other bogie as the reference, or each bogie's own", "", *feature_table(rows, chosen)]
    lines += ["## The sister's features, chosen on the training fleets", "", "Share of fault windows above the healthy windows' 99.9th percentile of the score.", "", *selection_table(steps)]
    if configurations:
        lines += ["## The wagon judge on the held-out wagons", "", *evaluation_table(configurations)]
    if stretches:
        lines += ["## The commissioning guard", "", *guard_table(stretches)]
    written = [out / "tables.md", out / "results.json"]
    write_text_atomically(written[0], "\n".join(lines) + "\n")
    results = {
        **extra,
        "chosen": {load: list(names) for load, names in chosen.items()},
        "selection": [{"load": s.load, "features": list(s.features), "score": s.score, "shares": s.shares} for s in steps],
        "features": rows_as_dicts(rows),
        "evaluation": [
            {"model": c.model, "mode": c.mode, "sister": c.sister, "targets": {t.name: vars(t.measure(c)) for t in TARGETS}} for c in configurations
        ],
        "guard": [vars(s) for s in stretches],
    }
    write_text_atomically(written[1], json.dumps(results, indent=1, default=_plain) + "\n")
    if rows:
        written.append(_figure(rows, out / "figures" / "features.png"))
    return written


def _plain(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    raise TypeError(f"not JSON: {type(x)}")


def _figure(rows: Sequence[FeatureRow], path: Path) -> Path:
    """Per model and load: each feature's spread ratio (alone / difference) and its broken springs'
    standard score as a difference over the one alone, both on log scales."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = sorted({r.model for r in rows})
    fig, axes = plt.subplots(len(models), 2, figsize=(14, 3.6 * len(models)), squeeze=False)
    for i, model in enumerate(models):
        for j, load in enumerate(("full", "tare")):
            mine = [r for r in rows if r.model == model and r.load == load]
            ax = axes[i][j]
            x = np.arange(len(mine))
            ax.bar(x - 0.2, [r.ratio for r in mine], 0.4, label="spread alone / difference")
            ax.bar(x + 0.2, [r.gain("broken spring") for r in mine], 0.4, label="broken springs: z difference / z alone")
            ax.axhline(1.0, color="k", lw=0.8)
            ax.set_yscale("log")
            ax.set_xticks(x, [r.feature for r in mine], rotation=90, fontsize=6)
            ax.set_title(f"model {model.upper()}, {load}")
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
