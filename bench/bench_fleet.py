"""The back office's throughput: `bogiemon fleet analyze` on 1 and 2 Dask workers, against `analyze`.

A fleet of W wagons x D days x R recordings of 10 min (four simulated runs, each placed many
times at its own day and time, gzip CSV as the recorder writes them) is analysed on a Dask
LocalCluster of one and of two single-threaded workers (the cluster started beforehand: its
start-up is not the analysis), every partition redone each time, the two interleaved run by run
so both see the same machine. Figures: wagon-hours of recording per core-second and per second,
the speed-up from 1 to 2 workers, and one recording's analysis in the fleet's task against
`bogiemon analyze --json` of the same file into a file (the baseline: the same reader and core,
every field of every window written, without the gateway's sensor checks and load estimate).
From the 2-worker figure: the largest fleet one machine of N cores analyses per day at one hour
of recording per wagon, and the core-hours per 10 000 wagon-days.

    .venv/bin/python bench/bench_fleet.py [--runs 3] [--wagons 16] [--days 2] [--recordings 2]
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import guard  # noqa: E402
from timing import Figure  # noqa: E402

COMMAND = "make bench-fleet"
RUN_S = 600.0
# Issue 29's target: wagon-hours of recording per core-second (0.121 at its start), on 1 worker
# and on each of 2.
PER_CORE_TARGET = 0.3
SPEEDUP_TARGET = 1.8  # from 1 to 2 workers (issue 36)


def _simulate_runs(folder: Path, n: int) -> list[Path]:
    from bogiemon.drivers.recording import write_csv_recording
    from bogiemon.simulator.run import simulate_batch
    from bogiemon.simulator.scenario import Scenario, SpeedProfile
    from bogiemon.simulator.sensors import SensorModel

    tracks = ("erri-low", "erri-high", "fra-5", "fra-4")
    scenarios = [
        Scenario(load="full" if i % 2 == 0 else "tare", speed=SpeedProfile(((0.0, 60.0 + 10 * i), (RUN_S, 100.0 - 10 * i))),
                 track=tracks[i % 4], duration_s=RUN_S, seed=100 + i,
                 sensor=SensorModel(noise_mps2=0.01, quantum_mps2=16 * 9.81 / 32768))
        for i in range(n)
    ]  # fmt: skip
    out = []
    for i, result in enumerate(simulate_batch(scenarios)):
        path = folder / f"run{i}.csv.gz"
        write_csv_recording(path, result.time_s, result.accel_mps2)
        out.append(path)
    return out


def build_fleet(root: Path, runs: list[Path], wagons: int, days: int, recordings: int) -> float:
    """The tree; returns its seconds of recording."""
    import datetime as dt

    from bogiemon.drivers.recording import read_csv_recording, write_csv_recording

    loaded = [read_csv_recording(p) for p in runs]
    start = dt.datetime(2026, 11, 2, tzinfo=dt.UTC).timestamp()
    total_s = 0.0
    for w in range(wagons):
        folder = root / f"31-80-{w:04d}"
        folder.mkdir(parents=True)
        (folder / "bogiemon.toml").write_text('[decision]\nload = "auto"\n', encoding="utf-8")
        for d in range(days):
            day = folder / time.strftime("%Y-%m-%d", time.gmtime(start + d * 86400))
            day.mkdir()
            for r in range(recordings):
                rec = loaded[(w + d + r) % len(loaded)]
                t0 = start + d * 86400 + 6 * 3600 + r * 5400
                path = day / f"{time.strftime('%H%M%S', time.gmtime(t0))}_run.csv.gz"
                # The same samples at another time: each file is read and analysed on its own.
                write_csv_recording(path, rec.time_s - rec.time_s[0] + t0, rec.accel_mps2)
                total_s += rec.duration_s
    return total_s


def _analyze_command(recording: Path, out: Path) -> None:
    """`bogiemon analyze --json FILE > out`, the command's own code: every field of every window
    written, as the fleet's partition holds them (the wagon's config, as the fleet task uses)."""
    import argparse
    import contextlib

    from bogiemon.cli import analyze

    config = recording.parent.parent / "bogiemon.toml"
    with out.open("w", encoding="utf-8") as f, contextlib.redirect_stdout(f):
        analyze.run(argparse.Namespace(files=[str(recording)], config=str(config), json=True))


def figures(runs: int = 3, wagons: int = 16, days: int = 2, recordings: int = 2) -> list[Figure]:
    from bogiemon.fleet.analyze import analyze_fleet, analyze_day, day_tasks, local_client
    from bogiemon.fleet.layout import scan_fleet

    with tempfile.TemporaryDirectory(prefix="bogiemon-bench-fleet-") as tmp:
        scratch = Path(tmp)
        (scratch / "runs").mkdir()
        sims = _simulate_runs(scratch / "runs", 4)
        recorded_s = build_fleet(scratch / "fleet", sims, wagons, days, recordings)
        wagon_hours = recorded_s / 3600.0
        fleet = scan_fleet(scratch / "fleet")

        # One recording: `bogiemon analyze --json` against the fleet's task of it, interleaved pair
        # by pair (each takes half a second: five pairs a run steady the medians).
        one = fleet.wagons[0].days[0].files[0]
        task = day_tasks(fleet, scratch / "one")[0]
        task = type(task)(task.wagon_id, task.date, task.midnight_s, (one,), task.config, task.digest, task.path)
        baseline, fleet_task = [], []
        for _ in range(5 * runs):
            t0 = time.perf_counter()
            _analyze_command(one.path, scratch / "analyze.jsonl")
            baseline.append(RUN_S / (time.perf_counter() - t0))
            t0 = time.perf_counter()
            analyze_day(task)
            fleet_task.append(RUN_S / (time.perf_counter() - t0))

        per_worker: dict[int, list[float]] = {1: [], 2: []}
        per_cpu: dict[int, list[float]] = {1: [], 2: []}  # wagon-h per CPU second of the workers and this process
        clients = {n: local_client(n) for n in (1, 2)}
        try:
            for n, client in clients.items():  # warm-up: imports in the workers
                analyze_fleet(scratch / "fleet", scratch / f"warm{n}", client=client)
            for _ in range(runs):
                for n, client in clients.items():
                    cpu0 = _cluster_cpu_s(client)
                    t0 = time.perf_counter()
                    analyze_fleet(scratch / "fleet", scratch / f"out{n}", client=client, redo=True)
                    per_worker[n].append(wagon_hours / (time.perf_counter() - t0))
                    per_cpu[n].append(wagon_hours / (_cluster_cpu_s(client) - cpu0))
        finally:
            for client in clients.values():
                cluster = client.cluster
                client.close()
                cluster.close()

    speedups = [b / a for a, b in zip(per_worker[1], per_worker[2], strict=True)]
    # On a loaded machine the wall clock says how busy the others were: what a worker costs is its
    # CPU. From CPU, the speed-up an idle machine gives is 2 x (CPU per wagon-hour on 1 worker over
    # that on 2): the work the second worker adds (scheduling, transfers), the tasks being alike.
    cpu_speedups = [2 * b / a for a, b in zip(per_cpu[1], per_cpu[2], strict=True)]
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    two = statistics.median(per_worker[2])
    cores = os.cpu_count() or 1
    # One hour of recording per wagon and day (the sizing): wagons per day a machine of
    # `cores` cores handles, scaling from 2 workers linearly (the tasks share nothing).
    per_core_s = two / 2
    wagons_per_day_per_core = per_core_s * 86_400
    core_hours_per_10k = 10_000 / per_core_s / 3600
    f_base = Figure.of("fleet.analyze_baseline", "`bogiemon analyze --json` of one 10-min recording", "x real time", baseline, COMMAND)
    f_task = Figure.of("fleet.task", "the fleet's task on the same recording (+ checks, Parquet)", "x real time", fleet_task, COMMAND, target=f_base.median).compare(f_base)
    f1 = Figure.of("fleet.one_worker", f"fleet analyze, 1 worker ({wagons} wagons x {days} days x {recordings} x 10 min)", "wagon-h/s", per_worker[1], COMMAND)
    f2 = Figure.of("fleet.two_workers", "fleet analyze, 2 workers", "wagon-h/s", per_worker[2], COMMAND, target=1.7 * f1.median).compare(f1)
    f_speed = Figure.of("fleet.speedup", "speed-up from 1 to 2 workers (wall clock)", "x", speedups, COMMAND, target=SPEEDUP_TARGET)
    f_core1 = Figure.of("fleet.per_core_one_worker", "throughput per core (1 worker)", "wagon-h/core-s", per_worker[1], COMMAND,
                        target=PER_CORE_TARGET)  # fmt: skip
    f_core = Figure.of("fleet.per_core", "throughput per core (2 workers)", "wagon-h/core-s", [v / 2 for v in per_worker[2]], COMMAND,
                       target=PER_CORE_TARGET).compare(f_core1)  # fmt: skip
    f_day = Figure.of("fleet.wagons_per_core_day", "wagons (1 h/day each) one core analyses per day", "wagons", [wagons_per_day_per_core], COMMAND,
                      note=f"x {cores} cores here: {wagons_per_day_per_core * cores:,.0f} wagons/day".replace(",", " "))  # fmt: skip
    f_cost = Figure.of("fleet.core_hours_10k", "core-hours per 10 000 wagon-days (1 h each)", "core-h", [core_hours_per_10k], COMMAND, higher_is_better=False)
    f_cpu1 = Figure.of("fleet.per_cpu_s_one_worker", "throughput per CPU second, 1 worker (workers + scheduler)", "wagon-h/CPU-s", per_cpu[1],
                       COMMAND, target=PER_CORE_TARGET, note=f"load average {load}")  # fmt: skip
    f_cpu2 = Figure.of("fleet.per_cpu_s_two_workers", "throughput per CPU second, 2 workers", "wagon-h/CPU-s", per_cpu[2], COMMAND,
                       target=PER_CORE_TARGET).compare(f_cpu1)  # fmt: skip
    f_cpu_speed = Figure.of("fleet.speedup_from_cpu", "speed-up from 1 to 2 workers, from CPU (2 x the CPU ratio)", "x", cpu_speedups, COMMAND,
                            target=SPEEDUP_TARGET)  # fmt: skip
    # The guard judges costs: CPU seconds per wagon-hour on 1 worker (target: the throughput target's inverse).
    f_cost1 = Figure.of("fleet_cpu_s_per_wagon_h", "CPU seconds per wagon-hour, 1 worker (guarded)", "CPU s", [1 / v for v in per_cpu[1]], COMMAND,
                        higher_is_better=False, target=1 / PER_CORE_TARGET)  # fmt: skip
    return [f_base, f_task, f1, f2, f_speed, f_core1, f_core, f_cpu1, f_cpu2, f_cpu_speed, f_cost1, f_day, f_cost]


def _cluster_cpu_s(client: object) -> float:
    """CPU seconds so far of the cluster's workers (each process, all its threads) and of this
    process (the client, and the scheduler a LocalCluster runs in it)."""
    return float(sum(client.run(time.process_time).values())) + time.process_time()  # type: ignore[attr-defined]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--wagons", type=int, default=16)
    parser.add_argument("--days", type=int, default=2)
    parser.add_argument("--recordings", type=int, default=2)
    parser.add_argument("--record", action="store_true", help="append the guarded figure to bench/results/records.json (the guard's baseline)")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record it even when it missed its target")
    args = parser.parse_args()
    measured = figures(args.runs, args.wagons, args.days, args.recordings)
    outcome = guard.check(measured, shlex.join(["bench/bench_fleet.py", *sys.argv[1:]]), record=args.record, accept_worse=args.accept_worse)
    return outcome.shown()


if __name__ == "__main__":
    np.seterr(all="ignore")
    raise SystemExit(main())
