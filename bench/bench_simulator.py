"""Benchmark of the simulator: one scenario and a batch, in x real time, and numba's compile time.

Figures (median of several runs, min and max): one scenario on one thread, and the per-scenario
speed of a batch on every core as a ratio against the single scenario measured in the same run;
and the first-call cost in a fresh process, compiling the kernel (an empty NUMBA_CACHE_DIR)
against loading it from the cache. The same for model B (simulator/model_b), its single scenario
also as a ratio against model A's and against its budget (300x real time per core).
Run with `make bench-simulator` or `.venv/bin/python bench/bench_simulator.py [--runs R]`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numba

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import Figure, table, time_interleaved  # noqa: E402

from bogiemon.simulator.run import simulate, simulate_batch  # noqa: E402
from bogiemon.simulator.scenario import Scenario  # noqa: E402
from bogiemon.simulator.suspension import parse_fault  # noqa: E402

COMMAND = "make bench-simulator"
_FIRST_CALL = (
    "import time; t = time.perf_counter(); from bogiemon.simulator.run import simulate; "
    "from bogiemon.simulator.scenario import Scenario; simulate(Scenario(duration_s=1.0)); "
    "print(time.perf_counter() - t)"
)


def first_call_s(cache_dir: str) -> float:
    env = {**os.environ, "NUMBA_CACHE_DIR": cache_dir}
    out = subprocess.run([sys.executable, "-c", _FIRST_CALL], env=env, check=True, capture_output=True, text=True)
    return float(out.stdout.strip())


def compile_figures(runs: int) -> list[Figure]:
    """Seconds to the first simulated second in a fresh process: compiling, then from the cache."""
    compile_s: list[float] = []
    cached_s: list[float] = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as cold:
            compile_s.append(first_call_s(cold))
            cached_s.append(first_call_s(cold))
    cached = Figure.of("simulator_first_call_cached_s", "simulator first call, fresh process, kernel cached", "s",
                       cached_s, COMMAND, higher_is_better=False)  # fmt: skip
    compiling = Figure.of("simulator_first_call_compile_s", "simulator first call, fresh process, empty numba cache", "s",
                     compile_s, COMMAND, higher_is_better=False)  # fmt: skip
    return [compiling.compare(cached), cached]


def speed_figures(runs: int, duration_s: float, batch_n: int) -> list[Figure]:
    """x real time of one scenario (one thread) and per scenario in a batch (every thread)."""
    broken = (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    single = Scenario(duration_s=duration_s, faults=broken)
    batch = [Scenario(duration_s=duration_s, seed=s, faults=broken if s % 2 else ()) for s in range(batch_n)]
    threads = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]  # numba.config sets its options at import

    def one_thread() -> None:
        numba.set_num_threads(1)
        simulate(single)
        numba.set_num_threads(threads)

    single_s, batch_s = time_interleaved([one_thread, lambda: simulate_batch(batch)], runs)
    one = Figure.of("simulate_single_x_realtime", f"simulate, one {duration_s:g} s scenario, one thread", "x real time",
                    [duration_s / s for s in single_s], COMMAND)  # fmt: skip
    per = Figure.of("simulate_batch_x_realtime", f"simulate, per scenario in a batch of {batch_n}, {threads} threads",
                    "x real time", [duration_s * batch_n / s for s in batch_s], COMMAND)  # fmt: skip
    return [one, per.compare(one)]


# Model B ------------------------------------------------------------------------------------------

# Hundreds of 10-minute runs on 2 cores in an evening: at least 300x real time per core.
MODEL_B_TARGET_X_REALTIME = 300.0
_FIRST_CALL_B = _FIRST_CALL.replace("Scenario(duration_s=1.0)", "Scenario(model='b', duration_s=1.0)")


def model_b_speed_figures(runs: int, duration_s: float, batch_n: int) -> list[Figure]:
    """Model B: x real time of one scenario (one thread, against model A's), and per scenario in a batch."""
    broken = (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    single_a = Scenario(duration_s=duration_s, faults=broken)
    single_b = Scenario(model="b", duration_s=duration_s, faults=broken)
    batch = [Scenario(model="b", duration_s=duration_s, seed=s, faults=broken if s % 2 else ()) for s in range(batch_n)]
    threads = numba.config.NUMBA_NUM_THREADS  # type: ignore[attr-defined]  # numba.config sets its options at import

    def one_thread(scenario: Scenario) -> None:
        numba.set_num_threads(1)
        simulate(scenario)
        numba.set_num_threads(threads)

    a_s, b_s, batch_s = time_interleaved([lambda: one_thread(single_a), lambda: one_thread(single_b), lambda: simulate_batch(batch)], runs)
    one_a = Figure.of("simulate_single_x_realtime_a_ref", f"model A, one {duration_s:g} s scenario, one thread (reference)",
                      "x real time", [duration_s / s for s in a_s], COMMAND)  # fmt: skip
    one_b = Figure.of("simulate_b_single_x_realtime", f"model B, one {duration_s:g} s scenario, one thread", "x real time",
                      [duration_s / s for s in b_s], COMMAND, target=MODEL_B_TARGET_X_REALTIME)  # fmt: skip
    per = Figure.of("simulate_b_batch_x_realtime", f"model B, per scenario in a batch of {batch_n}, {threads} threads",
                    "x real time", [duration_s * batch_n / s for s in batch_s], COMMAND)  # fmt: skip
    return [one_a, one_b.compare(one_a), per.compare(one_b)]


def model_b_compile_figures(runs: int) -> list[Figure]:
    """Model B's first call in a fresh process: compiling its kernel, then from the cache."""
    compile_s: list[float] = []
    cached_s: list[float] = []
    for _ in range(runs):
        with tempfile.TemporaryDirectory() as cold:
            env = {**os.environ, "NUMBA_CACHE_DIR": cold}
            for out in (compile_s, cached_s):
                done = subprocess.run([sys.executable, "-c", _FIRST_CALL_B], env=env, check=True, capture_output=True, text=True)
                out.append(float(done.stdout.strip()))
    cached = Figure.of("simulator_b_first_call_cached_s", "model B first call, fresh process, kernels cached", "s",
                       cached_s, COMMAND, higher_is_better=False)  # fmt: skip
    compiling = Figure.of("simulator_b_first_call_compile_s", "model B first call, fresh process, empty numba cache", "s",
                     compile_s, COMMAND, higher_is_better=False)  # fmt: skip
    return [compiling.compare(cached), cached]


def figures(runs: int = 5, duration_s: float = 120.0, batch_n: int = 16) -> list[Figure]:
    return (
        speed_figures(runs, duration_s, batch_n)
        + compile_figures(max(1, runs // 3))
        + model_b_speed_figures(runs, duration_s, batch_n)
        + model_b_compile_figures(max(1, runs // 3))
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=5, help="timed runs per figure (default 5)")
    parser.add_argument("--duration-s", type=float, default=120.0, help="simulated seconds per scenario (default 120)")
    parser.add_argument("--batch", type=int, default=16, help="scenarios in the batch (default 16)")
    args = parser.parse_args()
    print(f"# 500 Hz output, 0.25 ms step, full load, 80 km/h, ERRI low level; {os.cpu_count()} cores, numba {numba.__version__}")
    print(table(figures(args.runs, args.duration_s, args.batch)))


if __name__ == "__main__":
    main()
