"""The work list and a wagon's page as a person sees them: opened in a real headless Chromium at
desktop (1400 px) and tablet (800 px) width, screenshot, console and what the script does checked."""

from __future__ import annotations

import numpy as np
import pytest

from bogiemon.fleet.plot import ALARM_COLOUR, LEFT_PX, RIGHT_PX, SCORE_BOTTOM_PX, SCORE_COLOUR, SCORE_TOP_PX, STATE_COLOURS, TREND_COLOUR, W_PX
from bogiemon.fleet.report import write_report
from bogiemon.fleet.worklist import file_id
from tests.fleet.browser import count_colour, find_chromium, read_png, visit
from tests.fleet.judged_fixture import DEFAULT_FLEET, WagonSpec, write_judged

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed (`make system-deps` installs it as root)"),
]

CONFIRMED_WAGON = "31-80-4557-001"
HOSTILE = WagonSpec('<script>window.pwned=1</script>', "no_data", notes=('<img src=x onerror="window.pwned=2">',))
FLEET = (*DEFAULT_FLEET, HOSTILE)

BOX = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})"
SHOWN = "Array.prototype.filter.call(document.querySelectorAll('table.work tbody tr'),function(r){return r.offsetHeight>0;})"


def _set(element: str, value: str) -> str:
    """Set a filter control the way a person does, and count the rows still shown."""
    prop, cleared = ("checked", "false") if element == "fx" else ("value", "''")
    return (
        f"(function(){{var x=document.getElementById('{element}');x.{prop}={value};x.dispatchEvent(new Event('input'));"
        f"var n={SHOWN}.length;x.{prop}={cleared};x.dispatchEvent(new Event('input'));return n;}})()"
    )


INDEX = {
    "rows": "document.querySelectorAll('table.work tbody tr').length",
    "first_state": "document.querySelector('table.work tbody tr .b').textContent",
    "page_width": "document.documentElement.scrollWidth",
    "table": f"{BOX}(document.querySelector('table.work'))",
    # Every row's action on the screen, at least 200 px wide: the line is read, not guessed at.
    "action_widths": f"{SHOWN}.map(function(r){{return r.querySelector('td.act').getBoundingClientRect().width;}})",
    "scripts": "document.scripts.length",
    "pwned": "typeof window.pwned",
    "hostile_note": "document.querySelector('table.work').textContent.indexOf('<img src=x') >= 0",
    "search_sensor": _set("q", "'sensor a3'"),
    "state_normal": _set("fs", "'NORMAL'"),
    "type_light": _set("ft", "'Sgns-Y25-light'"),
    "commissioned_none": _set("fc", "'none'"),
    "shown_after": f"{SHOWN}.length",
    # Last: a click on the State header sorts by it, least urgent first (the screenshot follows).
    "after_click": "(function(){document.querySelectorAll('table.work th')[1].click();"
    "return Array.prototype.map.call(document.querySelectorAll('table.work tbody tr'),function(tr){return parseFloat(tr.cells[1].dataset.v);});})()",
}
WAGON = {"plot": f"{BOX}(document.querySelector('svg.plot'))", "page_width": "document.documentElement.scrollWidth"}


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("browser")
    judged = write_judged(root / "JUDGED", FLEET)
    out = root / "report"
    write_report(judged, out)
    return out


@pytest.fixture(scope="module", params=[1400, 800], ids=["desktop", "tablet"])
def seen(request: pytest.FixtureRequest, report):
    width = request.param
    result = visit((report / "index.html").as_uri(), width=width, height=1600, evaluate=INDEX)
    (report / f"index-{width}.png").write_bytes(result.png)  # to look at when a test fails
    return width, report, result


def test_the_page_loads_with_no_console_error_and_asks_for_nothing_outside(seen) -> None:
    _, report, result = seen
    assert result.errors == []
    assert result.requests == [(report / "index.html").as_uri()]


def test_every_wagon_has_its_line_with_the_most_urgent_first(seen) -> None:
    _, _, result = seen
    assert result.values["rows"] == len(FLEET)
    assert result.values["first_state"] == "CONFIRMED"


def test_the_page_fits_the_width_and_every_action_is_on_the_screen(seen) -> None:
    width, _, result = seen
    assert result.values["page_width"] <= width  # nothing runs off the page sideways
    left, _, table_width, _ = result.values["table"]
    assert left >= 0 and left + table_width <= width
    assert len(result.values["action_widths"]) == len(FLEET) and min(result.values["action_widths"]) >= 200


def test_the_confirmed_badge_is_red_on_the_screen(seen) -> None:
    _, _, result = seen
    assert count_colour(read_png(result.png), STATE_COLOURS["CONFIRMED"], result.values["table"]) > 200  # a badge is about 90 x 18 px


def test_search_and_the_filters_by_state_type_and_commissioning_show_the_matching_lines(seen) -> None:
    _, _, result = seen
    v = result.values
    assert v["search_sensor"] == 1  # the sensor fault's line names the sensor
    assert v["state_normal"] == sum(1 for s in FLEET if s.kind in ("normal", "blip"))
    assert v["type_light"] == 1
    assert v["commissioned_none"] == 1
    assert v["shown_after"] == len(FLEET)  # cleared, every line again


def test_hostile_text_is_shown_as_text_and_runs_nothing(seen) -> None:
    _, _, result = seen
    assert result.values["scripts"] == 1  # the filter and sorter alone
    assert result.values["pwned"] == "undefined"
    assert result.values["hostile_note"] is True


def test_a_click_on_a_column_header_sorts_the_table_by_it(seen) -> None:
    _, _, result = seen
    ranks = result.values["after_click"]
    assert len(ranks) == len(FLEET) and ranks == sorted(ranks) and ranks[0] < ranks[-1]


@pytest.mark.parametrize("width", [1400, 800])
def test_the_wagons_page_draws_its_score_and_trend_on_the_screen(report, width: int) -> None:
    result = visit((report / "wagons" / f"{file_id(CONFIRMED_WAGON)}.html").as_uri(), width=width, height=1400, evaluate=WAGON)
    (report / f"wagon-{width}.png").write_bytes(result.png)
    assert result.errors == [] and result.values["page_width"] <= width
    pixels = read_png(result.png)
    left, top, plot_width, _ = plot = result.values["plot"]
    assert plot[1] + plot[3] <= 1400 and plot_width >= min(1000, 0.8 * (width - 40))  # its natural width, or the page's
    for colour in (SCORE_COLOUR, TREND_COLOUR, ALARM_COLOUR):
        assert count_colour(pixels, colour, plot) > 30, colour
    # The score line spans most of the plot: nights are cut from the time axis.
    scale = plot_width / W_PX
    panel = pixels[round(top + SCORE_TOP_PX * scale) : round(top + SCORE_BOTTOM_PX * scale), round(left + LEFT_PX * scale) : round(left + RIGHT_PX * scale)]
    blue = np.array([int(SCORE_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])
    drawn = np.any(np.all(np.abs(panel - blue) <= 24, axis=-1), axis=0)
    assert drawn.mean() > 0.6
