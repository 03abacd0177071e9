"""Helpers shared by the benchmarks: repeated timing, figures with median/min/max, the table.

A Figure is one line of the benchmark table: what was measured, its unit, the median over the
runs with the min and max, and, where it is a comparison, the ratio against a baseline figure
measured in the same run (`compare`). Every benchmark module returns Figures from a function;
bench/suite.py collects them into one table and a JSON file, and each module's own main()
prints the table of its part.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace


@dataclass(frozen=True)
class Timing:
    median_s: float
    min_s: float
    max_s: float
    runs: int


def time_each(fn: Callable[[], object], runs: int) -> list[float]:
    """Wall-clock seconds of each of `runs` calls of fn (after one untimed warm-up call)."""
    fn()
    seconds = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        seconds.append(time.perf_counter() - t0)
    return seconds


def time_interleaved(fns: Sequence[Callable[[], object]], runs: int) -> list[list[float]]:
    """Wall-clock seconds of each fn, `runs` rounds of one call each in turn (after a warm-up call
    each): a figure and its baseline then see the same machine, even when its load changes."""
    for fn in fns:
        fn()
    seconds: list[list[float]] = [[] for _ in fns]
    for _ in range(runs):
        for fn, out in zip(fns, seconds, strict=True):
            t0 = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t0)
    return seconds


def time_runs(fn: Callable[[], object], runs: int) -> Timing:
    """Median, min and max wall-clock seconds of `runs` calls of fn (after a warm-up call)."""
    seconds = time_each(fn, runs)
    return Timing(statistics.median(seconds), min(seconds), max(seconds), runs)


@dataclass(frozen=True)
class Figure:
    """One measured figure: the median of `runs` values, with their min and max.

    higher_is_better says which way the figure improves (x real time, frames/s: up; CPU
    seconds, MB, latency: down). ratio is this figure's median over the baseline's, set by
    compare() with the baseline measured in the same run; vs names that baseline.
    """

    key: str  # stable identifier, for the JSON and for comparing runs
    what: str
    unit: str
    median: float
    min: float
    max: float
    runs: int
    command: str  # the make target (or script) that measures it
    higher_is_better: bool = True
    target: float | None = None  # the figure's budget, where it has one (same unit)
    vs: str | None = None  # the baseline's key
    ratio: float | None = None  # median / the baseline's median
    note: str = ""

    @classmethod
    def of(cls, key: str, what: str, unit: str, values: Sequence[float], command: str, **extra: object) -> Figure:
        if not values:
            raise ValueError(f"figure {key}: no values measured")
        return cls(key, what, unit, statistics.median(values), min(values), max(values), len(values), command, **extra)  # type: ignore[arg-type]

    def compare(self, baseline: Figure) -> Figure:
        """This figure with its ratio against a baseline of the same unit."""
        if baseline.unit != self.unit:
            raise ValueError(f"{self.key} ({self.unit}) cannot be compared with {baseline.key} ({baseline.unit})")
        return replace(self, vs=baseline.key, ratio=self.median / baseline.median)

    @property
    def meets_target(self) -> bool | None:
        if self.target is None:
            return None
        return self.median >= self.target if self.higher_is_better else self.median <= self.target


def format_value(value: float, unit: str) -> str:
    """A value in its unit, rounded as the table shows it (thin groups of thousands)."""
    if abs(value) >= 1e6:
        text = f"{value / 1e6:.1f} M"
    elif abs(value) >= 100:
        text = f"{value:,.0f}".replace(",", " ") + " "
    elif abs(value) >= 10:
        text = f"{value:.1f} "
    else:
        text = f"{value:.3g} "
    return text + unit if not text.endswith("M") else f"{text} {unit}".strip()


def _comparison(figure: Figure, by_key: dict[str, Figure]) -> str:
    parts = []
    if figure.ratio is not None and figure.vs is not None:
        baseline = by_key.get(figure.vs)
        name = baseline.what if baseline is not None else figure.vs
        parts.append(f"{figure.ratio:.2f}x {name}")
    if figure.target is not None:
        share = figure.median / figure.target
        verdict = "met" if figure.meets_target else "MISSED"
        parts.append(f"target {'>=' if figure.higher_is_better else '<='} {format_value(figure.target, figure.unit)}: {verdict} ({share:.0%})")
    if figure.note:
        parts.append(figure.note)
    return "; ".join(parts)


def table(figures: Sequence[Figure]) -> str:
    """The figures as one Markdown table (readable in a terminal, pasted as is in the README)."""
    by_key = {f.key: f for f in figures}
    rows = [("what", "median", "min .. max", "runs", "against the baseline / target", "command")]
    for f in figures:
        spread = f"{format_value(f.min, '').strip()} .. {format_value(f.max, '').strip()}"
        rows.append((f.what, format_value(f.median, f.unit), spread, str(f.runs), _comparison(f, by_key), f"`{f.command}`"))
    widths = [max(len(r[c]) for r in rows) for c in range(len(rows[0]))]
    lines = ["| " + " | ".join(cell.ljust(w) for cell, w in zip(r, widths, strict=True)) + " |" for r in rows]
    lines.insert(1, "|" + "|".join("-" * (w + 2) for w in widths) + "|")
    return "\n".join(lines)
