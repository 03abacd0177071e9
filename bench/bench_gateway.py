"""Benchmark of the gateway (issue 35): its install on disk, and its CPU over a wagon's day, with and
without a duty cycle ([duty], daemon/duty.py).

(a) Install: the host architecture's bundle (`make bundle`, build/bundle/) installed by its
    install.sh into a temporary /opt/bogiemon and /etc/bogiemon (BOGIEMON_PREFIX, BOGIEMON_ETC): the
    MB on disk of the version's tree, beside the 434 MB of the pip install before the extras were
    split off (pyarrow 170 MB, scipy 143 MB).
(b) A wagon's day, 6 h running and 18 h standing, extrapolated from three stretches measured at
    real time on the hub's CAN layout at 500 Hz. The service runs in this process on the
    gateway's own CAN path: the `socketcan` kind, its frames read with recvmmsg(2) and parsed with
    numpy, from a socket that is a UDP one here (this kernel has no AF_CAN; tests/drivers/frames.py:
    DatagramCanBus, bound to one port so that a reopened bus gets the frames again) carrying the
    kernel's struct can_frame datagrams with their receive stamps; a sender in a process of its own
    plays the hub's frames there (python-can's virtual bus would need the player in the daemon's
    process, whose activity there weighs on a resting daemon's few wake-ups). The stretches:
    running, measured the whole time (the daemon's steady state, its windows judged); standing
    with [duty] on (every channel still: after standing_after_s the source rests, with a listen of
    probe_s every probe_every_s); and a rest between two measurements of a cycle (the source
    closed, no listen). The day without a duty cycle is
    6 h x running + 18 h x standing; with a cycle of M minutes in every N, the running hours are
    M/N x running + (1 - M/N) x resting. A measurement's first window_s only fills the window and
    costs less than the steady state, so the running figure over-counts a cycle slightly.
(c) What a duty cycle costs the detection: a simulated broken spring (the demo wagon, loaded, at
    80 km/h; two hours, the spring breaking at one) replayed through the duty-cycled monitor with
    the break at 8 moments spread over the cycle, and the time from the break to its CONFIRMED,
    beside the time without a duty cycle. Not timing: the same every run.

(d) Memory: the peak RSS (VmHWM) of `bogiemon run` on hub CAN at 500 Hz, run by the host bundle's
    install (the gateway's packages only) on the same datagram stand-in, fed by a sender process,
    for window_s + 60 s at least (bench/gateway_memory.py).

The figures with a target are guarded (bench/guard.py). Run with `make bench-gateway` or
`.venv/bin/python bench/bench_gateway.py [--part install|day|detection|memory|all] [--seconds S] [--runs R] [--record]`.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import platform
import shlex
import socket
import struct
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(Path(__file__).resolve().parents[1]))  # tests.drivers.frames: the datagram stand-in of SocketCAN

import guard  # noqa: E402
from bench_daemon import FS_HZ, START_UP_S, BenchError, healthy_accel  # noqa: E402
from timing import Figure  # noqa: E402

from can.interfaces import socketcan  # noqa: E402

from bogiemon.daemon.config import BogiemonConfig, load_config  # noqa: E402
from bogiemon.daemon.logs import configure_logging  # noqa: E402
from bogiemon.daemon.service import Service  # noqa: E402
from bogiemon.daemon.sources import duty_cycled  # noqa: E402
from bogiemon.drivers.base import Source  # noqa: E402
from bogiemon.drivers.can_source import CanBusPort, CanSource  # noqa: E402
from bogiemon.drivers.candb import load_layout  # noqa: E402
from bogiemon.drivers.can_frames import SO_TIMESTAMPNS  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
COMMAND = "make bench-gateway"
TARGET_INSTALL_MB = 150.0
BEFORE_INSTALL_MB = 434.0  # a gateway's pip install before issue 35 (pyarrow and scipy in it)
TARGET_DAY_CPU_S = 100.0
TARGET_RSS_MIB = 64.0
BEFORE_VM_RSS_MIB = 78.6  # vcan_daemon_peak_rss_mib, bench_vcan.py in the VM at b089627
MEMORY_START_UP_S = 5.0  # for the installed daemon to start and bind its socket before the sender plays
TARGET_STANDING_CPU_S_PER_H = 1.0
RUNNING_H, STANDING_H = 6.0, 18.0
# The cycle the day's figure with a duty cycle uses: 10 minutes measured in every 30.
CYCLE_MEASURE_MIN, CYCLE_EVERY_MIN = 10.0, 30.0
STANDING_NOISE_MPS2 = 0.01  # a standing wagon's sensors: their noise alone
DUTY = "[duty]\nenabled = true\nstanding_after_s = {standing_after_s}\nmeasure_min = {measure_min}\nevery_min = {every_min}\n"


# -- (a) the install ---------------------------------------------------------------------------


@contextlib.contextmanager
def installed(bundle: Path) -> Iterator[Path]:
    """The version's tree that the bundle's install.sh makes in a temporary prefix (removed after)."""
    with tempfile.TemporaryDirectory() as tmp:
        with tarfile.open(bundle) as tar:
            tar.extractall(tmp, filter="data")
        (installer,) = Path(tmp).glob("bogiemon-*/install.sh")
        env = {**os.environ, "BOGIEMON_PREFIX": f"{tmp}/opt", "BOGIEMON_ETC": f"{tmp}/etc",
               "BOGIEMON_UNIT_DIR": f"{tmp}/units", "BOGIEMON_NETWORK_DIR": f"{tmp}/network"}  # fmt: skip
        done = subprocess.run(["sh", str(installer)], env=env, capture_output=True, text=True)
        if done.returncode != 0:
            raise BenchError(f"{installer} failed: {done.stderr[-2000:]}")
        (tree,) = Path(tmp, "opt", "versions").iterdir()
        yield tree


def install_mb(bundle: Path) -> float:
    """MB on disk of the version's tree that the bundle's install.sh makes."""
    with installed(bundle) as tree:
        size = subprocess.run(["du", "-sk", str(tree)], capture_output=True, text=True, check=True)
        return int(size.stdout.split()[0]) / 1024


def host_bundle() -> Path:
    bundles = sorted((REPO / "build" / "bundle").glob(f"bogiemon-*-{platform.machine()}.tar.gz"))
    if not bundles:
        raise BenchError(f"no bundle for {platform.machine()} in build/bundle: run `make bundle` first")
    return bundles[-1]


def install_figures() -> list[Figure]:
    bundle = host_bundle()
    mb = install_mb(bundle)
    return [
        Figure.of("gateway_install_mb", f"gateway install on disk ({bundle.name}, CPython {platform.python_version()})", "MB",
                  [mb], COMMAND, higher_is_better=False, target=TARGET_INSTALL_MB,
                  note=f"{mb / BEFORE_INSTALL_MB:.2f}x the {BEFORE_INSTALL_MB:g} MB of the pip install before issue 35"),
    ]  # fmt: skip


# -- (b) a wagon's day ---------------------------------------------------------------------------


def standing_accel(duration_s: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.standard_normal((int(duration_s * FS_HZ), 3)) * STANDING_NOISE_MPS2 + [0.0, 0.0, 9.81]


SENDER = """
import socket, sys, time
import numpy as np
frames = np.load(sys.argv[1])  # (instants, 16): each instant's struct can_frame (the hub: one)
port, fs_hz = int(sys.argv[2]), float(sys.argv[3])
out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
start = time.monotonic()
sent = 0
while sent < len(frames):
    due = min(len(frames), int((time.monotonic() - start) * fs_hz) + 1)
    for i in range(sent, due):
        out.sendto(frames[i].tobytes(), ("127.0.0.1", port))
    sent = due
    time.sleep(0.01)
"""


def hub_datagrams(accel: np.ndarray, path: Path) -> None:
    """The hub's frames of a run, one struct can_frame (16 bytes) an instant, saved for the sender."""
    from bogiemon.drivers.player import encode_instants

    layout = load_layout(None, "hub")
    frames = [frame for instant in encode_instants(layout, accel) for frame in instant]
    if len(frames) != accel.shape[0]:
        raise BenchError("the hub layout sends one frame an instant")
    raw = b"".join(struct.pack("=IB3x8s", frame_id, len(payload), payload) for frame_id, _, payload in frames)
    np.save(path, np.frombuffer(raw, np.uint8).reshape(-1, 16))


def stretch_cpu_s_per_h(accel: np.ndarray, config_text: str, from_s: float, seconds: float, seed: int) -> float:
    """The daemon's CPU s/h between from_s and from_s + seconds after the sender starts."""
    from tests.drivers.frames import DatagramCanBus

    layout = load_layout(None, "hub")
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]  # a free port for the daemon's socket, every reopening
    probe.close()

    class FixedPortBus(DatagramCanBus):
        def __init__(self, channel: str = "", **settings: object) -> None:
            super().__init__(channel, **settings)
            self.socket.close()
            self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.socket.bind(("127.0.0.1", port))
            self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            self.address = self.socket.getsockname()

    samples: list[tuple[float, float]] = []  # process CPU, wall
    original = socketcan.SocketcanBus
    socketcan.SocketcanBus = FixedPortBus  # type: ignore[misc,assignment]  # the socketcan kind opens the stand-in
    try:
        with tempfile.TemporaryDirectory() as tmp:
            hub_datagrams(accel, Path(tmp) / "frames.npy")
            config_path = Path(tmp) / "bogiemon.toml"
            source = '[source]\nkind = "can"\ninterface = "socketcan"\nchannel = "can0"\nlayout = "hub"\n'
            config_path.write_text(f'{source}{config_text}[state]\ndirectory = "{Path(tmp) / "state"}"\n')
            configure_logging(stream=open(os.devnull, "w"))  # noqa: SIM115 - closed at exit

            def opened(config: BogiemonConfig) -> Source:
                return duty_cycled(CanSource(CanBusPort("socketcan", "can0"), layout, FS_HZ), config)

            service = Service(config_path, opened, sinks=[])
            sender: list[subprocess.Popen[bytes]] = []

            def start_sender() -> None:
                sender.append(subprocess.Popen([sys.executable, "-c", SENDER, str(Path(tmp) / "frames.npy"), str(port), str(FS_HZ)]))

            def sample() -> None:
                samples.append((time.process_time(), time.monotonic()))

            timers = [threading.Timer(START_UP_S, start_sender), threading.Timer(START_UP_S + from_s, sample),
                      threading.Timer(START_UP_S + from_s + seconds, sample),
                      threading.Timer(START_UP_S + from_s + seconds + 0.5, service.request_stop)]  # fmt: skip
            for timer in timers:
                timer.name = "bench-timer"
                timer.start()
            try:
                status = service.run()
            finally:
                for timer in timers:
                    timer.cancel()
                for process in sender:
                    process.kill()
                    process.wait()
    finally:
        socketcan.SocketcanBus = original  # type: ignore[misc]
    if status != 0 or len(samples) != 2:
        raise BenchError(f"the service exited with status {status} after {len(samples)} of 2 samples")
    (cpu0, wall0), (cpu1, wall1) = samples
    return (cpu1 - cpu0) / (wall1 - wall0) * 3600.0


def day_figures(runs: int, seconds: float) -> list[Figure]:
    window_s = load_config(None).processing.window_s
    running, standing, resting = [], [], []
    for seed in range(runs):
        # Running: the steady state, after the first window.
        running.append(stretch_cpu_s_per_h(healthy_accel(window_s + seconds + 20.0, seed), "", window_s + 10.0, seconds, seed))
        # Standing, [duty] on: still from the start, so resting after standing_after_s (30 s here).
        duty_on = DUTY.format(standing_after_s=30.0, measure_min=60.0, every_min=60.0)
        standing.append(stretch_cpu_s_per_h(standing_accel(seconds + 60.0, seed), duty_on, 40.0, seconds, seed))
        # A rest between two measurements: the shortest measurement a window allows, then the rest.
        measure_min = (window_s + 20.0) / 60.0
        cycled = DUTY.format(standing_after_s=3600.0, measure_min=round(measure_min, 3), every_min=60.0)
        resting.append(stretch_cpu_s_per_h(healthy_accel(measure_min * 60.0 + seconds + 30.0, seed), cycled, measure_min * 60.0 + 10.0, seconds, seed))
    share = CYCLE_MEASURE_MIN / CYCLE_EVERY_MIN
    day = [RUNNING_H * r + STANDING_H * s for r, s in zip(running, standing, strict=True)]
    day_cycled = [RUNNING_H * (share * r + (1 - share) * c) + STANDING_H * s for r, s, c in zip(running, standing, resting, strict=True)]
    extrapolated = f"extrapolated: {RUNNING_H:g} h x running + {STANDING_H:g} h x standing, from stretches of {seconds:g} s"
    return [
        Figure.of("gateway_running_cpu_s_per_h", "running, measured whole (hub CAN at 500 Hz, recvmmsg on a datagram socket)", "CPU s/h",
                  running, COMMAND, higher_is_better=False),
        Figure.of("gateway_standing_cpu_s_per_h", "standing, [duty] on: the source at rest, a 2 s listen a minute", "CPU s/h",
                  standing, COMMAND, higher_is_better=False, target=TARGET_STANDING_CPU_S_PER_H),
        Figure.of("gateway_resting_cpu_s_per_h", "a duty cycle's rest between two measurements", "CPU s/h",
                  resting, COMMAND, higher_is_better=False),
        Figure.of("gateway_day_cpu_s", "a day of 6 h running + 18 h standing, no duty cycle", "CPU s",
                  day, COMMAND, higher_is_better=False, target=TARGET_DAY_CPU_S, note=extrapolated),
        Figure.of("gateway_day_cycled_cpu_s",
                  f"the same day measuring {CYCLE_MEASURE_MIN:g} min in every {CYCLE_EVERY_MIN:g} while running", "CPU s",
                  day_cycled, COMMAND, higher_is_better=False, note=extrapolated),
    ]  # fmt: skip


# -- (c) what a duty cycle costs the detection ---------------------------------------------------

FAULT_ONSET_S = 3600.0
FAULT_RUN = REPO / "build" / "duty" / "broken-spring-2h.csv"
CYCLES_MIN = ((10.0, 30.0), (10.0, 60.0))  # (measure_min, every_min)
PHASES = 8  # fault onsets spread evenly over a cycle


def fault_run() -> tuple[np.ndarray, float]:
    """Two hours of the demo wagon (loaded, 80 km/h, good track): its rear outer coil spring over the
    leading-left axle box breaks at one hour (simulated once, kept in build/duty)."""
    from bogiemon.drivers.recording import read_recording

    if not FAULT_RUN.exists():
        FAULT_RUN.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run([sys.executable, "-m", "bogiemon.cli.main", "simulate", "--load", "full", "--track", "erri-low",
                        "--speed-kmh", "80", "--duration-s", "7200", "--fault", "type_a:rear_outer:0.0@leading-left",
                        "--fault-at-s", f"{FAULT_ONSET_S:g}", "--seed", "5", "-q", "-o", str(FAULT_RUN)], check=True)  # fmt: skip
    recording = read_recording(FAULT_RUN)
    return recording.accel_mps2, recording.fs_hz


def confirmed_after_s(accel: np.ndarray, fs_hz: float, start_s: float, duty: str) -> float | None:
    """Seconds from the fault's onset to its CONFIRMED, the run replayed from start_s through the
    monitor of the demo wagon's config (its commissioning), on the [duty] given (empty: none)."""
    from bogiemon.daemon.monitor import MemoryEventLog, Monitor
    from bogiemon.drivers.base import Block, EndOfStream, MemorySource
    from bogiemon.judgement.events import EventKind

    class Recording(MemorySource):
        finite = True

    calibration = REPO / "bogiemon" / "config" / "demo_calibration.toml"
    path = FAULT_RUN.parent / "bogiemon.toml"
    path.write_text(f'allow_absolute_includes = true\ninclude = ["{calibration}"]\n[decision]\nload = "full"\n{duty}')
    config = load_config(path)
    first = int(start_s * fs_hz)
    blocks = [Block(i / fs_hz, fs_hz, accel[i : i + int(fs_hz)]) for i in range(first, accel.shape[0], int(fs_hz))]
    source = duty_cycled(Recording(blocks), config)
    monitor = Monitor(config.monitor_settings("full", fs_hz), MemoryEventLog())
    try:
        while True:
            block = source.read(0.0)
            if block is None:
                continue
            for event in monitor.feed(block):
                if event.kind is EventKind.CONFIRMED:
                    return event.time_s - FAULT_ONSET_S
    except EndOfStream:
        return None


def detection_figures() -> list[Figure]:
    configure_logging(stream=open(os.devnull, "w"))  # noqa: SIM115 - the duty cycle's log lines, closed at exit
    accel, fs_hz = fault_run()
    plain = confirmed_after_s(accel, fs_hz, FAULT_ONSET_S - 600.0, "")
    if plain is None:
        raise BenchError(f"{FAULT_RUN}: the broken spring is never confirmed without a duty cycle")
    out = [Figure.of("duty_confirm_s_none", "time from a broken spring to its CONFIRMED, no duty cycle", "s", [plain], COMMAND,
                     higher_is_better=False, note="the demo wagon, loaded, 80 km/h, replayed from 10 min before the break")]  # fmt: skip
    for measure_min, every_min in CYCLES_MIN:
        duty = DUTY.format(standing_after_s=60.0, measure_min=measure_min, every_min=every_min)
        delays = []
        for k in range(PHASES):
            phase_s = (k + 0.5) * every_min * 60.0 / PHASES  # the break this long after a measurement began
            delay = confirmed_after_s(accel, fs_hz, FAULT_ONSET_S - phase_s, duty)
            if delay is None:
                raise BenchError(f"{FAULT_RUN}: measuring {measure_min:g} min in every {every_min:g}, the break {phase_s:g} s into a cycle is never confirmed")
            delays.append(delay)
        out.append(Figure.of(f"duty_confirm_s_{measure_min:g}_of_{every_min:g}",
                             f"  measuring {measure_min:g} min in every {every_min:g} (median, min .. max over {PHASES} breaks through the cycle)",
                             "s", delays, COMMAND, higher_is_better=False))  # fmt: skip
    return out


# -- (d) the daemon's peak memory --------------------------------------------------------------


def memory_figures(seconds: float) -> list[Figure]:
    """VmHWM of `bogiemon run` on hub CAN at 500 Hz, as the host bundle installs it (bench/gateway_memory.py)."""
    from gateway_memory import MemoryBenchError, run_peak_rss_mib

    window_s = load_config(None).processing.window_s
    span_s = max(seconds, window_s + 60.0)  # the first window judged and several hops after it
    with installed(host_bundle()) as tree, tempfile.TemporaryDirectory() as tmp:
        frames = Path(tmp) / "frames.npy"
        hub_datagrams(healthy_accel(span_s + MEMORY_START_UP_S + 30.0, seed=0), frames)
        try:
            mib, _ = run_peak_rss_mib(tree / "bin" / "python", frames, SENDER, REPO / "systemd" / "bogiemon.service", span_s, FS_HZ, MEMORY_START_UP_S)
        except MemoryBenchError as exc:
            raise BenchError(str(exc)) from None
    return [
        Figure.of("gateway_run_peak_rss_mib", f"peak RSS of `bogiemon run`, hub CAN at 500 Hz, the bundle's install, {span_s:g} s", "MiB",
                  [mib], COMMAND, higher_is_better=False, target=TARGET_RSS_MIB,
                  note=f"VmHWM on this host (recvmmsg on a datagram socket); before: {BEFORE_VM_RSS_MIB:g} MiB in the VM (bench_vcan)"),
    ]  # fmt: skip


PARTS: dict[str, Callable[[argparse.Namespace], list[Figure]]] = {
    "install": lambda args: install_figures(),
    "memory": lambda args: memory_figures(args.seconds),
    "day": lambda args: day_figures(args.runs, args.seconds),
    "detection": lambda args: detection_figures(),
}


def figures(runs: int = 1, seconds: float = 180.0, part: str = "all") -> list[Figure]:
    args = argparse.Namespace(runs=runs, seconds=seconds)
    return [f for name in (PARTS if part == "all" else (part,)) for f in PARTS[name](args)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=(*PARTS, "all"), default="all")
    parser.add_argument("--runs", type=int, default=1, help="runs of each stretch (default 1)")
    parser.add_argument("--seconds", type=float, default=180.0, help="real-time seconds of each measured stretch (default 180)")
    parser.add_argument("--record", action="store_true", help="append the guarded figures to bench/results/records.json")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record figures that missed their target too")
    args = parser.parse_args()
    try:
        measured = figures(args.runs, args.seconds, args.part)
        outcome = guard.check(measured, shlex.join(["bench/bench_gateway.py", *sys.argv[1:]]), record=args.record, accept_worse=args.accept_worse)
    except (BenchError, guard.GuardError) as exc:
        print(f"bench_gateway: error: {exc}", file=sys.stderr)
        return 2
    return outcome.shown()


if __name__ == "__main__":
    sys.exit(main())
