"""Benchmark of the detection core: streaming core vs the naive baseline, and `analyze` on a file.

Figures in x real time (median of several runs, with min and max): the streaming core at 500 Hz
and 1 kHz in 1 s blocks, as a live source delivers them, against the naive baseline timed in
turn with it in the same run (bench/baseline.py: scipy.signal.correlate over every whole window at every hop),
and `bogiemon analyze` on a one-hour 500 Hz recording as a whole process (start-up, reading and
parsing included), as CSV and as Parquet (the same samples), timed in turn run by run, against
the issue's target. The core also computes what the baseline does not (channel statistics, band
spectra): the ratio is a lower bound of the correlation's own speed-up.
Run with `make bench-core` or `.venv/bin/python bench/bench_core.py [--minutes M] [--runs R]`.
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
from timing import Figure, table, time_each, time_interleaved  # noqa: E402

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


def analyze_figures(runs: int) -> list[Figure]:
    """`bogiemon analyze` on one hour at 500 Hz, the whole process, x real time: the recording as CSV
    and the same samples (those the CSV holds) as Parquet, timed in turn; Parquet against CSV."""
    fs_hz, data_s = 500.0, 3600.0
    with tempfile.TemporaryDirectory() as tmp:
        csv_path, parquet_path = Path(tmp) / "one_hour.csv", Path(tmp) / "one_hour.parquet"
        accel = synthetic_accel(data_s, fs_hz, seed=1)
        write_csv_recording(csv_path, np.arange(accel.shape[0]) / fs_hz, accel)
        samples = read_recording(csv_path)
        write_parquet_recording(parquet_path, samples.time_s, samples.accel_mps2)
        commands = [[sys.executable, "-m", "bogiemon.daemon.cli.main", "analyze", str(path)] for path in (csv_path, parquet_path)]
        csv_s, parquet_s = time_interleaved(
            [lambda command=command: subprocess.run(command, check=True, stdout=subprocess.DEVNULL) for command in commands], runs
        )
    csv_figure = Figure.of("analyze_1h_x_realtime", "`bogiemon analyze`, one-hour 500 Hz CSV, whole process", "x real time",
                           [data_s / s for s in csv_s], COMMAND, target=ANALYZE_TARGET_X_REALTIME)  # fmt: skip
    parquet_figure = Figure.of("analyze_1h_parquet_x_realtime", "`bogiemon analyze`, the same hour as Parquet, whole process", "x real time",
                               [data_s / s for s in parquet_s], COMMAND, target=ANALYZE_TARGET_X_REALTIME)  # fmt: skip
    return [csv_figure, parquet_figure.compare(csv_figure)]


def figures(minutes: float = 10.0, runs: int = 7) -> list[Figure]:
    out = []
    for fs_hz in (500.0, 1000.0):
        out += core_figures(minutes, runs, fs_hz)
    out += analyze_figures(max(3, runs // 2))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of data for the core (default 10)")
    parser.add_argument("--runs", type=int, default=7, help="timed runs per figure (default 7)")
    args = parser.parse_args()
    print(table(figures(args.minutes, args.runs)))


if __name__ == "__main__":
    main()
