"""`fleet report`: a JUDGED folder as the work list and a page per wagon (fleet/report.py, fleet/svg.py)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.fleet import svg
from bogiemon.fleet.judged_files import ReportError
from bogiemon.fleet.plot import GAP_PX, LEFT_PX, MAX_IDLE_S, MAX_POINTS_PER_PANEL, RIGHT_PX, SCORE_TOP_PX
from bogiemon.fleet.report import write_report
from bogiemon.fleet.worklist import file_id
from tests.fleet.judged_fixture import DEFAULT_FLEET, FleetShape, WagonSpec, read_wagons_json, write_judged, write_wagons_json

CONFIRMED_WAGON = "31-80-4557-001"
NORMAL_WAGON = "31-80-4557-003"


@pytest.fixture
def judged(tmp_path: Path) -> Path:
    return write_judged(tmp_path / "JUDGED")


class _Report(str):
    """The work list's page as text, and the report's folder."""

    folder: Path


def _page(judged: Path, tmp_path: Path) -> _Report:
    out = tmp_path / "report"
    write_report(judged, out)
    page = _Report((out / "index.html").read_text(encoding="utf-8"))
    page.folder = out
    return page


def _section(page: _Report, wagon: str) -> str:
    """The wagon's own page."""
    return (page.folder / "wagons" / f"{file_id(wagon)}.html").read_text(encoding="utf-8")


def _table_order(page: str) -> list[str]:
    body = page[page.index('<table class="work"') :]
    body = body[: body.index("</table>")]
    return re.findall(r'<td class="id"><a href="wagons/[^"]*">([^<]*)</a>', body)


def _events(judged: Path) -> list[dict]:
    return [json.loads(line) for line in (judged / "events.jsonl").read_text().splitlines()]


# --- the page ---------------------------------------------------------------------------------


def test_table_lists_wagons_by_attention_descending_even_when_the_file_is_not_sorted(judged: Path, tmp_path: Path) -> None:
    wagons = read_wagons_json(judged)["wagons"]
    as_written = [w["wagon"] for w in wagons]
    by_attention = [w["wagon"] for w in sorted(wagons, key=lambda w: -w["attention"])]
    assert as_written != by_attention  # the fixture writes them out of order
    assert _table_order(_page(judged, tmp_path)) == by_attention


def test_every_wagon_has_a_page_with_a_plot_that_the_work_list_links_to(judged: Path, tmp_path: Path) -> None:
    page = _page(judged, tmp_path)
    for spec in DEFAULT_FLEET:
        assert f'href="wagons/{file_id(spec.wagon)}.html"' in page
        assert "<svg" in _section(page, spec.wagon) and 'href="../index.html"' in _section(page, spec.wagon)
    assert "<svg" not in page  # the work list is lines only: a fleet of thousands stays small


def test_each_event_is_a_vertical_line_of_its_kind_on_its_wagons_plot(judged: Path, tmp_path: Path) -> None:
    page = _page(judged, tmp_path)
    for spec in DEFAULT_FLEET:
        section = _section(page, spec.wagon)
        expected = sorted(
            f'class="e e-{e["kind"]}"><title>{e["kind"]} {svg.utc_label(e["time_s"])} (seq {e["seq"]})</title>'
            for e in _events(judged)
            if e["wagon_id"] == spec.wagon
        )
        marks = sorted(re.findall(r'class="e e-[A-Z_]+"><title>[^<]*</title>', section))
        assert marks == expected
    assert "CONFIRMED</text>" in _section(page, CONFIRMED_WAGON)  # and labelled


def test_the_line_breaks_at_each_gap_between_recordings(judged: Path, tmp_path: Path) -> None:
    # Two days of two recordings each: four stretches of windows, so four moves in the score path.
    section = _section(_page(judged, tmp_path), NORMAL_WAGON)
    score = re.search(r'<path class="s" d="([^"]*)"', section).group(1)
    trend = re.search(r'<path class="t" d="([^"]*)"', section).group(1)
    assert score.count("M") == 4 and trend.count("M") == 4


def test_a_wagon_without_windows_has_an_empty_plot_that_says_so(judged: Path, tmp_path: Path) -> None:
    section = _section(_page(judged, tmp_path), "31-80-4557-005")
    assert "<svg" in section and "no judged windows" in section and '<path class="s"' not in section


def test_header_counts_wagons_per_state_and_lists_the_skipped_inputs(judged: Path, tmp_path: Path) -> None:
    page = _page(judged, tmp_path)
    header = page[page.index("<header>") : page.index("</header>")]
    assert '<button type="button" data-state="CONFIRMED"><span class="b b-CONFIRMED">CONFIRMED</span> 1</button>' in header
    assert '<button type="button" data-state="NORMAL"><span class="b b-NORMAL">NORMAL</span> 2</button>' in header
    assert "<details><summary>1 input skipped</summary>" in header
    assert "<td>31-80-4557-003/2026-11-31</td><td>day folder name is no date</td>" in header


def test_each_line_says_what_to_do_and_how_sure_with_the_figure_explained(judged: Path, tmp_path: Path) -> None:
    page = _page(judged, tmp_path)
    rows = {w: row for w, row in zip(_table_order(page), re.findall(r"<tr [^>]*><td class=\"id\">.*?</tr>", page), strict=True)}
    assert "Inspect the primary springs of bogie 1, leading-left or trailing-right axle box, within 2 days." in rows[CONFIRMED_WAGON]
    assert "Check the sensor: sensor a3 of bogie 1 (trailing-left axle box) reads noise; fix its cable or mounting, within 7 days." in rows["31-80-4557-002"]
    entry = next(w for w in read_wagons_json(judged)["wagons"] if w["wagon"] == NORMAL_WAGON)
    ratio = entry["trend"] / entry["trend_alarm"]
    assert f'title="the trend of the fused score ({entry["trend"]:.3g}) is {ratio:.2g} times its alarm level' in rows[NORMAL_WAGON]
    assert f"healthy · {ratio:.2g}x alarm</span>" in rows[NORMAL_WAGON] and "Nothing to do." in rows[NORMAL_WAGON]


def test_the_pages_refer_to_nothing_outside_the_report(judged: Path, tmp_path: Path) -> None:
    page = _page(judged, tmp_path)
    wagon = _section(page, CONFIRMED_WAGON)
    for text in (page, wagon):
        for outside in ("http://", "https://", "src=", "<link", "@import", "url(", "//cdn"):
            assert outside not in text, outside
    links = set(re.findall(r'href="([^"]*)"', page))
    assert links == {"worklist.csv", "worklist.json"} | {f"wagons/{file_id(s.wagon)}.html" for s in DEFAULT_FLEET}
    assert set(re.findall(r'href="([^"]*)"', wagon)) == {"../index.html"}
    assert page.count("<script") == 1 and "<script" not in wagon  # the work list's filter and sorter, inline


def test_text_from_the_data_is_escaped_and_inert(tmp_path: Path) -> None:
    hostile = '<script>alert("id")</script>'
    fleet = (
        *DEFAULT_FLEET,
        WagonSpec(hostile, "no_data", type="<b>t</b>", notes=('<img src=x onerror="alert(1)">', "</td></tr></table><script>alert(2)</script>")),
    )
    judged = write_judged(tmp_path / "JUDGED", fleet, fleet='Keeper "X" <script>alert(3)</script>', skipped=(("<script>p</script>", "<i>r</i>"),))
    page = _page(judged, tmp_path)
    wagon = _section(page, hostile)
    assert page.count("<script") == 1 and "<img" not in page and "<b>t</b>" not in page and "<i>r</i>" not in page
    assert "<script" not in wagon and "<img" not in wagon
    assert "&lt;script&gt;alert(&quot;id&quot;)&lt;/script&gt;" in page
    assert "&lt;img src=x onerror=&quot;alert(1)&quot;&gt;" in page
    assert re.fullmatch(r"[A-Za-z0-9._~-]+", file_id(hostile))


def test_summary_states_the_folder_it_wrote(judged: Path, tmp_path: Path) -> None:
    out = tmp_path / "r"
    summary = write_report(judged, out, title="Fleet page")
    assert summary.path == out and summary.bytes == (out / "index.html").stat().st_size and summary.wagons == len(DEFAULT_FLEET)
    assert sorted(p.name for p in out.iterdir()) == ["index.html", "wagons", "worklist.csv", "worklist.json"]
    assert len(list((out / "wagons").iterdir())) == len(DEFAULT_FLEET)
    assert dict(summary.states) == {"CONFIRMED": 1, "SUSPECTED": 1, "SENSOR_FAULT": 1, "NOT_JUDGED": 0, "NORMAL": 2, "NO_DATA": 1}
    assert summary.events == len(_events(judged)) and summary.skipped_inputs == 1
    assert "<title>Fleet page</title>" in (out / "index.html").read_text()


def test_a_long_series_is_decimated_to_the_panel_limit_keeping_its_peak(tmp_path: Path) -> None:
    judged = write_judged(tmp_path / "J", (WagonSpec("w1", "normal"),), FleetShape(days=1, recordings_per_day=1, windows_per_recording=20_000))
    path = judged / "series" / "wagon=w1" / "part-0.parquet"
    table = pq.read_table(path)
    score = np.array(table.column("score").to_numpy(zero_copy_only=False))
    peak = 15_000
    score[peak] = 1e4  # one window far above the rest
    pq.write_table(table.set_column(table.schema.get_field_index("score"), "score", pa.array(score)), path)
    summary = write_report(judged, tmp_path / "r")
    section = (tmp_path / "r" / "wagons" / "w1.html").read_text()
    d = re.search(r'<path class="s" d="([^"]*)"', section).group(1)
    xs, ys = _absolute_points(d)
    assert len(xs) <= MAX_POINTS_PER_PANEL and summary.points <= 2 * MAX_POINTS_PER_PANEL
    assert min(ys) == pytest.approx(SCORE_TOP_PX, abs=0.05)  # the peak (1e4, the axis' top) is drawn


# --- the broken time axis: nights and long pauses cut, runs at one scale ---------------------------


def _series_times(judged: Path, wagon: str) -> np.ndarray:
    return np.array(pq.read_table(judged / "series" / f"wagon={wagon}" / "part-0.parquet", columns=["time_s"]).column("time_s").to_numpy())


def _bands(section: str) -> list[tuple[float, float]]:
    return [(float(x), float(w)) for x, w in re.findall(r'<rect x="([-\d.]+)" y="[-\d.]+" width="([-\d.]+)" height="[-\d.]+" class="brk">', section)]


def _covered_fraction(d: str) -> float:
    """The share of the plot's width the path's strokes pass over: the union of its subpaths' x ranges."""
    covered = 0.0
    for sub in d.split("M")[1:]:
        xs, _ = _absolute_points("M" + sub)
        covered += max(xs) - min(xs)
    return covered / (RIGHT_PX - LEFT_PX)


def test_each_pause_over_the_idle_limit_is_a_band_on_both_panels_with_its_length(judged: Path, tmp_path: Path) -> None:
    # Two days of runs from 06:02 to 07:01:50 and 11:02 to 12:01:50: pauses of 4 h, 18 h (the night), 4 h.
    section = _section(_page(judged, tmp_path), NORMAL_WAGON)
    bands = _bands(section)
    assert len(bands) == 2 * 3 and all(w == GAP_PX for _, w in bands)
    assert [x for x, _ in bands[:3]] == [x for x, _ in bands[3:]]  # the score and the trend panel share the axis
    assert re.findall(r'class="gl" text-anchor="middle">([^<]*)</text>', section) == ["4 h", "18 h", "4 h"]
    assert section.count("<title>no data for 18 h: 2026-11-30 12:01:50Z to 2026-12-01 06:02:00Z (cut from the axis)</title>") == 2


def test_the_runs_fill_most_of_the_plot_and_keep_their_true_relative_lengths(judged: Path, tmp_path: Path) -> None:
    # On the old linear axis four one-hour runs over 30 hours covered about 14 % of the width.
    section = _section(_page(judged, tmp_path), NORMAL_WAGON)
    d = re.search(r'<path class="s" d="([^"]*)"', section).group(1)
    widths = [max(xs) - min(xs) for xs, _ in (_absolute_points("M" + sub) for sub in d.split("M")[1:])]
    assert _covered_fraction(d) > 0.85
    # Four equally long runs, equally wide: to a bucket of the decimation (0.6 px, which keeps each
    # bucket's largest value at its own time) at either end.
    assert max(widths) - min(widths) <= 1.3


def test_each_day_is_labelled_with_its_date_at_its_first_run(judged: Path, tmp_path: Path) -> None:
    section = _section(_page(judged, tmp_path), NORMAL_WAGON)
    axis = svg.broken_axis(_series_times(judged, NORMAL_WAGON), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    dates = re.findall(r'<text x="([-\d.]+)" y="[-\d.]+" class="dl">([^<]*)</text>', section)
    first_runs = [float(axis.start_px[0]), float(axis.start_px[2])]  # 06:02 on each day
    assert [label for _, label in dates] == ["2026-11-30", "2026-12-01"]
    assert [float(x) for x, _ in dates] == pytest.approx([x + 2 for x in first_runs], abs=0.05)


def _event_lines(section: str) -> list[tuple[float, str]]:
    """Each event mark's x and tooltip, in the page's order."""
    found = re.findall(r'<line x1="([-\d.]+)" y1="[-\d.]+" x2="[-\d.]+" y2="[-\d.]+" class="e e-[A-Z_]+"><title>([^<]*)</title>', section)
    return [(float(x), title) for x, title in found]


def test_events_are_drawn_at_their_true_time_on_the_broken_axis(judged: Path, tmp_path: Path) -> None:
    section = _section(_page(judged, tmp_path), CONFIRMED_WAGON)
    axis = svg.broken_axis(_series_times(judged, CONFIRMED_WAGON), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    times = [e["time_s"] for e in _events(judged) if e["wagon_id"] == CONFIRMED_WAGON]
    xs = [x for x, _ in _event_lines(section)]
    assert len(times) >= 2 and xs == pytest.approx(axis.px(np.array(times)).tolist(), abs=0.05)


def test_an_event_inside_a_cut_gap_is_drawn_at_the_gaps_start(judged: Path, tmp_path: Path) -> None:
    lines = (judged / "events.jsonl").read_text().splitlines()
    at = next(i for i, line in enumerate(lines) if json.loads(line)["wagon_id"] == CONFIRMED_WAGON)
    event = json.loads(lines[at])
    event["time_s"] = night_s = 1796078400.0  # 2026-11-30 22:40Z: the night, which is cut
    lines[at] = json.dumps(event, separators=(",", ":"))
    (judged / "events.jsonl").write_text("\n".join(lines) + "\n")
    section = _section(_page(judged, tmp_path), CONFIRMED_WAGON)
    night = _bands(section)[1]
    # Its tooltip keeps its true time; its mark is at the band's left edge, where the night began.
    tip = f"{event['kind']} {svg.utc_label(night_s)} (seq {event['seq']})"
    assert svg.utc_label(night_s) == "2026-11-30 22:40:00Z"
    assert [x for x, title in _event_lines(section) if title == tip] == [night[0]]


# --- a bad JUDGED folder: one line naming the file and the field -------------------------------


def test_a_missing_folder_is_a_report_error(tmp_path: Path) -> None:
    with pytest.raises(ReportError, match=r"no such folder"):
        write_report(tmp_path / "nope", tmp_path / "r")


def _mutated(tmp_path: Path, change) -> Path:
    judged = write_judged(tmp_path / "JUDGED")
    doc = read_wagons_json(judged)
    change(doc)
    write_wagons_json(judged, doc)
    return judged


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda d: d["wagons"][1].pop("attention"), r"wagons\.json: wagons\[1\]: missing field 'attention'"),
        (lambda d: d.pop("inputs"), r"wagons\.json: top level: missing field 'inputs'"),
        (lambda d: d["wagons"][1]["last_event"].pop("time_utc"), r"wagons\[1\]\.last_event: missing field 'time_utc'"),
        (lambda d: d["wagons"][1].update(diagnosis={"corner": "x"}), r"wagons\[1\]\.diagnosis: missing field 'kind'"),
        (lambda d: d["wagons"][2].update(days="two"), r"wagons\[2\]\.days: expected an integer"),
        (lambda d: d["wagons"][2].update(state="BROKEN"), r"wagons\[2\]\.state: 'BROKEN' is none of"),
        (lambda d: d["wagons"][2].update(wagon=d["wagons"][0]["wagon"]), r"wagons\[2\]: wagon '31-80-4557-003' is listed twice"),
        (lambda d: d.update(format=1), r"wagons\.json: format 1, this bogiemon reads format 3"),
    ],
    ids=["wagon-field", "top-field", "last-event-field", "diagnosis-field", "type", "state", "duplicate", "format"],
)
def test_a_wagons_json_off_the_contract_is_one_line_naming_the_file_and_field(tmp_path: Path, change, message: str) -> None:
    judged = _mutated(tmp_path, change)
    with pytest.raises(ReportError, match=message) as info:
        write_report(judged, tmp_path / "r")
    assert "\n" not in str(info.value) and str(judged / "wagons.json") in str(info.value)
    assert not (tmp_path / "r").exists()


def test_wagons_json_that_is_not_json_is_a_report_error(judged: Path, tmp_path: Path) -> None:
    (judged / "wagons.json").write_text('{"format": 3, "wagons": [', encoding="utf-8")
    with pytest.raises(ReportError, match=r"wagons\.json: not valid JSON \("):
        write_report(judged, tmp_path / "r")


def test_a_nan_reads_as_null_so_a_nan_attention_is_named(judged: Path, tmp_path: Path) -> None:
    doc = read_wagons_json(judged)
    doc["wagons"][0]["attention"] = float("nan")
    doc["wagons"][0]["trend"] = float("nan")
    write_wagons_json(judged, doc)  # Python's json writes NaN
    with pytest.raises(ReportError, match=r"wagons\[0\]\.attention: expected a number$"):
        write_report(judged, tmp_path / "r")
    doc["wagons"][0]["attention"] = 1.0
    write_wagons_json(judged, doc)
    assert write_report(judged, tmp_path / "r").wagons == len(DEFAULT_FLEET)  # a NaN trend is none


def test_a_diagnosis_with_unknown_parts_says_unknown_for_them(judged: Path, tmp_path: Path) -> None:
    doc = read_wagons_json(judged)
    confirmed = next(w for w in doc["wagons"] if w["wagon"] == CONFIRMED_WAGON)
    confirmed["diagnosis"] = {"corner": None, "kind": "friction", "corner_confidence": None, "kind_confidence": 0.6}
    write_wagons_json(judged, doc)
    section = _section(_page(judged, tmp_path), CONFIRMED_WAGON)
    assert "<dt>Diagnosis</dt><dd>corner: not told</dd>" in section


def test_a_missing_wagons_json_is_a_report_error(judged: Path, tmp_path: Path) -> None:
    (judged / "wagons.json").unlink()
    with pytest.raises(ReportError, match=r"wagons\.json: missing"):
        write_report(judged, tmp_path / "r")


def test_a_bad_event_line_names_its_line(judged: Path, tmp_path: Path) -> None:
    lines = (judged / "events.jsonl").read_text().splitlines()
    lines[2] = lines[2].replace('"kind":"', '"kind":"X')
    (judged / "events.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ReportError, match=r"events\.jsonl: line 3: kind: "):
        write_report(judged, tmp_path / "r")


def test_a_series_without_a_column_names_the_file_and_column(judged: Path, tmp_path: Path) -> None:
    path = judged / "series" / f"wagon={NORMAL_WAGON}" / "part-0.parquet"
    pq.write_table(pq.read_table(path).drop_columns(["trend"]), path)
    with pytest.raises(ReportError, match=rf"wagon={NORMAL_WAGON}/part-0\.parquet: missing column 'trend'"):
        write_report(judged, tmp_path / "r")


def test_a_series_time_outside_unix_seconds_is_a_report_error(judged: Path, tmp_path: Path) -> None:
    path = judged / "series" / f"wagon={NORMAL_WAGON}" / "part-0.parquet"
    table = pq.read_table(path)
    time_s = np.array(table.column("time_s").to_numpy())
    time_s[5] = 1e300
    pq.write_table(table.set_column(0, "time_s", pa.array(time_s)), path)
    with pytest.raises(ReportError, match=r"part-0\.parquet: column 'time_s': a time outside Unix seconds"):
        write_report(judged, tmp_path / "r")


def test_a_wagon_id_that_is_no_folder_name_reads_no_series(tmp_path: Path) -> None:
    judged = write_judged(tmp_path / "JUDGED", (WagonSpec("../../etc", "no_data"),))
    page = _page(judged, tmp_path)
    assert "no series is read for it" in _section(page, "../../etc")


def test_an_output_that_is_no_folder_is_a_report_error(judged: Path, tmp_path: Path) -> None:
    (tmp_path / "r").write_text("a file")
    with pytest.raises(ReportError, match=r"r: not a folder; the report is a folder"):
        write_report(judged, tmp_path / "r")
    with pytest.raises(ReportError, match=r"r\.html: the report is a folder \(index\.html, worklist\.csv, a page per wagon\): name a folder$"):
        write_report(judged, tmp_path / "r.html")


# --- svg.py against direct references ---------------------------------------------------------


def _absolute_points(d: str) -> tuple[list[float], list[float]]:
    """The points of a path written by svg.path_d (M x y, then l dx dy ... or h.1), absolute."""
    xs: list[float] = []
    ys: list[float] = []
    for command, args in re.findall(r"([Mlh])([^Mlh]*)", d):
        numbers = [float(v) for v in re.findall(r"-?(?:\d+\.?\d*|\.\d+)", args)]
        if command == "M":
            xs.append(numbers[0])
            ys.append(numbers[1])
        elif command == "l":
            for dx, dy in zip(numbers[::2], numbers[1::2], strict=True):
                xs.append(xs[-1] + dx)
                ys.append(ys[-1] + dy)
    return xs, ys


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1000, allow_nan=False), st.floats(-500, 500, allow_nan=False)), min_size=1, max_size=60), st.integers(0, 3))
def test_path_d_draws_every_point_at_its_rounded_position(points: list[tuple[float, float]], n_breaks: int) -> None:
    x = np.array([p[0] for p in points])
    y = np.array([p[1] for p in points])
    segments = np.sort(np.random.default_rng(len(points)).integers(0, n_breaks + 1, size=x.size))
    xs, ys = _absolute_points(svg.path_d(x, y, segments))
    assert np.allclose(xs, np.round(x, 1), atol=1e-6) and np.allclose(ys, np.round(y, 1), atol=1e-6)
    assert svg.path_d(x, y, segments).count("M") == len(np.unique(segments))


def _decimate_reference(t, v, seg, t0, t1, buckets):
    groups: dict[tuple[int, int], list[int]] = {}
    for i in range(t.size):
        b = min(max(int((t[i] - t0) / (t1 - t0) * buckets), 0), buckets - 1)
        groups.setdefault((int(seg[i]), b), []).append(i)
    return sorted(max(g, key=lambda i: (v[i], -i)) for g in groups.values())


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0, 1e3, allow_nan=False), min_size=1, max_size=300), st.integers(1, 40), st.integers(0, 2**31))
def test_decimate_max_keeps_each_buckets_largest_value(values: list[float], buckets: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(0.5, 20.0, size=len(values)))
    v = np.array(values)
    seg = svg.gap_segments(t, 15.0)
    t0, t1 = float(t[0]), float(t[-1]) + 1.0
    dt, dv, ds = svg.decimate_max(t, v, seg, t0, t1, buckets)
    keep = _decimate_reference(t, v, seg, t0, t1, buckets)
    assert dv.tolist() == v[keep].tolist() and dt.tolist() == t[keep].tolist() and ds.tolist() == seg[keep].tolist()
    assert dt.size <= buckets + int(seg[-1]) + 1


def test_gap_segments_break_only_where_windows_are_further_apart_than_the_gap() -> None:
    t = np.array([0.0, 10, 20, 50, 60, 100, 110])
    assert svg.gap_segments(t, 35.0).tolist() == [0, 0, 0, 0, 0, 1, 1]


def test_run_ends_keeps_the_first_and_last_point_of_each_level() -> None:
    level = np.array([5.0, 5, 5, 7, 7, 7, 7, 5])
    assert svg.run_ends(level, np.array([0, 0, 0, 0, 1, 1, 1, 1])).tolist() == [0, 2, 3, 4, 6, 7]


def test_non_positive_values_are_drawn_at_the_bottom_of_a_log_axis() -> None:
    y = svg.log_px(np.array([0.0, -3.0, 1e-9, 1.0, 100.0]), 1.0, 100.0, 50.0, 210.0)
    assert y.tolist() == [210.0, 210.0, 210.0, 210.0, 50.0]


def test_log_range_spans_whole_decades_holding_values_and_levels() -> None:
    assert svg.log_range(np.array([3.0, 12.0]), [67.0]) == (1.0, 100.0)
    assert svg.log_range(np.array([1e-9, 1000.0])) == (0.1, 1000.0)  # at most four decades


@settings(max_examples=100, deadline=None)
@given(st.text(min_size=1, max_size=20), st.text(min_size=1, max_size=20))
def test_file_id_is_a_safe_file_name_and_one_to_one(a: str, b: str) -> None:
    assert re.fullmatch(r"[A-Za-z0-9_~-][A-Za-z0-9._~-]*", file_id(a))
    assert (file_id(a) == file_id(b)) == (a == b)
