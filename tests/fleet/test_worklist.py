"""The work list's lines (fleet/worklist.py) and their exports (fleet/export.py), from synthetic JUDGED folders."""

from __future__ import annotations

import csv
import io
import json
import re
from pathlib import Path

import pytest

from bogiemon.daemon.messages import EventMessage
from bogiemon.fleet.judged_files import ReportError, WagonState, read_judged
from bogiemon.fleet.report import since_time, work_lines, write_report
from bogiemon.fleet.worklist import DEFAULT_BOGIE, bogie_of, replay, wagon_state
from tests.fleet.judged_fixture import DEFAULT_FLEET, WagonSpec, write_judged

CONFIRMED_WAGON = "31-80-4557-001"
SENSOR_WAGON = "31-80-4557-002"
TWO_BOGIES = "31-80-4557-020"


def _message(**bogie: str) -> EventMessage:
    details = {"window_start_s": 1.8e9 - 120.0, "window_end_s": 1.8e9, "rms_mps2": [1.0, 1.0, 1.0], "problems": {"a3": ["noisy"]}}
    return EventMessage(wagon_id="w", seq=1, event_id="e1", time_s=1.8e9, kind="SENSOR_FAULT", severity="warning", config_hash="h",
                        indicators={}, details=details, **bogie)  # fmt: skip


def test_an_event_without_a_bogie_is_about_bogie_1_and_one_that_names_its_bogie_is_about_it() -> None:
    assert bogie_of(_message()) == DEFAULT_BOGIE == "1"
    assert bogie_of(_message(bogie="2")) == "2"


@pytest.fixture(scope="module")
def judged(tmp_path_factory: pytest.TempPathFactory) -> Path:
    fleet = (
        *DEFAULT_FLEET,
        WagonSpec(TWO_BOGIES, "confirmed", bogie="2"),
        WagonSpec("31-80-4557-021", "sensor_fault", bogie="1"),
        WagonSpec("31-80-4557-030", "normal", days_behind=5),
        WagonSpec("31-80-4557-022", "sensor_fault", sensor_suspension=("trailing-left", "leading-right")),
        WagonSpec("=HYPERLINK(1)", "normal", type="+cmd", notes=("@SUM(A1)",)),
    )
    return write_judged(tmp_path_factory.mktemp("worklist") / "JUDGED", fleet)


@pytest.fixture(scope="module")
def lines(judged: Path):
    return {ln.wagon: ln for ln in work_lines(read_judged(judged), 0.0)}


def test_the_state_replayed_from_each_wagons_events_is_the_judges(judged: Path) -> None:
    for page in read_judged(judged).wagons:
        assert wagon_state(replay(page.events), page.entry["windows"] > 0).value == page.entry["state"], page.entry["wagon"]


def test_a_confirmed_fault_says_which_bogie_and_axle_boxes_to_inspect_by_when(lines) -> None:
    line = lines[CONFIRMED_WAGON]
    assert line.action == "Inspect the primary springs of bogie 1, leading-left or trailing-right axle box, within 2 days."
    assert line.bogies == ("1",) and line.due_days == 2 and line.sure.word in ("clear", "confirmed")
    assert lines[TWO_BOGIES].action.startswith("Inspect the primary springs of bogie 2, leading-left or trailing-right axle box")


def test_a_sensor_fault_names_the_sensor_its_corner_and_the_problem_in_words(lines) -> None:
    line = lines[SENSOR_WAGON]
    said = "Check the sensor: sensor a3 of bogie 1 (trailing-left axle box) reads noise; fix its cable or mounting, within 7 days."
    assert line.action == said and lines["31-80-4557-021"].action == said  # no bogie in the events is bogie 1
    assert line.sure.word == "sensor" and line.sure.figure == f"{line.sensor_fault_windows}/{line.windows} windows"


def test_a_sensor_fault_whose_couplings_point_at_a_corner_is_never_told_as_a_sensor_alone(lines) -> None:
    line = lines["31-80-4557-022"]
    assert line.state is WagonState.SENSOR_FAULT and line.due_days == 2  # as urgent as the spring it may be
    assert line.action == (
        "Inspect the primary springs of bogie 1, trailing-left or leading-right axle box, and the sensor: sensor a3 of bogie 1 "
        "(trailing-left axle box) reads noise; the couplings moved as a broken spring there moves them, within 2 days."
    )


def test_a_wagon_with_both_bogies_at_fault_has_one_line_naming_both(judged: Path) -> None:
    judged_doc = read_judged(judged)
    page = next(p for p in judged_doc.wagons if p.entry["wagon"] == TWO_BOGIES)
    other = next(p for p in judged_doc.wagons if p.entry["wagon"] == CONFIRMED_WAGON)
    # The wagon's bogie 1 confirms too: its events merged in time order (bogie_of reads none: "1").
    merged = sorted([*page.events, *other.events], key=lambda m: m.time_s)
    state = replay(merged)
    assert sorted(state) == ["1", "2"] and all(s.state is WagonState.CONFIRMED for s in state.values())
    from bogiemon.fleet.worklist import action

    text, named, due = action(WagonState.CONFIRMED, state, page.entry, None)
    assert named == ("1", "2") and due == 2
    assert text == ("Inspect the primary springs of bogie 1, leading-left or trailing-right axle box; "
                    "bogie 2, leading-left or trailing-right axle box, within 2 days.")  # fmt: skip


def test_a_wagon_whose_data_stopped_stands_out_as_stale_with_what_to_do(lines) -> None:
    line = lines["31-80-4557-030"]
    assert line.stale and re.fullmatch(r"No data since \d{4}-\d\d-\d\d \d\d:\d\dZ: check the gateway's power and upload\.", line.action)
    assert not any(ln.stale for w, ln in lines.items() if w != "31-80-4557-030")


def test_changes_are_told_against_the_state_at_the_moment_from_the_events(judged: Path) -> None:
    doc = read_judged(judged)
    confirm_s = next(m.time_s for p in doc.wagons for m in p.events if p.entry["wagon"] == CONFIRMED_WAGON and m.kind == "CONFIRMED")
    before = {ln.wagon: ln for ln in work_lines(doc, confirm_s - 1.0)}[CONFIRMED_WAGON]
    after = {ln.wagon: ln for ln in work_lines(doc, confirm_s)}[CONFIRMED_WAGON]
    assert before.changed == "worse" and before.changed_text.startswith("was SUSPECTED; 1 new event")
    assert after.changed == "same" and after.changed_text == ""
    never = {ln.wagon: ln for ln in work_lines(doc, 0.0)}
    assert never[CONFIRMED_WAGON].changed == "new" and never["31-80-4557-005"].changed == "same"  # no data then, none now


def test_no_sentence_is_said_twice_on_a_line(lines) -> None:
    for line in lines.values():
        said = [line.action, *line.notes, line.sure.explained, line.changed_text]
        sentences = [s.strip() for text in said for s in re.split(r"(?<=[.;:])\s", text) if s.strip()]
        assert len(sentences) == len(set(sentences)), line.wagon


def test_the_csv_holds_every_line_with_the_jsons_fields_and_no_formula(judged: Path, tmp_path: Path) -> None:
    write_report(judged, tmp_path / "r")
    rows = list(csv.DictReader(io.StringIO((tmp_path / "r" / "worklist.csv").read_text(encoding="utf-8"))))
    doc = json.loads((tmp_path / "r" / "worklist.json").read_text(encoding="utf-8"))
    assert [r["wagon"].removeprefix("'") for r in rows] == [w["wagon"] for w in doc["wagons"]] != []
    assert list(rows[0]) == list(doc["wagons"][0])
    first = rows[0]
    assert first["state"] == "CONFIRMED" and first["action"] == doc["wagons"][0]["action"] and first["page"].startswith("wagons/")
    hostile = next(r for r in rows if "HYPERLINK" in r["wagon"])
    assert hostile["wagon"] == "'=HYPERLINK(1)" and hostile["type"] == "'+cmd" and hostile["notes"] == "'@SUM(A1)"
    assert not any(v.startswith(("=", "+", "@")) for r in rows for v in r.values())


def test_the_next_report_tells_what_changed_since_the_previous_one(tmp_path: Path) -> None:
    first = write_judged(tmp_path / "J1", (WagonSpec("w1", "normal"),))
    report = write_report(first, tmp_path / "r")
    assert report.compared_with.startswith("over the last day of data")
    until = json.loads((tmp_path / "r" / "worklist.json").read_text())["data_until_s"]
    again = write_report(first, tmp_path / "r")
    assert again.compared_with == f"since the previous report (its data until {since_until(until)})" and again.changed == 0


def since_until(time_s: float) -> str:
    from bogiemon.fleet.worklist import utc

    return utc(time_s)


def test_since_takes_a_date_or_a_time_in_utc_and_refuses_anything_else() -> None:
    assert since_time("2026-12-01") == 1796083200.0
    assert since_time("2026-12-01T06:30") == 1796083200.0 + 6.5 * 3600
    with pytest.raises(ReportError, match=r"^--since 'last week': expected a date, YYYY-MM-DD or YYYY-MM-DDTHH:MM \(UTC\)$"):
        since_time("last week")


def test_a_since_report_opens_on_the_changed_wagons_only(judged: Path, tmp_path: Path) -> None:
    summary = write_report(judged, tmp_path / "r", since="2026-12-01")
    page = (tmp_path / "r" / "index.html").read_text()
    assert summary.compared_with == "since 2026-12-01 (UTC)" and '<input type="checkbox" id="fx" checked>' in page
    assert f"{summary.changed} changed since 2026-12-01 (UTC)." in page and summary.changed >= 3
