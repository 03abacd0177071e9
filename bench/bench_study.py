"""Benchmark of the detection study: `bogiemon study -o <tmpdir>`, wall-clock minutes, run once.

The full study simulates the paper's whole experiment matrix (about 7 minutes on two cores), so
the suite runs it once: the figure's min and max are that one run. --quick times the small
subset instead (`study --quick`), for trying the suite out.
Run with `.venv/bin/python bench/bench_study.py [--quick] [--runs R]`.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from timing import Figure, table  # noqa: E402

COMMAND = "bogiemon study -o DIR"


def study_minutes(quick: bool) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "bogiemon.cli.main", "study", "-o", str(Path(tmp) / "study"), "--quiet"]
        t0 = time.perf_counter()
        subprocess.run([*cmd, "--quick"] if quick else cmd, check=True, stdout=subprocess.DEVNULL)
        return (time.perf_counter() - t0) / 60.0


def figures(runs: int = 1, quick: bool = False) -> list[Figure]:
    what = "the detection study, --quick subset" if quick else "the full detection study (figures included), once"
    minutes = [study_minutes(quick) for _ in range(runs)]
    command = COMMAND + (" --quick" if quick else "")
    return [Figure.of("study_quick_minutes" if quick else "study_minutes", what, "min", minutes, command, higher_is_better=False)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1, help="runs (default 1: the full study takes minutes)")
    parser.add_argument("--quick", action="store_true", help="time `study --quick` instead of the full study")
    args = parser.parse_args()
    print(table(figures(args.runs, args.quick)))


if __name__ == "__main__":
    main()
