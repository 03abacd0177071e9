"""Benchmark of import times: `import bogiemon.fleet.report` in fresh interpreters, beside its target.

Each run is a new interpreter (nothing cached in sys.modules, the files in the page cache after the
warm-up run) that times the import alone: wall seconds (time.perf_counter) and CPU seconds
(time.process_time, which a busy machine inflates less), the median of the runs with their min and
max. The interpreter's own start (`python -c pass`) is measured the same way as the baseline of the
whole command. `--why` adds the heaviest modules of one run (`python -X importtime`, cumulative).

Run with `make bench-import` or `.venv/bin/python bench/bench_import.py [--runs R] [--why]`.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))

from timing import Figure, table  # noqa: E402

COMMAND = "make bench-import"
MODULE = "bogiemon.fleet.report"
# The page's module is imported by every reader of a JUDGED folder (`bogiemon fleet report`, the
# fuzz target, the tests): the import alone, in a fresh interpreter on a quiet machine.
TARGET_S = 0.3
_TIMED = (
    "import json, sys, time; w, c = time.perf_counter(), time.process_time(); import {module}; "
    "print(json.dumps([time.perf_counter() - w, time.process_time() - c]))"
)


def import_seconds(module: str) -> tuple[float, float]:
    """(wall s, CPU s) of importing module in a fresh interpreter."""
    out = subprocess.run([sys.executable, "-c", _TIMED.format(module=module)], capture_output=True, text=True, check=True)
    wall_s, cpu_s = json.loads(out.stdout)
    return float(wall_s), float(cpu_s)


def start_seconds() -> float:
    """Wall seconds of a whole `python -c pass`, measured from outside."""
    timer = "import subprocess, sys, time; t = time.perf_counter(); subprocess.run([sys.executable, '-c', 'pass'], check=True); print(time.perf_counter() - t)"
    return float(subprocess.run([sys.executable, "-c", timer], capture_output=True, text=True, check=True).stdout)


def heaviest(module: str, n: int = 12) -> list[tuple[float, str]]:
    """The n modules of one import with the most cumulative seconds (`-X importtime`)."""
    err = subprocess.run([sys.executable, "-X", "importtime", "-c", f"import {module}"], capture_output=True, text=True, check=True).stderr
    rows = []
    for line in err.splitlines():
        parts = line.split("|")
        if len(parts) == 3 and parts[1].strip().isdigit():
            rows.append((int(parts[1]) / 1e6, parts[2].rstrip()))
    return sorted(rows, reverse=True)[:n]


def figures(runs: int = 9) -> list[Figure]:
    import_seconds(MODULE)  # warm-up: the files in the page cache, the bytecode written
    measured = [import_seconds(MODULE) for _ in range(runs)]
    starts = [start_seconds() for _ in range(runs)]
    wall = Figure.of("import.fleet_report", f"import {MODULE} (wall)", "s", [w for w, _ in measured], COMMAND,
                     higher_is_better=False, target=TARGET_S)  # fmt: skip
    cpu = Figure.of("import.fleet_report_cpu", f"import {MODULE} (CPU)", "s", [c for _, c in measured], COMMAND, higher_is_better=False)
    start = Figure.of("import.python_start", "python -c pass, the whole process (wall)", "s", starts, COMMAND, higher_is_better=False)
    return [wall, cpu, start]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=9, help="fresh interpreters per figure (default 9)")
    parser.add_argument("--why", action="store_true", help="also the heaviest modules of one import (-X importtime)")
    args = parser.parse_args()
    print(table(figures(args.runs)))
    if args.why:
        print(f"\nthe heaviest modules of one `import {MODULE}` (cumulative seconds, -X importtime):")
        for seconds, name in heaviest(MODULE):
            print(f"  {seconds:7.3f}  {name}")


if __name__ == "__main__":
    main()
