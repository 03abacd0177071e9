"""Benchmark of the simulator: one scenario and a batch, in x real time, and numba's compile time.

Prints the median of several runs with min and max, the batch's per-scenario speed as a ratio
against the single scenario measured in the same run, and the first-call cost of compiling the
kernel (a fresh process with an empty NUMBA_CACHE_DIR) against loading it from the cache.
Run with `make bench-simulator` or `.venv/bin/python bench/bench_simulator.py [--runs R]`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import Timing, time_runs  # noqa: E402

from bogiemon.simulator.run import simulate, simulate_batch  # noqa: E402
from bogiemon.simulator.scenario import Scenario  # noqa: E402
from bogiemon.simulator.suspension import parse_fault  # noqa: E402

_FIRST_CALL = (
    "import time; t = time.perf_counter(); from bogiemon.simulator.run import simulate; "
    "from bogiemon.simulator.scenario import Scenario; simulate(Scenario(duration_s=1.0)); "
    "print(time.perf_counter() - t)"
)


def fmt(label: str, t: Timing, simulated_s: float) -> str:
    return (
        f"{label:<52} {simulated_s / t.median_s:8.0f}x real time "
        f"(min {simulated_s / t.max_s:.0f}x, max {simulated_s / t.min_s:.0f}x; median {t.median_s:.3f} s, {t.runs} runs)"
    )


def first_call_s(cache_dir: str) -> float:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True, capture_output=True, text=True)
    return float(out.stdout.strip())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--duration-s", type=float, default=120.0, help="simulated seconds per scenario (default 120)")
    parser.add_argument("--batch", type=int, default=16, help="scenarios in the batch (default 16)")
    args = parser.parse_args()
    duration = args.duration_s
    broken = (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    single = Scenario(duration_s=duration, faults=broken)
    batch = [Scenario(duration_s=duration, seed=s, faults=broken if s % 2 else ()) for s in range(args.batch)]

    print(f"# simulator: {duration:g} s scenarios at 500 Hz output, 0.25 ms step, full load, 80 km/h, ERRI low level")
    print(f"# {os.cpu_count()} cores, numba {numba.__version__}, {numba.get_num_threads()} threads for batches")
    with tempfile.TemporaryDirectory() as cold:
        compile_s = first_call_s(cold)
        cached_s = first_call_s(cold)
    print(f"{'first call in a fresh process, empty numba cache':<52} {compile_s:8.2f} s (compiling the kernel)")
    print(f"{'first call in a fresh process, kernel cached':<52} {cached_s:8.2f} s")

    numba.set_num_threads(1)
    t_single = time_runs(lambda: simulate(single), args.runs)
    print(fmt("one scenario, one thread", t_single, duration))
    numba.set_num_threads(numba.config.NUMBA_NUM_THREADS)
    t_batch = time_runs(lambda: simulate_batch(batch), args.runs)
    per_scenario = Timing(t_batch.median_s / len(batch), t_batch.min_s / len(batch), t_batch.max_s / len(batch), t_batch.runs)
    print(fmt(f"batch of {len(batch)}, per scenario, {numba.get_num_threads()} threads", per_scenario, duration))
    print(f"{'ratio batch / single, per scenario':<52} {t_single.median_s / per_scenario.median_s:8.1f}x faster")
    t0 = time.perf_counter()
    simulate_batch(batch)
    label = f"batch of {len(batch)} x {duration:g} s, wall clock"
    print(f"{label:<52} {time.perf_counter() - t0:8.2f} s")


if __name__ == "__main__":
    main()
