"""The fleet page as a person sees it: opened in a real headless Chromium, screenshot and console checked."""

from __future__ import annotations

import numpy as np
import pytest

from bogiemon.fleet.plot import ALARM_COLOUR, LEFT_PX, RIGHT_PX, SCORE_BOTTOM_PX, SCORE_COLOUR, SCORE_TOP_PX, STATE_COLOURS, TREND_COLOUR, W_PX
from bogiemon.fleet.report import html_id, write_report
from tests.fleet.browser import count_colour, find_chromium, read_png, visit
from tests.fleet.judged_fixture import DEFAULT_FLEET, WagonSpec, write_judged

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(find_chromium() is None, reason="chromium is not installed (`make system-deps` installs it as root)"),
]

CONFIRMED_WAGON = "31-80-4557-001"
HOSTILE = WagonSpec('<script>window.pwned=1</script>', "no_data", notes=('<img src=x onerror="window.pwned=2">',))

# What the page shows, read from the rendered DOM (boxes in CSS pixels: left, top, width, height).
BOX = "(function(e){var r=e.getBoundingClientRect();return [r.left,r.top,r.width,r.height];})"
EXPRESSIONS = {
    "rows": "document.querySelectorAll('table.fleet tbody tr').length",
    "first_state": "document.querySelector('table.fleet tbody tr .b').textContent",
    "table": f"{BOX}(document.querySelector('table.fleet'))",
    "confirmed_plot": f"{BOX}(document.querySelector('#{html_id(CONFIRMED_WAGON)} svg'))",
    "plots_drawn": "Array.prototype.filter.call(document.querySelectorAll('svg.plot'),function(s){var r=s.getBoundingClientRect();return r.width>500&&r.height>100;}).length",
    "score_lengths": "Array.prototype.map.call(document.querySelectorAll('svg.plot path.s'),function(p){return p.getTotalLength();})",
    "scripts": "document.scripts.length",
    "pwned": "typeof window.pwned",
    "hostile_note": "document.querySelector('table.fleet').textContent.indexOf('<img src=x') >= 0",
    # Last: a click on the Attention header sorts the table by it, ascending (the screenshot follows).
    "after_click": "(function(){document.querySelectorAll('table.fleet th')[3].click();"
    "return Array.prototype.map.call(document.querySelectorAll('table.fleet tbody tr'),function(tr){return parseFloat(tr.cells[3].textContent);});})()",
}


@pytest.fixture(scope="module")
def seen(tmp_path_factory: pytest.TempPathFactory):
    root = tmp_path_factory.mktemp("browser")
    judged = write_judged(root / "JUDGED", (*DEFAULT_FLEET, HOSTILE))
    out = root / "report.html"
    write_report(judged, out)
    result = visit(out.as_uri(), width=1400, height=2000, evaluate=EXPRESSIONS)
    (root / "report.png").write_bytes(result.png)  # to look at when a test fails
    return out, result


def test_the_page_loads_with_no_console_error_and_asks_for_nothing_outside(seen) -> None:
    out, result = seen
    assert result.errors == []
    assert result.requests == [out.as_uri()]


def test_the_table_renders_every_wagon_with_the_most_urgent_first(seen) -> None:
    _, result = seen
    assert result.values["rows"] == len(DEFAULT_FLEET) + 1
    assert result.values["first_state"] == "CONFIRMED"


def test_the_confirmed_badge_is_red_in_the_table_on_the_screen(seen) -> None:
    _, result = seen
    pixels = read_png(result.png)
    table = result.values["table"]
    assert table[3] > 100 and table[0] + table[2] <= 1400  # every column on the screen
    assert count_colour(pixels, STATE_COLOURS["CONFIRMED"], table) > 200  # a badge is about 60 x 18 px


def test_every_wagon_gets_a_drawn_plot_with_its_lines_on_the_screen(seen) -> None:
    _, result = seen
    assert result.values["plots_drawn"] == len(DEFAULT_FLEET) + 1
    assert len(result.values["score_lengths"]) == 5 and min(result.values["score_lengths"]) > 100  # five wagons have windows
    pixels = read_png(result.png)
    plot = result.values["confirmed_plot"]
    assert plot[1] + plot[3] <= 2000  # on the screenshot
    for colour in (SCORE_COLOUR, TREND_COLOUR, ALARM_COLOUR):
        assert count_colour(pixels, colour, plot) > 30, colour


def test_the_confirmed_wagons_score_line_spans_most_of_its_plot_now_that_nights_are_cut(seen) -> None:
    # Its four one-hour runs over 30 hours drew over about 14 % of the width on a linear time axis.
    _, result = seen
    left, top, width, _ = result.values["confirmed_plot"]
    scale = width / W_PX  # CSS pixels per viewBox pixel
    panel = read_png(result.png)[
        round(top + SCORE_TOP_PX * scale) : round(top + SCORE_BOTTOM_PX * scale), round(left + LEFT_PX * scale) : round(left + RIGHT_PX * scale)
    ]
    blue = np.array([int(SCORE_COLOUR[i : i + 2], 16) for i in (1, 3, 5)])
    drawn = np.any(np.all(np.abs(panel - blue) <= 24, axis=-1), axis=0)  # the screen columns the score line is drawn in
    assert drawn.size > 500 and drawn.mean() > 0.6


def test_hostile_text_is_shown_as_text_and_runs_nothing(seen) -> None:
    _, result = seen
    assert result.values["scripts"] == 1  # the sorter alone
    assert result.values["pwned"] == "undefined"
    assert result.values["hostile_note"] is True


def test_a_click_on_a_column_header_sorts_the_table_by_it(seen) -> None:
    _, result = seen
    attention = result.values["after_click"]
    assert len(attention) == len(DEFAULT_FLEET) + 1 and attention == sorted(attention) and attention[0] < attention[-1]
