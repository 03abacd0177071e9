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

ROWS = "Array.prototype.map.call(document.querySelectorAll('table.work tbody tr'),function(tr){return tr.textContent;})"
ACTIONS = "Array.prototype.map.call(document.querySelectorAll('table.work tbody td.act'),function(td){return td.textContent;})"
TABLE = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})(document.querySelector('table.work'))"
WIDTH = "document.documentElement.scrollWidth"
PLOT = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})(document.querySelector('svg.plot'))"


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("fleet-demo")
    fleet, windows, judged = root / "fleet", root / "windows", root / "judged"
    steps = [
        ["fleet", "simulate", str(fleet), "--wagons", "6", "--days", "3", "--commission-runs", "4", "--runs-per-day", "2", "--run-s", "400"],
        ["fleet", "analyze", str(fleet), "-o", str(windows)],
        ["fleet", "calibrate", "--uncommissioned", "--fleet", str(fleet), "--windows", str(windows)],
        ["fleet", "judge", str(windows), "-o", str(judged)],
        ["fleet", "report", str(judged), "-o", str(root / "report")],
    ]
    for step in steps:
        assert main(step) == 0, step
    return root


@pytest.mark.parametrize("width", [1400, 800])
def test_the_work_list_puts_the_broken_springs_first_with_bogie_and_corner_pair_and_the_sensor_as_a_sensor(demo: Path, width: int) -> None:
    truth = json.loads((demo / "fleet" / "truth.json").read_text())
    faulty = {w["wagon"]: w["faults"][0]["corner"] for w in truth["wagons"] if w["faults"]}
    damaged = [w["wagon"] for w in truth["wagons"] if w["sensor_damages"]]
    assert len(faulty) == 2 and len(damaged) == 1

    seen = visit((demo / "report" / "index.html").as_uri(), width=width, height=1600,
                 evaluate={"rows": ROWS, "actions": ACTIONS, "table": TABLE, "width": WIDTH})  # fmt: skip
    (demo / f"report-{width}.png").write_bytes(seen.png)

    assert seen.errors == [] and seen.values["width"] <= width
    rows, actions = seen.values["rows"], seen.values["actions"]
    assert len(rows) == 6 and all(a.strip() for a in actions)  # every line says what to do
    for wagon, corner in faulty.items():
        at = next(i for i, r in enumerate(rows) if wagon in r)
        assert at < 2 and "CONFIRMED" in rows[at], rows[at]
        assert actions[at].startswith("Inspect the primary springs of bogie 1, ") and corner in actions[at], actions[at]
        assert "or" in actions[at].split("bogie 1, ")[1].split(" axle box")[0]  # a pair, never one corner alone
    at = next(i for i, r in enumerate(rows) if damaged[0] in r)
    assert at == 2 and "SENSOR FAULT" in rows[at] and actions[at].startswith("Check the sensor: sensor a3 of bogie 1")
    assert all(a.startswith("Nothing to do") for a in actions[3:])
    left, top_px, table_width, height = seen.values["table"]
    assert left + table_width <= width
    red = count_colour(read_png(seen.png), STATE_COLOURS["CONFIRMED"], box=(left, top_px, table_width, height))
    assert red > 50  # the two CONFIRMED badges, drawn in the table on the screen


def test_the_first_wagons_page_draws_its_score_over_the_runs(demo: Path) -> None:
    doc = json.loads((demo / "report" / "worklist.json").read_text())
    seen = visit((demo / "report" / doc["wagons"][0]["page"]).as_uri(), width=1400, height=1400, evaluate={"plot": PLOT})
    assert seen.errors == []
    left, top_px, width, _ = seen.values["plot"]  # the most urgent wagon's plot: a CONFIRMED one
    scale = width / W_PX
    panel = read_png(seen.png)[
        round(top_px + SCORE_TOP_PX * scale) : round(top_px + SCORE_BOTTOM_PX * scale), round(left + LEFT_PX * scale) : round(left + RIGHT_PX * scale)
    ]
    blue = np.array([int(SCORE_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])
    assert np.any(np.all(np.abs(panel[..., :3] - blue) <= 24, axis=-1), axis=0).mean() > 0.6  # nights cut: the runs fill the plot
