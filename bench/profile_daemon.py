"""Profile of the daemon's hot path on the CAN feed at 500 Hz, before and after the reader coalesces.

For each variant of the CAN reader (before: woken for every frame, coalesce_s = 0; after: the
default) it measures the daemon's CPU seconds per hour without a profiler (bench_daemon.py's
feed (a), the player thread subtracted; --runs times), then runs the same feed once under py-spy (`--gil`:
only the thread holding the interpreter, so sleeping and waiting threads never count) and
prints where the daemon's samples go: by thread (CAN source, core, service main loop) and the
functions with the largest inclusive share. The player thread and the start-up (imports, the
simulated data) are left out. py-spy comes with the bench extra (`make bench` installs it).

`--gil` samples see Python only: C code that released the interpreter (numpy's BLAS products,
the FFT) and threads no Python code started (OpenBLAS's workers spinning after a product) never
count, and a regression there is invisible in the profile (issue 16's cost was: README,
Performance). So each CPU figure comes with the CPU of every thread of the process from
/proc (bench_daemon.py's breakdown): what the profile's shares do not cover shows there.
Run with `.venv/bin/python bench/profile_daemon.py [--seconds S] [--runs R] [--out DIR]`.
"""

from __future__ import annotations

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

BENCH = Path(__file__).resolve().parent
VARIANTS = {"before (woken per frame, coalesce_s = 0)": "0", "after (default coalescing)": None}
ROLES = (("player", "run_player"), ("CAN source thread", "Pipeline._read_loop"),
         ("core thread", "Pipeline._process_loop"), ("service main loop", "Service.run"))  # fmt: skip
CPU_LINE = re.compile(r"daemon CAN CPU s/h ([0-9.]+)")
THREADS_LINE = re.compile(r"threads: (.*)$", re.MULTILINE)


class ProfileError(RuntimeError):
    """py-spy or the feed failed; the message says which."""


@dataclass(frozen=True)
class Profile:
    samples_by_role: dict[str, int]
    inclusive: list[tuple[str, str, int]]  # (role, function, samples)
    daemon_samples: int


def feed_command(seconds: float, coalesce_s: str | None) -> list[str]:
    cmd = [sys.executable, str(BENCH / "bench_daemon.py"), "--single", "--seconds", f"{seconds:g}"]
    return [*cmd, "--coalesce-s", coalesce_s] if coalesce_s is not None else cmd


def measure_cpu_s_per_hour(seconds: float, coalesce_s: str | None) -> tuple[float, str]:
    """The daemon's CPU s/h and its threads' (bench_daemon.py's line: "source 20.1, processing 3.0, ...")."""
    out = subprocess.run(feed_command(seconds, coalesce_s), capture_output=True, text=True)
    match = CPU_LINE.search(out.stdout)
    if out.returncode != 0 or match is None:
        raise ProfileError(f"the CAN feed failed ({out.returncode}): {out.stderr[-1500:]}")
    threads = THREADS_LINE.search(out.stdout)
    return float(match.group(1)), threads.group(1) if threads else ""


def record(seconds: float, coalesce_s: str | None, raw_path: Path) -> float:
    """Run the feed under py-spy into raw_path; the daemon's CPU s/h as measured under it."""
    py_spy = shutil.which("py-spy", path=str(Path(sys.executable).parent)) or shutil.which("py-spy")
    if py_spy is None:
        raise ProfileError("py-spy is not installed: `make bench` installs it (pip install -e '.[bench]')")
    cmd = [py_spy, "record", "--gil", "--nonblocking", "--rate", "100", "--format", "raw", "--output", str(raw_path), "--"]
    out = subprocess.run([*cmd, *feed_command(seconds, coalesce_s)], capture_output=True, text=True)
    match = CPU_LINE.search(out.stdout)
    if out.returncode != 0 or not raw_path.exists() or match is None:
        raise ProfileError(f"py-spy or the feed failed ({out.returncode}): {out.stderr[-1500:]}")
    return float(match.group(1))


def role_of(frames: list[str]) -> str | None:
    for role, marker in ROLES:
        if any(marker in frame for frame in frames):
            return role
    return None  # start-up: imports, simulating the data, the harness


def summarise(raw_path: Path, top_n: int) -> Profile:
    """Samples per thread role and the top functions by inclusive share, player and start-up left out."""
    by_role: Counter[str] = Counter()
    inclusive: Counter[tuple[str, str]] = Counter()
    for line in raw_path.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = [f for f in stack.split(";") if f]
        role = role_of(frames)
        n = int(count)
        by_role[role or "start-up"] += n
        if role is None or role == "player":
            continue
        for frame in set(frames):
            if not frame.startswith(("Thread.", "<module>")):  # every stack has these
                inclusive[(role, frame)] += n
    daemon = sum(n for role, n in by_role.items() if role not in ("player", "start-up"))
    top = [(role, frame, n) for (role, frame), n in inclusive.most_common(top_n)]
    return Profile(dict(by_role), top, daemon)


def report(name: str, measured_runs: list[tuple[float, str]], profiled_cpu_s_per_hour: float, profile: Profile) -> str:
    cpu_s_per_hour = [cpu for cpu, _ in measured_runs]
    measured = (f"{statistics.median(cpu_s_per_hour):.1f} s/h without the profiler (median of {len(cpu_s_per_hour)}: "
                f"{', '.join(f'{v:.1f}' for v in cpu_s_per_hour)}), " if cpu_s_per_hour else "")  # fmt: skip
    lines = [f"## {name}: daemon CPU {measured}{profiled_cpu_s_per_hour:.1f} s/h under py-spy"]
    lines += [f"CPU s/h by thread (/proc, run {i + 1}): {threads}" for i, (_, threads) in enumerate(measured_runs) if threads]
    total = max(profile.daemon_samples, 1)
    lines.append(f"py-spy --gil samples: {profile.daemon_samples} in the daemon's threads; "
                 + ", ".join(f"{role} {n}" for role, n in sorted(profile.samples_by_role.items())))  # fmt: skip
    for role, frame, n in profile.inclusive:
        lines.append(f"  {100 * n / total:5.1f} %  {role:<18} {frame}")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=240.0, help="real-time seconds per feed (default 240)")
    parser.add_argument("--runs", type=int, default=1, help="unprofiled runs per variant for the CPU figure (default 1; 0: none)")
    parser.add_argument("--top", type=int, default=20, help="functions listed per variant (default 20)")
    parser.add_argument("--out", type=Path, help="keep py-spy's raw (collapsed) stacks in this folder")
    args = parser.parse_args()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            folder = args.out or Path(tmp)
            folder.mkdir(parents=True, exist_ok=True)
            for i, (name, coalesce_s) in enumerate(VARIANTS.items()):
                cpu = [measure_cpu_s_per_hour(args.seconds, coalesce_s) for _ in range(args.runs)]
                raw_path = folder / f"daemon-can-{'before' if i == 0 else 'after'}.txt"
                profiled = record(args.seconds, coalesce_s, raw_path)
                print(report(name, cpu, profiled, summarise(raw_path, args.top)), flush=True)
    except ProfileError as exc:
        print(f"profile_daemon: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
