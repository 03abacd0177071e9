"""Small helpers shared by the benchmarks: repeated timing with median, min and max."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Timing:
    median_s: float
    min_s: float
    max_s: float
    runs: int


def time_runs(fn: Callable[[], object], runs: int) -> Timing:
    """Wall-clock seconds of `runs` calls of fn (after one untimed warm-up call)."""
    fn()
    seconds = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        seconds.append(time.perf_counter() - t0)
    return Timing(statistics.median(seconds), min(seconds), max(seconds), runs)
