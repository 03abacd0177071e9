"""`make fleet-demo`'s steps on a small simulated fleet, through the command line, and the page they
end in as a person sees it in a real headless Chromium: the faulty wagons first, with their corners."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from bogiemon.cli.main import main
import numpy as np

from bogiemon.fleet.plot import LEFT_PX, RIGHT_PX, SCORE_BOTTOM_PX, SCORE_COLOUR, SCORE_TOP_PX, STATE_COLOURS, W_PX
from tests.fleet.browser import count_colour, find_chromium, read_png, visit

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed (`make system-deps` installs it as root)"),
]

ROWS = "Array.prototype.map.call(document.querySelectorAll('table.fleet tbody tr'),function(tr){return tr.textContent;})"
TABLE = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})(document.querySelector('table.fleet'))"
FIRST_PLOT = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})(document.querySelector('section.w svg'))"


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fleet-demo")
    fleet, windows, judged = root / "fleet", root / "windows", root / "judged"
    steps = [
        ["fleet", "simulate", str(fleet), "--wagons", "6", "--days", "3", "--commission-runs", "4", "--runs-per-day", "2", "--run-s", "400"],
        ["fleet", "analyze", str(fleet), "-o", str(windows)],
        ["fleet", "calibrate", "--uncommissioned", "--fleet", str(fleet), "--windows", str(windows)],
        ["fleet", "judge", str(windows), "-o", str(judged)],
        ["fleet", "report", str(judged), "-o", str(root / "report.html")],
    ]
    for step in steps:
        assert main(step) == 0, step
    return root


def test_the_report_shows_the_faulty_wagons_first_with_their_corners(demo: Path) -> None:
    truth = json.loads((demo / "fleet" / "truth.json").read_text())
    faulty = {w["wagon"]: w["faults"][0]["corner"] for w in truth["wagons"] if w["faults"]}
    damaged = [w["wagon"] for w in truth["wagons"] if w["sensor_damages"]]
    assert len(faulty) == 2 and len(damaged) == 1

    seen = visit((demo / "report.html").as_uri(), width=1400, height=1600, evaluate={"rows": ROWS, "table": TABLE, "first_plot": FIRST_PLOT})
    (demo / "report.png").write_bytes(seen.png)

    assert seen.errors == []
    rows = seen.values["rows"]
    assert len(rows) == 6
    top = rows[:2]
    for wagon, corner in faulty.items():
        row = next(r for r in top if wagon in r)
        assert "CONFIRMED" in row and corner in row
    assert damaged[0] in rows[2] and "SENSOR_FAULT" in rows[2] and "a3" in rows[2]
    assert all("CONFIRMED" not in r and "SUSPECTED" not in r for r in rows[3:])
    left, top_px, width, height = seen.values["table"]
    red = count_colour(read_png(seen.png), STATE_COLOURS["CONFIRMED"], box=(left, top_px, width, height))
    assert red > 50  # the two CONFIRMED badges, drawn in the table on the screen
    left, top_px, width, _ = seen.values["first_plot"]  # the most urgent wagon's plot: a CONFIRMED one
    scale = width / W_PX
    panel = read_png(seen.png)[
        round(top_px + SCORE_TOP_PX * scale) : round(top_px + SCORE_BOTTOM_PX * scale), round(left + LEFT_PX * scale) : round(left + RIGHT_PX * scale)
    ]
    blue = np.array([int(SCORE_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])
    assert np.any(np.all(np.abs(panel[..., :3] - blue) <= 24, axis=-1), axis=0).mean() > 0.6  # nights cut: the runs fill the plot
