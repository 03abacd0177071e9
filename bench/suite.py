"""The benchmark suite: every part of bench/ in one run, one table, and the same figures as JSON.

Runs the detection core against its naive baseline and `analyze` (bench_core), the CAN decoder
and the sources (bench_drivers), the simulator (bench_simulator), the whole daemon at 500 Hz
(bench_daemon) and the full detection study once (bench_study), the back office's `fleet analyze` on 1 and 2
Dask workers (bench_fleet) and the import of the fleet's page (bench_import), then prints one Markdown table
and writes JSON with the figures, the machine's CPU model, the load average before and after,
the versions of Python and the libraries, the date and the git commit.
The daemon's figures are guarded (bench/guard.py): each must stay within 25 % of the last figure
recorded on this machine class in bench/results/records.json (committed), and within its absolute
budget; the table says MISSED and the suite exits 1 otherwise. `--record` appends this run's
figures there: an explicit step, refused for a figure that missed unless `--accept-worse` too.
Takes about 50 minutes (the daemon's real-time runs and the study); --quick takes about 10.
Run with `make bench` or
`.venv/bin/python bench/suite.py [--quick] [--only PART,...] [--json PATH] [--record [--accept-worse]]`.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import asdict
from datetime import UTC, datetime
from importlib import metadata
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import bench_core  # noqa: E402
import bench_daemon  # noqa: E402
import bench_drivers  # noqa: E402
import bench_fleet  # noqa: E402
import bench_import  # noqa: E402
import bench_simulator  # noqa: E402
import bench_study  # noqa: E402
import guard  # noqa: E402
from timing import Figure, table  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_JSON = REPO / "bench" / "results" / "latest.json"
LIBRARIES = ("numpy", "scipy", "python-can", "cantools", "numba", "pydantic", "structlog", "bogiemon")

# Each part with its settings: the full suite, and --quick for trying it out.
PARTS: dict[str, tuple[Callable[..., list[Figure]], dict[str, Any], dict[str, Any]]] = {
    "core": (bench_core.figures, {"minutes": 10.0, "runs": 7}, {"minutes": 2.0, "runs": 3}),
    "drivers": (bench_drivers.figures, {"runs": 5, "seconds": 10.0}, {"runs": 3, "seconds": 3.0}),
    "simulator": (bench_simulator.figures, {"runs": 5, "duration_s": 120.0, "batch_n": 16},
                  {"runs": 3, "duration_s": 20.0, "batch_n": 4}),
    "daemon": (bench_daemon.figures, {"runs": 3, "seconds": 240.0}, {"runs": 1, "seconds": 150.0}),  # the three feeds
    "study": (bench_study.figures, {"runs": 1}, {"runs": 1, "quick": True}),
    "fleet": (bench_fleet.figures, {"runs": 5, "wagons": 16, "days": 2, "recordings": 2},
              {"runs": 1, "wagons": 4, "days": 1, "recordings": 2}),
    "import": (bench_import.figures, {"runs": 9}, {"runs": 3}),
}  # fmt: skip


def load_average() -> tuple[float, float, float]:
    one, five, fifteen = os.getloadavg()
    return (round(one, 2), round(five, 2), round(fifteen, 2))


def git(*args: str) -> str:
    # --no-optional-locks: `status` must not refresh the index (this only reads).
    out = subprocess.run(["git", "--no-optional-locks", *args], cwd=REPO, capture_output=True, text=True)
    return out.stdout.strip() if out.returncode == 0 else ""


def versions() -> dict[str, str]:
    out = {"python": platform.python_version()}
    for name in LIBRARIES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def daemon_config() -> str:
    from bogiemon.daemon.config import load_config

    decision = load_config(None).decision
    return f"shipped default config: decision.method = {decision.method!r}, decision.load = {decision.load!r}"


def context(started: datetime, load_before: tuple[float, float, float], quick: bool) -> dict[str, Any]:
    return {
        "date": started.isoformat(timespec="seconds"),
        "command": " ".join(["bench/suite.py", *sys.argv[1:]]),
        "quick": quick,
        "machine": {
            **asdict(guard.machine_class()),
            "load_average_before": load_before,
            "load_average_after": load_average(),
            "kernel": platform.release(),
        },
        "versions": versions(),
        "git": {"commit": git("rev-parse", "HEAD"), "uncommitted_changes": bool(git("status", "--porcelain", "--untracked-files=no"))},
        "daemon": daemon_config(),
    }


def header(info: dict[str, Any], wall_min: float) -> str:
    m, g = info["machine"], info["git"]
    return "\n".join([
        f"# bogiemon benchmark suite, {info['date']}, {wall_min:.0f} min{' (--quick)' if info['quick'] else ''}",
        f"# {m['arch']}, {m['cpu_model']}, {m['cores']} cores (the guard's machine class); load average before {m['load_average_before']}, after {m['load_average_after']}",
        f"# commit {g['commit'][:12]}{' with uncommitted changes' if g['uncommitted_changes'] else ''}; "
        + ", ".join(f"{k} {v}" for k, v in info["versions"].items()),
        f"# {info['daemon']}",
    ])  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs, `study --quick`: to try the suite out, not to quote")
    parser.add_argument("--only", default=",".join(PARTS), help=f"comma-separated parts (default all: {','.join(PARTS)})")
    parser.add_argument("--json", type=Path, default=DEFAULT_JSON, help=f"where to write the JSON (default {DEFAULT_JSON.relative_to(REPO)})")
    parser.add_argument("--record", action="store_true", help="append the daemon's figures to bench/results/records.json (the guard's baseline)")
    parser.add_argument("--accept-worse", action="store_true", help="with --record: record figures that missed their target too")
    args = parser.parse_args()
    wanted = [p.strip() for p in args.only.split(",") if p.strip()]
    unknown = [p for p in wanted if p not in PARTS]
    if unknown:
        print(f"suite: error: unknown part(s) {', '.join(unknown)}: choose from {', '.join(PARTS)}", file=sys.stderr)
        return 2
    started, load_before, t0 = datetime.now(UTC), load_average(), time.monotonic()
    figures: list[Figure] = []
    for name in wanted:
        fn, full, quick = PARTS[name]
        print(f"suite: {name} ...", file=sys.stderr, flush=True)
        try:
            figures += fn(**(quick if args.quick else full))
        except bench_daemon.BenchError as exc:
            print(f"suite: error: {name}: {exc}", file=sys.stderr)
            return 2
    info = context(started, load_before, args.quick)
    try:
        outcome = guard.check(figures, info["command"], record=args.record, accept_worse=args.accept_worse, quick=args.quick)
    except guard.GuardError as exc:
        print(f"suite: error: {exc}", file=sys.stderr)
        return 2
    print(header(info, (time.monotonic() - t0) / 60.0))
    print(table(outcome.figures))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({**info, "figures": [asdict(f) for f in outcome.figures]}, indent=2) + "\n")
    print(f"# figures written to {args.json}")
    for line in outcome.messages:
        print(f"# {line}")
    return outcome.status


if __name__ == "__main__":
    sys.exit(main())
