"""A recordings tree (FLEET) made by others: names that are not UTF-8, days no clock reads, files
that are FIFOs or devices, paths that lead out of FLEET. Each is skipped and named, or one clear
error; never a traceback, a hang or a fleet refused for one bad thing (a hostile-input probe's
finding 4)."""

from __future__ import annotations

import datetime as dt
import json
import os
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from bogiemon.fleet.judge import judge_fleet
from bogiemon.fleet.layout import FleetError, scan_fleet
from bogiemon.fleet.report import write_report
from bogiemon.fleet.windows_files import partition_path
from tests.fleet import tiny
from tests.fleet.tree import DEMO_CALIBRATION

NOT_UTF8 = os.fsdecode(b"07\xff\xfe.csv.gz")  # what Python lists for a name whose bytes are not UTF-8


def _reasons(issues) -> dict[str, str]:
    return {Path(i.path).name: i.reason for i in issues}


def test_a_recording_whose_name_is_not_utf8_is_skipped_and_named_and_the_rest_goes_on(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    good = root / "W1" / tiny.DAYS[0] / "060000_run.csv.gz"
    (good.parent / NOT_UTF8).write_bytes(good.read_bytes())

    for run in range(2):  # the probe's run failed every time: so must the rerun not
        summary = tiny.analyze(root, tmp_path / "windows")
        assert (summary.partitions, summary.analysed) == (4, 4 - 4 * run)
    judged = judge_fleet(tmp_path / "windows", tmp_path / "judged")
    report = write_report(tmp_path / "judged", tmp_path / "report")

    named = [i for i in summary.issues if "not UTF-8" in i.reason]
    assert [i.path for i in named] == [str(good.parent / "07\\xff\\xfe.csv.gz")]
    table = pq.read_table(partition_path(tmp_path / "windows", "W1", tiny.DAYS[0]))
    assert set(table.column("recording").to_pylist()) == {good.name}
    assert any(i.path.endswith("07\\xff\\xfe.csv.gz") for i in judged.issues)
    assert report.wagons == 2 and "07\\xff\\xfe.csv.gz" in (tmp_path / "report" / "index.html").read_text(encoding="utf-8")


def test_wagon_and_day_folders_whose_names_are_not_utf8_are_skipped_and_named(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet", wagons=("W1",))
    (root / os.fsdecode(b"W\xff")).mkdir()
    (root / "W1" / os.fsdecode(b"2026-11-0\xff")).mkdir()
    reasons = _reasons(scan_fleet(root).issues)
    assert "not UTF-8" in reasons["W\\xff"] and "not UTF-8" in reasons["2026-11-0\\xff"]


def test_a_fleet_folder_whose_name_is_not_utf8_is_one_clear_error(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / os.fsdecode(b"fleet\xff"))
    with pytest.raises(FleetError, match=r"fleet\\xff: the fleet folder's name is not UTF-8"):
        scan_fleet(root)
    with pytest.raises(FleetError, match=r"windows\\xff: WINDOWS must have a UTF-8 name"):
        tiny.analyze(tiny.fleet(tmp_path / "fleet"), tmp_path / os.fsdecode(b"windows\xff"))


AFTER_TOMORROW = (dt.datetime.now(dt.UTC).date() + dt.timedelta(days=2)).isoformat()


@pytest.mark.parametrize("date", ["0001-01-01", "9999-12-31", "1999-12-31", "2100-01-01", AFTER_TOMORROW])
def test_a_day_no_gateways_clock_reads_is_skipped_and_the_fleet_judged_and_reported(tmp_path: Path, date: str) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    # Times from the recording's own origin, which the analysis places at its day's midnight.
    tiny.recording(root / "W1" / date / "000000_run.csv.gz", None)

    summary = tiny.analyze(root, tmp_path / "windows")
    judged = judge_fleet(tmp_path / "windows", tmp_path / "judged")
    report = write_report(tmp_path / "judged", tmp_path / "report")

    newest = min("2099-12-31", (dt.datetime.now(dt.UTC).date() + dt.timedelta(days=1)).isoformat())
    assert _reasons(summary.issues)[date] == f"a day outside 2000-01-01 .. {newest} (no gateway's clock reads it now); skipped"
    assert summary.partitions == 4 and judged.wagons == 2 and report.wagons == 2


def test_tomorrow_is_a_day_a_clock_reads_somewhere_already(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet", wagons=("W1",), days=(tiny.DAYS[0], "2026-12-04"))
    assert [d.date for d in scan_fleet(root, today=dt.date(2026, 12, 3)).wagon("W1").days] == [tiny.DAYS[0], "2026-12-04"]
    assert [d.date for d in scan_fleet(root, today=dt.date(2026, 12, 2)).wagon("W1").days] == [tiny.DAYS[0]]


def test_fleet_toml_as_a_fifo_is_one_clear_error_without_blocking(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    os.mkfifo(root / "fleet.toml")
    error = tiny.without_blocking(lambda: scan_fleet(root))
    assert isinstance(error, FleetError) and str(error) == f"{root / 'fleet.toml'}: not a regular file; " + 'fleet.toml is a page of TOML ([fleet] and [wagons."<id>"])'


def test_fleet_toml_as_a_link_to_dev_zero_is_one_clear_error_without_reading_it(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    (root / "fleet.toml").symlink_to("/dev/zero")
    error = tiny.without_blocking(lambda: scan_fleet(root))
    assert isinstance(error, FleetError)
    assert "leads out of the fleet folder" in str(error)


def test_fleet_toml_larger_than_a_page_of_toml_is_refused_before_it_is_read(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    with (root / "fleet.toml").open("wb") as f:
        f.truncate(1 << 30)  # sparse: a GiB of zeros that costs nothing on disk
    with pytest.raises(FleetError, match=r"fleet\.toml: larger than 1024 KiB; fleet\.toml is a page of TOML: is this the right file\?$"):
        scan_fleet(root)


@pytest.mark.parametrize("config", ["../..", "../outside.toml", "/etc/passwd", "configs/../../outside.toml"])
def test_a_config_fleet_toml_names_outside_the_fleet_skips_that_wagon_only(tmp_path: Path, config: str) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    (tmp_path / "outside.toml").write_text(tiny.CONFIG, encoding="utf-8")
    (root / "fleet.toml").write_text(f'[wagons.W1]\nconfig = "{config}"\n', encoding="utf-8")
    fleet = scan_fleet(root)
    assert [w.wagon_id for w in fleet.wagons] == ["W2"]
    reason = _reasons(fleet.issues)["W1"]
    assert "leads out of the fleet folder" in reason or "expected a path relative to the fleet folder" in reason
    with pytest.raises(FleetError, match=r"W1: .*wagon skipped"):
        fleet.wagon("W1")


def test_a_calibration_symlinked_outside_the_fleet_skips_the_wagon_and_says_so(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    (root / "W1" / "calibration.toml").symlink_to(DEMO_CALIBRATION)
    fleet = scan_fleet(root)
    assert [w.wagon_id for w in fleet.wagons] == ["W2"]
    assert _reasons(fleet.issues)["calibration.toml"].startswith("leads out of the fleet folder")


def test_a_calibration_that_is_a_fifo_skips_the_wagon_rather_than_judging_it_uncommissioned(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    os.mkfifo(root / "W1" / "calibration.toml")
    scanned = []
    assert tiny.without_blocking(lambda: scanned.append(scan_fleet(root))) is None
    assert [w.wagon_id for w in scanned[0].wagons] == ["W2"]
    assert "calibration.toml: not a regular file" in _reasons(scanned[0].issues)["bogiemon.toml"]


def test_recordings_and_days_symlinked_outside_the_fleet_are_skipped(tmp_path: Path) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    elsewhere = tiny.recording(tmp_path / "elsewhere" / "2026-11-04" / "060000_x.csv.gz", "2026-11-04", "06:00")
    (root / "W1" / "2026-11-04").symlink_to(elsewhere.parent)
    (root / "W2" / tiny.DAYS[0] / "070000_x.csv.gz").symlink_to(elsewhere)
    (root / "W2" / tiny.DAYS[0] / "080000_zero.csv").symlink_to("/dev/zero")
    reasons = _reasons(scan_fleet(root).issues)
    assert reasons["2026-11-04"].startswith("leads out of the fleet folder")
    assert reasons["070000_x.csv.gz"].startswith("leads out of the fleet folder")
    assert reasons["080000_zero.csv"].startswith("not a recording")


def test_the_analysis_summary_is_json_every_reader_takes(tmp_path: Path) -> None:
    # Python's json writes a lone surrogate as \udcff, which strict readers refuse: none is left.
    root = tiny.fleet(tmp_path / "fleet")
    (root / "W1" / tiny.DAYS[0] / NOT_UTF8).write_bytes(b"x")
    tiny.analyze(root, tmp_path / "windows")
    text = (tmp_path / "windows" / "_analysis.json").read_bytes()
    assert b"\\udc" not in text
    json.loads(text.decode("utf-8"))
