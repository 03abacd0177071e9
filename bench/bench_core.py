"""Benchmark of the detection core: streaming core vs the naive baseline, and `analyze` on a file.

Prints x-real-time figures (median of several runs, with min and max) and the ratio of the core
against the baseline measured in the same run. Run with `make bench-core` or
`.venv/bin/python bench/bench_core.py [--minutes M] [--runs R]`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from baseline import naive_indicators  # noqa: E402
from timing import Timing, time_runs  # noqa: E402

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402


def synthetic_accel(duration_s: float, fs_hz: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((int(duration_s * fs_hz), 3)) + 9.81


def run_core(accel: np.ndarray, settings: ProcessingSettings, block_n: int) -> np.ndarray:
    stream = IndicatorStream(settings, BogieGeometry())
    out = []
    for i in range(0, accel.shape[0], block_n):
        out += stream.process(accel[i : i + block_n])
    return np.array([w.raw for w in out])


def fmt(label: str, t: Timing, data_s: float) -> str:
    return (
        f"{label:<44} {data_s / t.median_s:10.0f}x real time "
        f"(min {data_s / t.max_s:.0f}x, max {data_s / t.min_s:.0f}x; median {t.median_s * 1e3:.1f} ms, {t.runs} runs)"
    )


def bench_core(minutes: float, runs: int, fs_hz: float) -> None:
    settings = ProcessingSettings(fs_hz=fs_hz)
    data_s = minutes * 60
    accel = synthetic_accel(data_s, fs_hz)
    block_n = int(fs_hz)  # 1 s blocks, as a live source would deliver them
    fast, slow = run_core(accel, settings, block_n), naive_indicators(accel, settings, BogieGeometry())
    np.testing.assert_allclose(fast, slow, rtol=1e-8)  # same work, same answer
    core = time_runs(lambda: run_core(accel, settings, block_n), runs)
    naive = time_runs(lambda: naive_indicators(accel, settings, BogieGeometry()), max(3, runs // 2))
    print(fmt(f"core, {fs_hz:.0f} Hz, {minutes:g} min in 1 s blocks", core, data_s))
    print(fmt(f"naive baseline, {fs_hz:.0f} Hz", naive, data_s))
    print(f"{'ratio core / naive':<44} {naive.median_s / core.median_s:10.1f}x faster")


def bench_analyze(runs: int) -> None:
    fs_hz, data_s = 500.0, 3600.0
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "one_hour.csv"
        accel = synthetic_accel(data_s, fs_hz, seed=1)
        write_csv_recording(path, np.arange(accel.shape[0]) / fs_hz, accel)
        cmd = [sys.executable, "-m", "bogiemon.daemon.cli.main", "analyze", str(path)]
        t = time_runs(lambda: subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL), runs)
    print(fmt("bogiemon analyze, one-hour 500 Hz CSV", t, data_s))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of data for the core (default 10)")
    parser.add_argument("--runs", type=int, default=7, help="timed runs per figure (default 7)")
    args = parser.parse_args()
    for fs_hz in (500.0, 1000.0):
        bench_core(args.minutes, args.runs, fs_hz)
    bench_analyze(max(3, args.runs // 2))


if __name__ == "__main__":
    main()
