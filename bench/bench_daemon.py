"""Benchmark of the whole daemon at 500 Hz real-time pace: CPU per hour, thread by thread, peak memory, latency.

Three feeds, each run for `seconds` of real time on a simulated healthy wagon, with the shipped
default config, measured over the steady state after the first window (the core only emits
from then on):

(a) CAN: the service in this process, its CAN source on python-can's virtual bus fed by a player
    thread (the bus does not cross processes), in the hub layout and (a') in the per-node one.
    The process's CPU is measured with time.process_time(), the player's own with its thread's
    CPU clock, and the player's is subtracted. Each thread's CPU (/proc/self/task: the Python
    threads by name, and the native ones no Python code started, such as a BLAS library's
    workers) is given for the hub layout: where the daemon's CPU goes. The latency is from a
    window's last sample (its time stamp on the bus) to the moment the monitor finished that
    window: judged, its events committed and reported.
(b) A recording without CAN: `bogiemon run` as its own process on a CSV replayed at real time
    ([source] kind = "replay", realtime = true); CPU from /proc/PID/stat, peak RSS from VmHWM:
    the daemon alone.

The daemon's figures are guarded (bench/guard.py): each has a target at most 25 % above the last
figure recorded on this machine class in bench/results/records.json, and the command exits 1 when
one is missed. `--record` appends this run's figures there (never automatically).

Run with `make bench-daemon` or
`.venv/bin/python bench/bench_daemon.py [--runs R] [--seconds S] [--feed can|per-node|recording|all] [--record]`.
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import guard  # noqa: E402
from timing import Figure  # noqa: E402

from bogiemon.daemon.config import load_config  # noqa: E402
from bogiemon.daemon.logs import configure_logging  # noqa: E402
from bogiemon.judgement.verdict import WindowVerdict  # noqa: E402
from bogiemon.daemon.service import Service  # noqa: E402
from bogiemon.drivers.can_source import CanBusPort, CanSource  # noqa: E402
from bogiemon.drivers.candb import load_layout  # noqa: E402
from bogiemon.drivers.player import open_player_bus, play  # noqa: E402
from bogiemon.drivers.recording import write_csv_recording  # noqa: E402

FS_HZ = 500.0
CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
TARGET_CPU_S_PER_H = 72.0  # 2 % of one core
AIM_CPU_S_PER_H = 36.0  # 1 %
# The whole daemon on the hub's CAN at 500 Hz (issue 35; 28.7 CPU s/h before it): a wagon's day of
# 6 h running within 100 CPU s with the standing hours (bench_gateway.py).
TARGET_CAN_HUB_CPU_S_PER_H = 11.0
TARGET_RSS_MB = 150.0
COMMAND = "make bench-daemon"
FEEDS = ("can", "per-node", "recording")  # "all": each in turn
LAYOUT_OF_FEED = {"can": "hub", "per-node": "per-node"}
START_UP_S = 1.0  # the service opens its bus before the player sends


class BenchError(RuntimeError):
    """A benchmark run could not measure what it should (too short, the daemon failed)."""


@dataclass(frozen=True)
class DaemonRun:
    cpu_s_per_hour: float
    peak_rss_mb: float | None
    latencies_s: tuple[float, ...]
    player_cpu_s_per_hour: float | None = None
    thread_cpu_s_per_hour: dict[str, float] | None = None  # by role (THREAD_ROLES), the player left out


# The daemon's threads by name (daemon/pipeline.py, daemon/delivery/, daemon/recorder.py), in the
# order the breakdown lists them; the bench's own (the player, the stop timer) are not the daemon's.
THREAD_ROLES = {
    "bogiemon-source": "source",
    "bogiemon-core": "processing",
    "MainThread": "main",
    "bogiemon-mqtt": "delivery",
    "bogiemon-can-alarms": "delivery",
    "bogiemon-recorder": "recorder",
}
ROLE_WHAT = {
    "source": "CAN source thread (python-can, the decoder, the ring)",
    "processing": "processing thread (the core, health, decision, event store)",
    "main": "main thread (supervision: status lines, watchdog)",
    "delivery": "delivery threads (MQTT, CAN alarms)",
    "recorder": "recorder's writer thread",
    "other": "other Python threads (a library's)",
    "native": "native threads no Python code started (a BLAS library's workers)",
    "bench": "bench's stop timer (not the daemon's, but in the total)",
}
PLAYER_THREAD = "bench-player"


def thread_cpu_s() -> dict[int, float]:
    """CPU seconds (user + system) of each thread of this process, by native thread id."""
    out = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:  # the thread ended meanwhile
            continue
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS
    return out


def thread_roles() -> dict[int, str]:
    """The role of each Python thread by native id; a thread not listed is a native one."""
    def role(name: str) -> str:
        if name == PLAYER_THREAD:
            return "player"
        return "bench" if name.startswith("bench-") else THREAD_ROLES.get(name, "other")

    return {t.native_id: role(t.name) for t in threading.enumerate() if t.native_id is not None}


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
        self.threads_first: dict[int, float] = {}
        self.threads_last: dict[int, float] = {}
        self.roles: dict[int, str] = {}
        self.latencies_s: list[float] = []
        self.closed = False

    def close(self) -> None:
        """The run is stopping: windows the drain completes are not the steady state (and the
        source thread may have ended, taking its CPU clock with it)."""
        self.closed = True

    def observe(self, report: WindowVerdict) -> None:
        if self.closed:
            return
        now = (time.process_time(), time.clock_gettime(self.player_clock), time.monotonic())
        threads = thread_cpu_s()
        self.roles.update(thread_roles())
        if self.first is None:
            self.threads_first = threads
        self.threads_last = threads
        # The CAN source stamps samples with the bus's receive times (time.time()): end_s is
        # one sample period after the window's last sample.
        self.latencies_s.append(time.time() - (report.window.end_s - 1.0 / FS_HZ))
        if self.first is None:
            self.first = now
        self.last = now


    def cpu_by_role(self, span_s: float) -> dict[str, float]:
        """CPU s/h of each role between the first and the last window (the player left out)."""
        out: dict[str, float] = {}
        for tid, cpu_s in self.threads_last.items():
            role = self.roles.get(tid, "native")
            if role != "player":
                out[role] = out.get(role, 0.0) + (cpu_s - self.threads_first.get(tid, 0.0)) / span_s * 3600.0
        return out


def run_can_in_process(seconds: float, seed: int, coalesce_s: float | None = None, layout_name: str = "hub") -> DaemonRun:
    """(a): the service here, its CAN source fed by a player thread on a virtual bus."""
    accel = healthy_accel(seconds + 5.0, seed)
    channel = f"bench-daemon-{os.getpid()}-{seed}-{time.monotonic_ns()}"
    layout = load_layout(None, layout_name)
    window_s = load_config(None).processing.window_s
    with tempfile.TemporaryDirectory() as tmp:
        source = f'[source]\nkind = "can"\ninterface = "virtual"\nchannel = "{channel}"\nlayout = "{layout_name}"'
        config_path = _config_file(Path(tmp), source)
        bus = open_player_bus("virtual", channel)

        def run_player() -> None:
            time.sleep(START_UP_S)
            play(bus, layout, accel, FS_HZ, rate=1.0)
            bus.shutdown()

        configure_logging(stream=open(os.devnull, "w"))  # noqa: SIM115 - closed at exit
        player = threading.Thread(target=run_player, name=PLAYER_THREAD, daemon=True)
        player.start()
        assert player.ident is not None
        steady = _SteadyState(time.pthread_getcpuclockid(player.ident))
        service = Service(
            config_path, lambda c: CanSource(CanBusPort("virtual", channel), layout, FS_HZ, coalesce_s=coalesce_s),
            sinks=[], observers=[steady.observe],
        )  # fmt: skip
        def stop() -> None:
            steady.close()
            service.request_stop()

        timer = threading.Timer(START_UP_S + seconds, stop)
        timer.name = "bench-stop-timer"
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
        thread_cpu_s_per_hour=steady.cpu_by_role(span_s),
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
            [sys.executable, "-m", "bogiemon.cli.main", "run", "--config", str(config_path)],
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


def can_figures(runs: int, seconds: float, layout_name: str = "hub") -> list[Figure]:
    can_runs = [run_can_in_process(seconds, seed, layout_name=layout_name) for seed in range(runs)]
    if layout_name == "per-node":
        return [
            Figure.of("daemon_can_per_node_cpu_s_per_h", "daemon, CAN per-node layout at 500 Hz (player thread subtracted)",
                      "CPU s/h", [r.cpu_s_per_hour for r in can_runs], COMMAND, higher_is_better=False,
                      target=TARGET_CPU_S_PER_H),
        ]  # fmt: skip
    latencies = [lat for r in can_runs for lat in r.latencies_s]
    roles = [role for role in ROLE_WHAT if any(role in (r.thread_cpu_s_per_hour or {}) for r in can_runs)]
    return [
        Figure.of("daemon_can_cpu_s_per_h", "daemon, CAN at 500 Hz (virtual bus, player thread subtracted)", "CPU s/h",
                  [r.cpu_s_per_hour for r in can_runs], COMMAND, higher_is_better=False, target=TARGET_CAN_HUB_CPU_S_PER_H,
                  note="28.7 before issue 35"),
        *[Figure.of(f"daemon_can_thread_{role}_cpu_s_per_h", f"  of which the {ROLE_WHAT[role]}", "CPU s/h",
                    [(r.thread_cpu_s_per_hour or {}).get(role, 0.0) for r in can_runs], COMMAND, higher_is_better=False)
          for role in roles],
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


def figures(runs: int = 3, seconds: float = 180.0, feed: str = "all") -> list[Figure]:
    """The figures of one feed, or of all three ("all")."""
    out = []
    for name in FEEDS if feed == "all" else (feed,):
        out += recording_figures(runs, seconds) if name == "recording" else can_figures(runs, seconds, LAYOUT_OF_FEED[name])
    return out


def single_line(run: DaemonRun, setting: str) -> str:
    threads = ", ".join(f"{role} {cpu:.1f}" for role, cpu in sorted((run.thread_cpu_s_per_hour or {}).items(), key=lambda x: -x[1]))
    return f"daemon CAN CPU s/h {run.cpu_s_per_hour:.1f} (player {run.player_cpu_s_per_hour:.1f}), coalesce_s {setting}; threads: {threads}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=3, help="runs per feed (default 3)")
    parser.add_argument("--seconds", type=float, default=180.0, help="real-time seconds per run (default 180)")
    parser.add_argument("--feed", choices=(*FEEDS, "all"), default="all", help="can (hub layout), per-node, recording, or all (default)")
    parser.add_argument("--single", action="store_true", help="one run of the CAN feed only, its CPU s/h on one line (for profiling)")
    parser.add_argument("--layout", choices=("hub", "per-node"), default="hub", help="with --single: the CAN layout")
    parser.add_argument("--coalesce-s", type=float, default=None, help="with --single: the CAN reader's coalescing (0: woken per frame)")
    parser.add_argument("--record", action="store_true", help="append the daemon's figures to bench/results/records.json (the guard's baseline)")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record figures that missed their target too")
    args = parser.parse_args()
    try:
        if args.single:
            run = run_can_in_process(args.seconds, 0, coalesce_s=args.coalesce_s, layout_name=args.layout)
            print(single_line(run, "default" if args.coalesce_s is None else f"{args.coalesce_s:g}"))
            return 0
        measured = figures(args.runs, args.seconds, args.feed)
        command = shlex.join(["bench/bench_daemon.py", *sys.argv[1:]])
        outcome = guard.check(measured, command, record=args.record, accept_worse=args.accept_worse)
    except (BenchError, guard.GuardError) as exc:
        print(f"bench_daemon: error: {exc}", file=sys.stderr)
        return 2
    return outcome.shown()


if __name__ == "__main__":
    sys.exit(main())
