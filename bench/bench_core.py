"""Benchmark of the detection core: streaming core vs the naive baseline, and `analyze` on a file.

Figures in x real time (median of several runs, with min and max): the streaming core at 500 Hz
and 1 kHz in 1 s blocks, as a live source delivers them, against the naive baseline timed in
turn with it in the same run (bench/baseline.py: scipy.signal.correlate over every whole window at every hop),
and `bogiemon analyze` on a one-hour 500 Hz recording as a whole process (start-up, reading and
parsing included), as CSV, as .csv.gz and as Parquet (the same samples), timed in turn run by run,
against plain CSV and the issue's target; `--vs-python` times another tree's `analyze` (main's
interpreter: before and after) in the same rounds. The core also computes what the baseline does
not (channel statistics, band spectra): the ratio is a lower bound of the correlation's own speed-up.
Run with `make bench-core` or
`.venv/bin/python bench/bench_core.py [--minutes M] [--runs R] [--analyze-only] [--vs-python PYTHON]`.
"""

from __future__ import annotations

import argparse
import functools
import os
import resource
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import guard  # noqa: E402
from baseline import naive_indicators  # noqa: E402
from timing import Figure, time_interleaved  # noqa: E402

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings  # noqa: E402
from bogiemon.drivers.recording import read_recording, write_csv_recording, write_parquet_recording  # noqa: E402

COMMAND = "make bench-core"
# `bogiemon analyze` of an hour at 500 Hz, the whole process (the target: 1 070x before the
# recordings were read with pyarrow, 3.37 s, most of it numpy's loadtxt on the text).
ANALYZE_TARGET_X_REALTIME = 2000.0


def synthetic_accel(duration_s: float, fs_hz: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((int(duration_s * fs_hz), 3)) + 9.81


def run_core(accel: np.ndarray, settings: ProcessingSettings, block_n: int) -> np.ndarray:
    stream = IndicatorStream(settings, BogieGeometry())
    out = []
    for i in range(0, accel.shape[0], block_n):
        out += stream.process(accel[i : i + block_n])
    return np.array([w.raw for w in out])


def core_figures(minutes: float, runs: int, fs_hz: float) -> list[Figure]:
    """The core and the naive baseline at fs_hz, x real time; the core compared with the baseline."""
    settings = ProcessingSettings(fs_hz=fs_hz)
    data_s = minutes * 60
    accel = synthetic_accel(data_s, fs_hz)
    block_n = int(fs_hz)  # 1 s blocks, as a live source would deliver them
    fast, slow = run_core(accel, settings, block_n), naive_indicators(accel, settings, BogieGeometry())
    np.testing.assert_allclose(fast, slow, rtol=1e-8)  # same indicators, same answer
    core_s, naive_s = time_interleaved(
        [lambda: run_core(accel, settings, block_n), lambda: naive_indicators(accel, settings, BogieGeometry())], runs
    )
    rate = f"{fs_hz / 1000:g} kHz" if fs_hz >= 1000 else f"{fs_hz:.0f} Hz"
    naive = Figure.of(
        f"naive_{fs_hz:.0f}hz_x_realtime", f"naive baseline at {rate} (scipy.signal.correlate of every window)",
        "x real time", [data_s / s for s in naive_s], COMMAND,
    )  # fmt: skip
    core = Figure.of(
        f"core_{fs_hz:.0f}hz_x_realtime", f"detection core at {rate}, 1 s blocks, {minutes:g} min of data",
        "x real time", [data_s / s for s in core_s], COMMAND, note="the core also computes band spectra and channel statistics",
    ).compare(naive)  # fmt: skip
    return [core, naive]


def analyze_figures(runs: int, vs_python: str | None = None) -> list[Figure]:
    """`bogiemon analyze` on one hour at 500 Hz, the whole process, x real time: the recording as
    plain CSV (the baseline: the issue's figure), as .csv.gz (what the recorder writes) and the
    same samples (those the CSV holds) as Parquet, timed in turn run by run. With vs_python (another
    tree's interpreter, e.g. main's .venv/bin/python), that tree's `analyze` of each file is timed
    in the same rounds, and each figure is compared with its own."""
    fs_hz, data_s = 500.0, 3600.0
    # The figures' names as the README's table has them.
    formats = (("csv", "one-hour 500 Hz CSV"), ("csv.gz", "the same hour as .csv.gz"), ("parquet", "the same hour as Parquet"))
    with tempfile.TemporaryDirectory() as tmp:
        paths = {suffix: Path(tmp) / f"one_hour.{suffix}" for suffix, _ in formats}
        accel = synthetic_accel(data_s, fs_hz, seed=1)
        write_csv_recording(paths["csv"], np.arange(accel.shape[0]) / fs_hz, accel)
        samples = read_recording(paths["csv"])
        write_csv_recording(paths["csv.gz"], samples.time_s, samples.accel_mps2)
        write_parquet_recording(paths["parquet"], samples.time_s, samples.accel_mps2)
        pythons = [sys.executable] + ([vs_python] if vs_python else [])
        commands = [[python, "-m", "bogiemon.cli.main", "analyze", str(paths[suffix])] for suffix, _ in formats for python in pythons]
        # pyarrow's bare read of the same files, whole process: the floor under any reader of them.
        bare = [[sys.executable, "-c", BARE_READ[suffix], str(paths[suffix])] for suffix in ("csv", "parquet")]
        # From a folder without a bogiemon/ in it: each interpreter imports its own tree.
        cpu: list[list[float]] = [[] for _ in (*commands, *bare)]
        runners = [functools.partial(_child_cpu_s, command, tmp, into) for command, into in zip((*commands, *bare), cpu, strict=True)]
        seconds = time_interleaved(runners, runs)
        cpu = [c[1:] for c in cpu]  # the warm-up's left out, as time_interleaved leaves it out
    out: list[Figure] = []
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    for k, (suffix, name) in enumerate((("csv", "CSV"), ("parquet", "Parquet"))):
        key = "analyze_1h_cpu_s" if suffix == "csv" else "analyze_1h_parquet_cpu_s"
        floor = Figure.of(f"pyarrow_read_1h_{suffix}_cpu_s", f"  pyarrow's bare read of the same {name} file, whole process", "CPU s",
                          cpu[len(commands) + k], COMMAND, higher_is_better=False)  # fmt: skip
        ours = Figure.of(key, f"`bogiemon analyze` of the hour as {name}, whole process, CPU (guarded)", "CPU s",
                         cpu[formats.index(next(f for f in formats if f[0] == suffix)) * len(pythons)], COMMAND, higher_is_better=False,
                         target=3600.0 / ANALYZE_TARGET_X_REALTIME, note=f"load average {load}").compare(floor)  # fmt: skip
        out += [ours, floor]
    plain_csv: Figure | None = None  # the x-real-time figures' baseline
    for k, (suffix, name) in enumerate(formats):
        key = "analyze_1h" if suffix == "csv" else f"analyze_1h_{suffix.replace('.', '_')}"
        ours = Figure.of(f"{key}_x_realtime", f"`bogiemon analyze`, {name}, whole process", "x real time",
                         [data_s / s for s in seconds[k * len(pythons)]], COMMAND, target=ANALYZE_TARGET_X_REALTIME)  # fmt: skip
        if vs_python:
            theirs = Figure.of(f"{key}_vs_x_realtime", f"  the same with {vs_python}", "x real time",
                               [data_s / s for s in seconds[k * len(pythons) + 1]], COMMAND)  # fmt: skip
            out += [ours.compare(theirs), theirs]
        elif plain_csv is None:
            out.append(plain_csv := ours)
        else:
            out.append(ours.compare(plain_csv))
    return out


# pyarrow's own read of a recording, nothing else: `python -c CODE FILE`.
BARE_READ = {
    "csv": "import sys, pyarrow.csv as c; c.read_csv(sys.argv[1])",
    "parquet": "import sys, pyarrow.parquet as q; q.read_table(sys.argv[1])",
}


def _child_cpu_s(command: list[str], cwd: str, into: list[float]) -> None:
    """Run a command; append the CPU seconds (user + system, all its threads) it took."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, cwd=cwd)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    into.append(after.ru_utime - before.ru_utime + after.ru_stime - before.ru_stime)


def figures(minutes: float = 10.0, runs: int = 7, vs_python: str | None = None, only_analyze: bool = False) -> list[Figure]:
    out = []
    if not only_analyze:
        for fs_hz in (500.0, 1000.0):
            out += core_figures(minutes, runs, fs_hz)
    out += analyze_figures(max(3, runs // 2), vs_python)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of data for the core (default 10)")
    parser.add_argument("--runs", type=int, default=7, help="timed runs per figure (default 7)")
    parser.add_argument("--analyze-only", action="store_true", help="only `bogiemon analyze` of the one-hour files")
    parser.add_argument("--vs-python", metavar="PYTHON", help="also time another tree's analyze in the same rounds (e.g. ../main/.venv/bin/python)")
    parser.add_argument("--record", action="store_true", help="append the guarded figures to bench/results/records.json (the guard's baseline)")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record figures that missed their target too")
    args = parser.parse_args()
    measured = figures(args.minutes, args.runs, args.vs_python, args.analyze_only)
    outcome = guard.check(measured, shlex.join(["bench/bench_core.py", *sys.argv[1:]]), record=args.record, accept_worse=args.accept_worse)
    return outcome.shown()


if __name__ == "__main__":
    sys.exit(main())
