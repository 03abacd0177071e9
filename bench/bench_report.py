"""The work list of a fleet of thousands: the size of its index.html and how long headless Chromium
takes to open it, beside their targets (3 MB, 2 s).

A synthetic JUDGED folder of N wagons (tests/fleet/judged_fixture.py: mostly normal, some
confirmed, suspected, with a sensor fault, without data or stale; three types; commissioned for
both loads, one or none), its report written once (CPU seconds), then the page opened `--runs`
times at each width in a fresh headless Chromium: the figure is the navigation's loadEventEnd (from
the request to the end of the load event: parsing, layout and the page's own script), as the
browser's Performance API gives it. With --screenshots DIR, the last visit at each width is kept
as DIR/worklist-<N>-<width>.png.

    .venv/bin/python bench/bench_report.py [--wagons 2000] [--runs 3] [--screenshots docs/figures]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from timing import Figure, table  # noqa: E402

from bogiemon.fleet.report import write_report  # noqa: E402
from tests.fleet.browser import find_chromium, visit  # noqa: E402
from tests.fleet.judged_fixture import SMALL_SHAPE, many_wagons, write_judged  # noqa: E402

COMMAND = "bench/bench_report.py"
OPEN_TARGET_MS = 2000.0  # issue 36: the page of 2 000 wagons opens in under 2 s
PAGE_TARGET_MB = 3.0
WIDTHS = (1400, 800)
LOAD_MS = "performance.getEntriesByType('navigation')[0].loadEventEnd"


def figures(wagons: int = 2000, runs: int = 3, screenshots: Path | None = None) -> list[Figure]:
    if find_chromium() is None:
        raise SystemExit("bench_report: chromium is not installed (`make system-deps` installs it as root)")
    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    with tempfile.TemporaryDirectory(prefix="bench-report-") as tmp:
        judged = write_judged(Path(tmp) / "JUDGED", many_wagons(wagons), SMALL_SHAPE)
        cpu0 = time.process_time()
        report = write_report(judged, Path(tmp) / "report")
        write_cpu_s = time.process_time() - cpu0
        out = [
            Figure.of("report_write_cpu_s", f"`fleet report` of {wagons} wagons (index, CSV, JSON, a page per wagon)", "CPU s", [write_cpu_s], COMMAND,
                      higher_is_better=False),  # fmt: skip
            Figure.of("report_index_mb", f"index.html of {wagons} wagons", "MB", [report.bytes / 1e6], COMMAND, higher_is_better=False,
                      target=PAGE_TARGET_MB),  # fmt: skip
        ]
        for width in WIDTHS:
            opened_ms = []
            for _ in range(runs):
                seen = visit(report.index.as_uri(), width=width, height=1200, evaluate={"load_ms": LOAD_MS}, timeout_s=120.0)
                if seen.errors:
                    raise SystemExit(f"bench_report: the page showed errors at {width} px: {seen.errors[:3]}")
                opened_ms.append(float(seen.values["load_ms"]))
            if screenshots is not None:
                (screenshots / f"worklist-{wagons}-{width}.png").write_bytes(seen.png)
            out.append(Figure.of(f"report_open_ms_{width}", f"headless Chromium opens it at {width} px (load event end)", "ms", opened_ms, COMMAND,
                                 higher_is_better=False, target=OPEN_TARGET_MS, note=f"load average {load}"))  # fmt: skip
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wagons", type=int, default=2000)
    parser.add_argument("--runs", type=int, default=3, help="visits per width (default 3)")
    parser.add_argument("--screenshots", type=Path, metavar="DIR", help="keep a screenshot per width in DIR")
    args = parser.parse_args()
    measured = figures(args.wagons, args.runs, args.screenshots)
    print(table(measured))
    return 1 if any(f.meets_target is False for f in measured) else 0


if __name__ == "__main__":
    sys.exit(main())
