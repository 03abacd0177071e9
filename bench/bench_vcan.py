"""Benchmark of the CAN path on a real kernel: `bogiemon run` reading the hub's frames from vcan0
beside candump reading the same frames, in the VM of tests/vm/ (Debian's kernel under QEMU's
software emulation: every CPU figure here is about 12 times the host's, the ratio is not).

In the VM, for a simulated healthy run at 500 Hz in the hub layout: candump (can-utils, C: a
recvmsg and a line of text per frame, to a file) and `bogiemon run` (its CAN source on the
SocketCAN socket, read with recvmmsg) listen on vcan0, then `bogiemon play` sends the run at real
time. Over `seconds` of the steady state each process's CPU is read from /proc, the daemon's per
thread by the names the pipeline gives them (bogiemon-source, bogiemon-core): the CAN source
thread against candump is the figure (target: at most 3 times candump's CPU), with the whole
daemon's CPU beside it, and the daemon's peak RSS (VmHWM: target 64 MiB; 93 MB before issue 35, on
a CSV replay with pyarrow loaded). Both readers must have read every frame the player sent.

Run with `make bench-vcan` (root: the VM, tests/vm/setup.sh) or
`.venv/bin/python bench/bench_vcan.py [--seconds S] [--record]`; `--inside` is the part in the VM.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import guard  # noqa: E402
from bench_daemon import CLOCK_TICKS, FS_HZ, BenchError, healthy_accel  # noqa: E402
from timing import Figure, table  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
OUT_DIR = REPO / "build" / "bench-vcan"
COMMAND = "make bench-vcan"
TARGET_RATIO = 3.0
TARGET_RSS_MIB = 64.0
BEFORE_RSS_MB = 93.7  # daemon_replay_peak_rss_mb recorded before issue 35 (bench/results/records.json)
WARM_UP_S = 20.0  # after the player's first frame, before the measured span
PATIENCE_S = 600.0  # for Python to start in the VM (a minute is usual)
BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]


# -- in the VM ------------------------------------------------------------------------------------


def cpu_s(stat_path: Path) -> float:
    fields = stat_path.read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


def threads_cpu_s(pid: int) -> dict[str, float]:
    """CPU seconds of each of a process's threads, summed by the kernel's name of the thread."""
    out: dict[str, float] = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            name = (task / "comm").read_text().strip()
            out[name] = out.get(name, 0.0) + cpu_s(task / "stat")
        except OSError:  # the thread ended meanwhile
            continue
    return out


def vm_hwm_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    raise BenchError("no VmHWM in /proc/PID/status")


def rss_by_mapping_kib(pid: int, top: int = 8) -> dict[str, int]:
    """Where a process's resident memory is: KiB by mapping (a library's file name, [heap], [anon]), the largest."""
    totals: dict[str, int] = {}
    name = "[anon]"
    for line in Path(f"/proc/{pid}/smaps").read_text().splitlines():
        fields = line.split()
        if fields and "-" in fields[0] and not fields[0].endswith(":"):
            name = Path(fields[5]).name if len(fields) > 5 else "[anon]"
        elif fields and fields[0] == "Rss:":
            totals[name] = totals.get(name, 0) + int(fields[1])
    return dict(sorted(totals.items(), key=lambda kv: -kv[1])[:top])


def wait_for(condition: Callable[[], bool], what: str, deadline_s: float) -> None:
    while not condition():
        if time.monotonic() > deadline_s:
            raise BenchError(f"gave up waiting for {what}")
        time.sleep(0.2)


def inside(recording: Path, out: Path, seconds: float) -> None:
    """The measurement in the VM; writes what it read to out (JSON)."""
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "bogiemon.toml"
        config.write_text(f'[source]\nkind = "can"\ninterface = "socketcan"\nchannel = "vcan0"\nlayout = "hub"\n[state]\ndirectory = "{tmp}/state"\n')
        log = open(Path(tmp) / "daemon.log", "w")  # noqa: SIM115 - closed below
        candump_out = open(Path(tmp) / "candump.txt", "w")  # noqa: SIM115
        # candump logs each frame as a line of text to a file (tmpfs), its receive buffer large enough
        # that a starved VM loses none of them.
        candump = subprocess.Popen(["candump", "-r", str(1 << 22), "vcan0"], stdout=candump_out)
        # The environment of the shipped unit (systemd/bogiemon.service): one BLAS thread.
        unit_env = {**os.environ, "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        daemon = subprocess.Popen([*BOGIEMON, "run", "--config", str(config)], stdout=log, stderr=subprocess.STDOUT, env=unit_env)
        deadline_s = time.monotonic() + PATIENCE_S
        ready = Path(tmp) / "player.ready"
        player = None
        try:
            wait_for(lambda: "bogiemon-source" in threads_cpu_s(daemon.pid), "the daemon's CAN source thread", deadline_s)
            player = subprocess.Popen([*BOGIEMON, "play", str(recording), "--interface", "socketcan", "--channel", "vcan0",
                                       "--ready-file", str(ready)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
            wait_for(ready.exists, "the player's first frame", deadline_s)
            time.sleep(WARM_UP_S)
            start = (time.monotonic(), cpu_s(Path(f"/proc/{candump.pid}/stat")), threads_cpu_s(daemon.pid), cpu_s(Path(f"/proc/{daemon.pid}/stat")))
            time.sleep(seconds)
            end = (time.monotonic(), cpu_s(Path(f"/proc/{candump.pid}/stat")), threads_cpu_s(daemon.pid), cpu_s(Path(f"/proc/{daemon.pid}/stat")))
            rss_kib = vm_hwm_kib(daemon.pid)
            breakdown = rss_by_mapping_kib(daemon.pid)
            if player.wait(timeout=PATIENCE_S) != 0:
                raise BenchError(f"bogiemon play failed: {player.stderr.read().decode()[-2000:] if player.stderr else ''}")
            time.sleep(2.0)  # the last frames into both readers
        finally:
            for process in (player, daemon):
                if process is not None and process.poll() is None:
                    process.send_signal(signal.SIGTERM)
            candump.send_signal(signal.SIGINT)
            daemon_status = daemon.wait(timeout=120)
            candump.wait(timeout=30)
            log.close()
            candump_out.close()
        log_lines = (Path(tmp) / "daemon.log").read_text().splitlines()
        # JSON lines behind a syslog priority, <6>{...} (daemon/logs.py)
        stopped = [json.loads(line[line.index("{"):]) for line in log_lines if '"event": "stopped"' in line]
        if daemon_status != 0 or not stopped:
            raise BenchError(f"bogiemon run exited {daemon_status}: {' | '.join(log_lines[-5:])}")
        candump_frames = sum(1 for _ in (Path(tmp) / "candump.txt").open())
    span_s = end[0] - start[0]
    result = {
        "span_s": span_s,
        "candump_cpu_s": end[1] - start[1],
        "daemon_cpu_s": end[3] - start[3],
        "threads_cpu_s": {name: end[2].get(name, 0.0) - start[2].get(name, 0.0) for name in end[2]},
        "daemon_peak_rss_kib": rss_kib,
        "daemon_frames": stopped[-1]["source"]["frames"],
        "candump_frames": candump_frames,
        "rss_by_mapping_kib": breakdown,
    }
    out.write_text(json.dumps(result, indent=2) + "\n")


# -- on the host ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class VcanRun:
    """What one VM run measured (inside()'s JSON)."""

    span_s: float
    candump_cpu_s: float
    daemon_cpu_s: float
    threads_cpu_s: dict[str, float]
    daemon_peak_rss_kib: int
    daemon_frames: int
    candump_frames: int
    rss_by_mapping_kib: dict[str, int]


LAST_RUN: VcanRun | None = None  # for the memory breakdown printed under the table


def run_in_vm(seconds: float) -> VcanRun:
    from bogiemon.drivers.recording import write_csv_recording

    OUT_DIR.mkdir(parents=True, exist_ok=True)
    recording = OUT_DIR / f"healthy-{seconds:g}s.csv"
    if not recording.exists():
        accel = healthy_accel(WARM_UP_S + seconds + 30.0, seed=0)
        write_csv_recording(recording, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    out = OUT_DIR / "out"
    out.mkdir(exist_ok=True)
    (out / "result.json").unlink(missing_ok=True)
    command = (f"cd {shlex.quote(str(REPO))} && PYTHONDONTWRITEBYTECODE=1 {shlex.quote(sys.executable)} bench/bench_vcan.py --inside "
               f"--recording {shlex.quote(str(recording))} --out {shlex.quote(str(out / 'result.json'))} --seconds {seconds:g}")  # fmt: skip
    done = subprocess.run(["bash", str(REPO / "tests" / "vm" / "run.sh"), command], env={**os.environ, "VM_OUT": str(out)},
                          capture_output=True, text=True)  # fmt: skip
    if done.returncode != 0 or not (out / "result.json").exists():
        raise BenchError(f"the VM run failed ({done.returncode}): {done.stdout[-3000:]}")
    global LAST_RUN
    run = VcanRun(**json.loads((out / "result.json").read_text()))
    LAST_RUN = run
    if run.daemon_frames != run.candump_frames:
        raise BenchError(f"the daemon read {run.daemon_frames} frames, candump {run.candump_frames}: not the same traffic")
    return run


def figures(runs: int = 1, seconds: float = 240.0) -> list[Figure]:
    results = [run_in_vm(seconds) for _ in range(runs)]
    source = [r.threads_cpu_s.get("bogiemon-source", 0.0) * 3600.0 / r.span_s for r in results]
    candump = [r.candump_cpu_s * 3600.0 / r.span_s for r in results]
    daemon = [r.daemon_cpu_s * 3600.0 / r.span_s for r in results]
    ratios = [s / c for s, c in zip(source, candump, strict=True)]
    rss = [r.daemon_peak_rss_kib / 1024 for r in results]
    vm = "in the VM (QEMU TCG: about 12x the host's CPU)"
    return [
        Figure.of("vcan_source_over_candump_cpu", "daemon's CAN source thread / candump, CPU on the same hub frames at 500 Hz",
                  "x", ratios, COMMAND, higher_is_better=False, target=TARGET_RATIO),
        Figure.of("vcan_source_cpu_s_per_h", f"  the CAN source thread {vm}", "CPU s/h", source, COMMAND, higher_is_better=False),
        Figure.of("vcan_candump_cpu_s_per_h", f"  candump {vm}", "CPU s/h", candump, COMMAND, higher_is_better=False),
        Figure.of("vcan_daemon_cpu_s_per_h", f"  the whole daemon {vm}", "CPU s/h", daemon, COMMAND, higher_is_better=False),
        Figure.of("vcan_daemon_peak_rss_mib", "peak RSS of `bogiemon run` on CAN (vcan0, hub at 500 Hz)", "MiB", rss, COMMAND,
                  higher_is_better=False, target=TARGET_RSS_MIB, note=f"{BEFORE_RSS_MB:g} MB before issue 35 (a CSV replay, pyarrow loaded)"),
    ]  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=240.0, help="real-time seconds measured (default 240)")
    parser.add_argument("--runs", type=int, default=1, help="VM runs (default 1; each about 6 minutes)")
    parser.add_argument("--record", action="store_true", help="append the guarded figures to bench/results/records.json")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record figures that missed their target too")
    parser.add_argument("--inside", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--recording", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    try:
        if args.inside:
            inside(args.recording, args.out, args.seconds)
            return 0
        measured = figures(args.runs, args.seconds)
        outcome = guard.check(measured, shlex.join(["bench/bench_vcan.py", *sys.argv[1:]]), record=args.record, accept_worse=args.accept_worse)
    except (BenchError, guard.GuardError) as exc:
        print(f"bench_vcan: error: {exc}", file=sys.stderr)
        return 2
    print(table(outcome.figures))
    if LAST_RUN is not None:
        where = ", ".join(f"{name} {kib / 1024:.1f}" for name, kib in LAST_RUN.rss_by_mapping_kib.items())
        print(f"the daemon's resident MiB by mapping at the end (the largest): {where}")
    for line in outcome.messages:
        print(line, file=sys.stderr)
    return outcome.status


if __name__ == "__main__":
    sys.exit(main())
