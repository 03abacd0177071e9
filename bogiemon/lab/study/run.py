"""Running the study: every run of a plan simulated, then every window's indicators from the
detection core, at each of the plan's window lengths."""

from __future__ import annotations

import dataclasses
import os
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings
from bogiemon.lab.study.plan import INDICATORS, THRESHOLD_GROUPS, StudyPlan, StudyRun

Progress = Callable[[float], None]  # called with the fraction done, 0..1

# Measured on the 2-core development machine: simulated seconds per wall second of the batch
# kernel and of one IndicatorStream; only used to weigh the progress fraction.
_SIM_RATE = 2500.0
_ANALYSIS_RATE = 4500.0


@dataclass(frozen=True)
class WindowTable:
    """Every window of the study at one window length: its run, its place in the run, its indicators."""

    run: NDArray[np.int64]  # index into StudyResult.runs
    position: NDArray[np.int64]  # 0, 1, ... in hop order within the run
    values: NDArray[np.float64]  # (n, 8), columns in INDICATORS order
    excitation_mps2: NDArray[np.float64]  # median of the three channels' RMS: the daemon's excitation gate


@dataclass(frozen=True)
class StudyResult:
    """Every run of a plan and every window's indicators; the analyses below take it as it is."""

    plan: StudyPlan
    settings: ProcessingSettings  # the default settings (the config's); window lengths vary
    geometry: BogieGeometry
    runs: tuple[StudyRun, ...]
    windows: Mapping[float, WindowTable]  # window_s -> windows
    simulated_s: float
    elapsed_s: float
    cpu_count: int

    @property
    def default_window_s(self) -> float:
        return self.settings.window_s

    @property
    def min_excitation_rms_mps2(self) -> float:
        """The main matrix's smallest median channel RMS of any window (the daemon gates below 0.3)."""
        table = self.windows[self.default_window_s]
        return float(table.excitation_mps2[self.run_mask(group="")[table.run]].min())

    def run_mask(self, **where: Any) -> NDArray[np.bool_]:
        """Runs matching every given attribute: group, load, key, severity, condition, rep (a set or a value)."""
        mask = np.ones(len(self.runs), dtype=bool)
        for name, wanted in where.items():
            accepted = wanted if isinstance(wanted, set | frozenset) else {wanted}
            mask &= np.array([_run_attribute(r, name) in accepted for r in self.runs])
        return mask

    def values(self, window_s: float, **where: Any) -> NDArray[np.float64]:
        """(n, 8): the indicators of every window of the matching runs at one window length."""
        table = self.windows[window_s]
        return table.values[self.run_mask(**where)[table.run]]


def _run_attribute(run: StudyRun, name: str) -> Any:
    if name in ("load", "key", "severity"):
        return getattr(run.case, name)
    if name == "parity":
        return run.rep % 2
    return getattr(run, name)


def window_settings(plan: StudyPlan, settings: ProcessingSettings) -> dict[float, ProcessingSettings]:
    """The processing settings of every window length the plan analyses (the plan's and the
    settings' own). Raises ValueError for one that does not fit the hop, the lags or the runs."""
    out = {}
    for w in sorted({*plan.window_lengths_s, settings.window_s}):
        s = dataclasses.replace(settings, window_s=w)
        if s.window_n % s.hop_n or s.max_lag_n >= s.window_n:
            raise ValueError(f"window {w:g} s must be a whole number of hops ({s.hop_s:g} s) and longer than the lags ({s.max_lag_s:g} s)")
        if w >= plan.duration_s:
            raise ValueError(f"window {w:g} s must be shorter than the runs ({plan.duration_s:g} s)")
        out[w] = s
    return out


def run_study(
    plan: StudyPlan,
    settings: ProcessingSettings,
    geometry: BogieGeometry,
    progress: Progress | None = None,
    batch_size: int = 24,
) -> StudyResult:
    """Simulate every run of the plan and compute every window's indicators with the detection core.

    `settings` are the processing settings of the report (the config's); the main matrix's and the
    envelope's runs are also analysed at each of the plan's window lengths (hop and everything
    else unchanged), the sensitivity runs at settings.window_s only. Raises ValueError for a
    window length that does not fit the hop, the lags or the runs.
    """
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when running

    per_window = window_settings(plan, settings)
    windows_s = sorted(per_window)
    runs = plan.runs()
    names = [r.name + "|" + r.group + "|" + r.corner.value for r in runs]
    assert len(set(names)) == len(names), "two runs of the plan are the same run"

    def analysed(run: StudyRun) -> list[float]:
        return windows_s if run.group in THRESHOLD_GROUPS else [settings.window_s]

    cost = [plan.duration_s * (1 / _SIM_RATE + len(analysed(r)) / _ANALYSIS_RATE) for r in runs]
    total_cost, done_cost = sum(cost), 0.0
    rows: dict[float, tuple[list[int], list[int], list[NDArray[np.float64]], list[float]]] = {w: ([], [], [], []) for w in windows_s}
    started = time.perf_counter()
    for first in range(0, len(runs), batch_size):
        batch = range(first, min(first + batch_size, len(runs)))
        sim_share = sum(plan.duration_s / _SIM_RATE for _ in batch) / total_cost

        def report(fraction: float, base: float = done_cost / total_cost, share: float = sim_share) -> None:
            if progress is not None:
                progress(min(1.0, base + share * fraction))

        scenarios = [runs[i].scenario(plan.duration_s, settings.fs_hz, geometry, plan.noise_mps2) for i in batch]
        results = simulate_batch(scenarios, report)
        done_cost += sim_share * total_cost
        for i, result in zip(batch, results, strict=True):
            for w in analysed(runs[i]):
                found = IndicatorStream(per_window[w], geometry).process(result.accel_mps2)
                run_ids, positions, values, excitation = rows[w]
                run_ids += [i] * len(found)
                positions += range(len(found))
                values.append(np.array([[getattr(x, n) for n in INDICATORS] for x in found]))
                excitation += [float(np.median(x.rms_mps2)) for x in found]
            done_cost += cost[i] - plan.duration_s / _SIM_RATE
            if progress is not None:
                progress(min(1.0, done_cost / total_cost))
    tables = {
        w: WindowTable(np.array(r, dtype=np.int64), np.array(p, dtype=np.int64), np.concatenate(v), np.array(e))
        for w, (r, p, v, e) in rows.items()
    }
    return StudyResult(
        plan=plan,
        settings=settings,
        geometry=geometry,
        runs=runs,
        windows=tables,
        simulated_s=plan.duration_s * len(runs),
        elapsed_s=time.perf_counter() - started,
        cpu_count=os.cpu_count() or 1,
    )
