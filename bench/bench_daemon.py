"""Benchmark of the whole daemon at 500 Hz real-time pace: CPU per hour, peak memory, latency.

Two feeds, each run for `seconds` of real time on a simulated healthy wagon, with the shipped
default config, measured over the steady state after the first window (the core only emits
from then on):

(a) CAN: the service in this process, its CAN source on python-can's virtual bus fed by a player
    thread (the bus does not cross processes). The process's CPU is measured with
    time.process_time(), the player's own with its thread's CPU clock, and the player's is
    subtracted. The latency is from a window's last sample (its time stamp on the bus) to the
    moment the monitor finished that window: judged, its events committed and reported.
(b) A recording without CAN: `bogiemon run` as its own process on a CSV replayed at real time
    ([source] kind = "replay", realtime = true); CPU from /proc/PID/stat, peak RSS from VmHWM:
    the daemon alone.

Run with `make bench-daemon` or
`.venv/bin/python bench/bench_daemon.py [--runs R] [--seconds S] [--feed can|recording|both]`.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import Figure, table  # noqa: E402

from bogiemon.daemon.config import load_config  # noqa: E402
from bogiemon.daemon.logs import configure_logging  # noqa: E402
from bogiemon.daemon.verdict import WindowVerdict  # noqa: E402
from bogiemon.daemon.service import Service  # noqa: E402
from bogiemon.drivers.can_source import CanBusPort, CanSource  # noqa: E402
from bogiemon.drivers.candb import load_layout  # noqa: E402
from bogiemon.drivers.player import open_player_bus, play  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402

FS_HZ = 500.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
TARGET_CPU_S_PER_H = 72.0  # 2 % of one core
AIM_CPU_S_PER_H = 36.0  # 1 %
TARGET_RSS_MB = 150.0
COMMAND = "make bench-daemon"
START_UP_S = 1.0  # the service opens its bus before the player sends


class BenchError(RuntimeError):
    """A benchmark run could not measure what it should (too short, the daemon failed)."""


@dataclass(frozen=True)
class DaemonRun:
    cpu_s_per_hour: float
    peak_rss_mb: float | None
    latencies_s: tuple[float, ...]
    player_cpu_s_per_hour: float | None = None


def healthy_accel(duration_s: float, seed: int) -> np.ndarray:
    from bogiemon.simulator import Scenario, simulate  # the simulator only for the data

    return simulate(Scenario(duration_s=duration_s, seed=seed, fs_hz=FS_HZ)).accel_mps2


def _config_file(directory: Path, source: str) -> Path:
    path = directory / "bogiemon.toml"
    path.write_text(f"{source}\n[state]\ndirectory = \"{directory / 'state'}\"\n")
    return path


class _SteadyState:
    """CPU clocks and wall time at the first and the latest window report, and each latency."""

    def __init__(self, player_clock: int) -> None:
        self.player_clock = player_clock
        self.first: tuple[float, float, float] | None = None  # process CPU, player CPU, wall
        self.last: tuple[float, float, float] | None = None
        self.latencies_s: list[float] = []

    def observe(self, report: WindowVerdict) -> None:
        now = (time.process_time(), time.clock_gettime(self.player_clock), time.monotonic())
        # The CAN source stamps samples with the bus's receive times (time.time()): end_s is
        # one sample period after the window's last sample.
        self.latencies_s.append(time.time() - (report.window.end_s - 1.0 / FS_HZ))
        if self.first is None:
            self.first = now
        self.last = now


def run_can_in_process(seconds: float, seed: int, coalesce_s: float | None = None) -> DaemonRun:
    """(a): the service here, its CAN source fed by a player thread on a virtual bus."""
    accel = healthy_accel(seconds + 5.0, seed)
    channel = f"bench-daemon-{os.getpid()}-{seed}-{time.monotonic_ns()}"
    layout = load_layout(None, "hub")
    window_s = load_config(None).processing.window_s
    with tempfile.TemporaryDirectory() as tmp:
        config_path = _config_file(Path(tmp), f'[source]\nkind = "can"\ninterface = "virtual"\nchannel = "{channel}"')
        bus = open_player_bus("virtual", channel)

        def run_player() -> None:
            time.sleep(START_UP_S)
            play(bus, layout, accel, FS_HZ, rate=1.0)
            bus.shutdown()

        configure_logging(stream=open(os.devnull, "w"))  # noqa: SIM115 - closed at exit
        player = threading.Thread(target=run_player, name="bench-player", daemon=True)
        player.start()
        assert player.ident is not None
        steady = _SteadyState(time.pthread_getcpuclockid(player.ident))
        service = Service(
            config_path, lambda c: CanSource(CanBusPort("virtual", channel), layout, FS_HZ, coalesce_s=coalesce_s),
            sinks=[], observers=[steady.observe],
        )  # fmt: skip
        timer = threading.Timer(START_UP_S + seconds, service.flags.stop.set)
        timer.start()
        try:
            status = service.run()
        finally:
            timer.cancel()
    if status != 0:
        raise BenchError(f"the service exited with status {status}")
    if steady.first is None or steady.last is None or len(steady.latencies_s) < 3:
        raise BenchError(f"only {len(steady.latencies_s)} windows in {seconds:g} s: run longer than the {window_s:g} s window")
    (cpu0, player0, wall0), (cpu1, player1, wall1) = steady.first, steady.last
    span_s, player_s = wall1 - wall0, player1 - player0
    return DaemonRun(
        cpu_s_per_hour=(cpu1 - cpu0 - player_s) / span_s * 3600.0,
        peak_rss_mb=None,
        latencies_s=tuple(steady.latencies_s),
        player_cpu_s_per_hour=player_s / span_s * 3600.0,
    )


def proc_cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime, stime


def proc_status_kb(pid: int, key: str) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith(key + ":"):
            return float(line.split()[1])
    raise KeyError(key)


def run_recording_subprocess(seconds: float, seed: int) -> DaemonRun:
    """(b): `bogiemon run` alone, on a CSV replayed at real time."""
    window_s = load_config(None).processing.window_s
    if seconds < window_s + 20.0:
        raise BenchError(f"--seconds {seconds:g}: the recording feed needs at least the {window_s:g} s window plus 20 s")
    accel = healthy_accel(seconds + 5.0, seed)
    with tempfile.TemporaryDirectory() as tmp:
        csv = Path(tmp) / "run.csv"
        write_csv_recording(csv, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
        config_path = _config_file(Path(tmp), f'[source]\nkind = "replay"\npath = "{csv}"\nrealtime = true')
        proc = subprocess.Popen(
            [sys.executable, "-m", "bogiemon.daemon.cli.main", "run", "--config", str(config_path)],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
        )  # fmt: skip
        try:
            time.sleep(window_s + 5.0)  # start-up, then the first window
            cpu0, wall0 = proc_cpu_s(proc.pid), time.monotonic()
            time.sleep(seconds - window_s - 5.0)
            cpu1, wall1 = proc_cpu_s(proc.pid), time.monotonic()
            peak_kb = proc_status_kb(proc.pid, "VmHWM")
        finally:
            proc.terminate()
            _, err = proc.communicate(timeout=30)
        if proc.returncode != 0:
            raise BenchError(f"bogiemon run failed ({proc.returncode}): {err.decode()[-2000:]}")
    return DaemonRun(cpu_s_per_hour=(cpu1 - cpu0) / (wall1 - wall0) * 3600.0, peak_rss_mb=peak_kb / 1024, latencies_s=())


def can_figures(runs: int, seconds: float) -> list[Figure]:
    can_runs = [run_can_in_process(seconds, seed) for seed in range(runs)]
    latencies = [lat for r in can_runs for lat in r.latencies_s]
    return [
        Figure.of("daemon_can_cpu_s_per_h", "daemon, CAN at 500 Hz (virtual bus, player thread subtracted)", "CPU s/h",
                  [r.cpu_s_per_hour for r in can_runs], COMMAND, higher_is_better=False, target=TARGET_CPU_S_PER_H,
                  note=f"aim {AIM_CPU_S_PER_H:g}"),
        Figure.of("daemon_can_player_cpu_s_per_h", "the CAN player thread of (a), not the daemon's", "CPU s/h",
                  [r.player_cpu_s_per_hour or 0.0 for r in can_runs], COMMAND, higher_is_better=False),
        Figure.of("daemon_can_latency_s", "latency, a window's last sample -> decided and committed (CAN)", "s",
                  latencies, COMMAND, higher_is_better=False,
                  note=f"median/min/max over {len(latencies)} windows of {runs} runs"),
    ]  # fmt: skip


def recording_figures(runs: int, seconds: float) -> list[Figure]:
    csv_runs = [run_recording_subprocess(seconds, seed) for seed in range(runs)]
    return [
        Figure.of("daemon_replay_cpu_s_per_h", "daemon, `bogiemon run` on a CSV replayed at 500 Hz real time", "CPU s/h",
                  [r.cpu_s_per_hour for r in csv_runs], COMMAND, higher_is_better=False, target=TARGET_CPU_S_PER_H,
                  note=f"aim {AIM_CPU_S_PER_H:g}"),
        Figure.of("daemon_replay_peak_rss_mb", "daemon peak RSS (VmHWM), `bogiemon run` on the CSV", "MB",
                  [r.peak_rss_mb or 0.0 for r in csv_runs], COMMAND, higher_is_better=False, target=TARGET_RSS_MB),
    ]  # fmt: skip


def figures(runs: int = 3, seconds: float = 180.0, feed: str = "both") -> list[Figure]:
    out = []
    if feed in ("can", "both"):
        out += can_figures(runs, seconds)
    if feed in ("recording", "both"):
        out += recording_figures(runs, seconds)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per feed (default 3)")
    parser.add_argument("--seconds", type=float, default=180.0, help="real-time seconds per run (default 180)")
    parser.add_argument("--feed", choices=("can", "recording", "both"), default="both")
    parser.add_argument("--single", action="store_true", help="one run of feed (a) only, its CPU s/h on one line (for profiling)")
    parser.add_argument("--coalesce-s", type=float, default=None, help="with --single: the CAN reader's coalescing (0: woken per frame)")
    args = parser.parse_args()
    try:
        if args.single:
            run = run_can_in_process(args.seconds, 0, coalesce_s=args.coalesce_s)
            setting = "default" if args.coalesce_s is None else f"{args.coalesce_s:g}"
            print(f"daemon CAN CPU s/h {run.cpu_s_per_hour:.1f} (player {run.player_cpu_s_per_hour:.1f}), coalesce_s {setting}")
            return 0
        print(table(figures(args.runs, args.seconds, args.feed)))
    except BenchError as exc:
        print(f"bench_daemon: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
