"""WINDOWS and JUDGED touched by others after the back office wrote them: a partition damaged,
edited or replaced, JUDGED's files replaced by FIFOs, devices or junk. `fleet analyze` analyses a
damaged day again and says so, `fleet judge` names the day and judges the rest, `fleet report`
is one clear error; never a traceback, a hang, or a damaged partition trusted (a hostile-input
probe's finding 4)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bogiemon.fleet.judge import judge_fleet
from bogiemon.fleet.judged_files import ReportError
from bogiemon.fleet.layout import day_start_s
from bogiemon.fleet.report import write_report
from bogiemon.drivers.atomic import temporary_name
from bogiemon.fleet.windows_files import DIGEST_KEY, METADATA_KEY, PART_FILE, partition_path, read_partition
from tests.fleet import tiny

DAY = tiny.DAYS[0]


def _rewrite_metadata(path: Path, change: Callable[[Any], object]) -> None:
    """The partition's metadata changed and its digest made to match, as a careful hand would."""
    table = pq.read_table(path)
    text = json.dumps(change(json.loads(table.schema.metadata[METADATA_KEY]))).encode()
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: text, DIGEST_KEY: hashlib.sha256(text).hexdigest().encode()}), path)


def _null_status(path: Path) -> None:
    table = pq.read_table(path)
    name = next(n for n in table.column_names if n.startswith("status"))
    nulls = pa.array([None] * table.num_rows, type=table.schema.field(name).type)
    pq.write_table(table.set_column(table.column_names.index(name), name, nulls), path)


def _fifo(path: Path) -> None:
    path.unlink()
    os.mkfifo(path)


def _folder(path: Path) -> None:
    path.unlink()
    path.mkdir()


def _link_out(path: Path) -> None:
    outside = path.parents[3] / "outside.parquet"
    shutil.move(path, outside)
    path.symlink_to(outside)


def _changed_window(path: Path) -> None:
    table = pq.read_table(path)
    end_s = table.column("end_s").to_pylist()
    end_s[0] += 1.0
    pq.write_table(table.set_column(table.column_names.index("end_s"), "end_s", pa.array(end_s)), path)


DAMAGES: dict[str, tuple[Callable[[Path], object], str]] = {
    "metadata []": (lambda p: _rewrite_metadata(p, lambda _: []), "its metadata is not a JSON object"),
    "segment_starts not a list": (lambda p: _rewrite_metadata(p, lambda m: {**m, "segment_starts": "x"}), "metadata segment_starts"),
    "segment_starts in year 1": (lambda p: _rewrite_metadata(p, lambda m: {**m, "segment_starts": [[-6.2e10, 200.0, False]]}), "metadata segment_starts"),
    "metadata edited, digest kept": (lambda p: _edit_keeping_digest(p), "does not match its digest"),
    "a null status column": (_null_status, "null values"),
    "a window edited": (_changed_window, "its windows do not match their digest"),
    "random bytes": (lambda p: p.write_bytes(os.urandom(5000)), "not a readable Parquet file"),
    "cut in half": (lambda p: p.write_bytes(p.read_bytes()[: p.stat().st_size // 2]), "not a readable Parquet file"),
    "empty": (lambda p: p.write_bytes(b""), "not a readable Parquet file"),
    "a FIFO": (_fifo, "a FIFO in the place of the partition"),
    "a folder": (_folder, "a folder in the place of the partition"),
    "a symlink out of WINDOWS": (_link_out, "a symlink in the place of the partition"),
}


def _edit_keeping_digest(path: Path) -> None:
    table = pq.read_table(path)
    meta = dict(table.schema.metadata)
    meta[METADATA_KEY] = meta[METADATA_KEY].replace(b'"covered":0', b'"covered":7')
    pq.write_table(table.replace_schema_metadata(meta), path)


@pytest.mark.parametrize("damage", list(DAMAGES))
def test_a_damaged_partition_is_named_by_judge_and_analysed_again_by_analyze(tmp_path: Path, damage: str) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    windows = tmp_path / "windows"
    tiny.analyze(root, windows)
    path = partition_path(windows, "W1", DAY)
    sound = pq.read_table(path).column("end_s").to_pylist()
    spoil, problem = DAMAGES[damage]
    spoil(path)

    judged: list[object] = []
    assert tiny.without_blocking(lambda: judged.append(judge_fleet(windows, tmp_path / "judged"))) is None
    (named,) = [i for i in judged[0].issues if i.path == str(path)]  # type: ignore[attr-defined]
    assert problem in named.reason and "day not judged" in named.reason
    assert judged[0].wagons == 2  # type: ignore[attr-defined]
    write_report(tmp_path / "judged", tmp_path / "report")

    again = tiny.analyze(root, windows)
    assert [(i.path, problem in i.reason) for i in again.repaired] == [(str(path), True)]
    assert (again.analysed, again.reused) == (1, 3)
    assert read_partition(path, day_start_s(DAY)).table.column("end_s").to_pylist() == sound
    assert tiny.analyze(root, windows).repaired == ()


def test_analyze_redoes_a_partition_damaged_after_a_run_whose_footer_still_reads(tmp_path: Path) -> None:
    # Not as the last run left it (its ledger entry differs): read whole before it is trusted.
    root = tiny.fleet(tmp_path / "fleet")
    windows = tmp_path / "windows"
    tiny.analyze(root, windows)
    path = partition_path(windows, "W2", DAY)
    _changed_window(path)
    again = tiny.analyze(root, windows)
    assert [i.path for i in again.repaired] == [str(path)] and again.analysed == 1


def test_a_folder_in_the_place_of_the_analysis_summary_is_replaced_not_a_failure_of_every_run(tmp_path: Path) -> None:
    # Found by make fuzz (fleet): the rename over it failed, run after run.
    root = tiny.fleet(tmp_path / "fleet")
    windows = tmp_path / "windows"
    tiny.analyze(root, windows)
    (windows / "_analysis.json").unlink()
    (windows / "_analysis.json").mkdir()
    again = tiny.analyze(root, windows)
    assert again.reused == 4 - again.analysed and json.loads((windows / "_analysis.json").read_text())["partitions"] == 4


def test_a_wagon_folder_of_windows_linked_elsewhere_loses_nothing_there(tmp_path: Path) -> None:
    # A run killed while writing leaves temporaries, which the next removes: never through a link.
    root = tiny.fleet(tmp_path / "fleet", wagons=("W1",))
    windows = tmp_path / "windows"
    elsewhere = tmp_path / "elsewhere"
    theirs = elsewhere / f"date={DAY}" / temporary_name(Path(PART_FILE)).name
    theirs.parent.mkdir(parents=True)
    theirs.write_bytes(b"theirs")
    windows.mkdir()
    (windows / "wagon=W1").symlink_to(elsewhere)
    summary = tiny.analyze(root, windows)
    assert theirs.read_bytes() == b"theirs"
    assert summary.analysed == 2 and (windows / "wagon=W1").is_dir() and not (windows / "wagon=W1").is_symlink()


# ---- JUDGED --------------------------------------------------------------------------------------


def _judged(tmp_path: Path) -> Path:
    root = tiny.fleet(tmp_path / "fleet")
    tiny.analyze(root, tmp_path / "windows")
    judge_fleet(tmp_path / "windows", tmp_path / "judged")
    return tmp_path / "judged"


def _link_to_dev_zero(path: Path) -> None:
    path.unlink()
    path.symlink_to("/dev/zero")


JUDGED_DAMAGES: dict[str, tuple[str, Callable[[Path], object], str]] = {
    "wagons.json a FIFO": ("wagons.json", _fifo, "wagons.json: not a regular file"),
    "wagons.json a link to /dev/zero": ("wagons.json", _link_to_dev_zero, "wagons.json: not a regular file"),
    "wagons.json a sparse GiB": ("wagons.json", lambda p: os.truncate(p, (1 << 30) + 1), "wagons.json: larger than 1 GiB"),
    "wagons.json random bytes": ("wagons.json", lambda p: p.write_bytes(b"\xff\xfe" + os.urandom(100)), "wagons.json: cannot be read"),
    "events.jsonl a FIFO": ("events.jsonl", _fifo, "events.jsonl: not a regular file"),
    "events.jsonl a link to /dev/zero": ("events.jsonl", _link_to_dev_zero, "events.jsonl: not a regular file"),
    "events.jsonl one endless line": ("events.jsonl", lambda p: p.write_bytes(b"x" * (2 << 20)), "events.jsonl: line 1: longer than"),
    "a series a FIFO": ("series/wagon=W1/part-0.parquet", _fifo, "part-0.parquet: not a regular file"),
    "a series a folder": ("series/wagon=W1/part-0.parquet", _folder, "part-0.parquet: a folder"),
    "a series random bytes": ("series/wagon=W1/part-0.parquet", lambda p: p.write_bytes(os.urandom(3000)), "not a readable Parquet file"),
}


@pytest.mark.parametrize("damage", list(JUDGED_DAMAGES))
def test_a_damaged_judged_folder_is_one_clear_error_of_report_without_blocking(tmp_path: Path, damage: str) -> None:
    judged = _judged(tmp_path)
    name, spoil, message = JUDGED_DAMAGES[damage]
    spoil(judged / name)
    error = tiny.without_blocking(lambda: write_report(judged, tmp_path / "report"))
    assert isinstance(error, ReportError) and message in str(error), error
    assert "\n" not in str(error) and not (tmp_path / "report").exists()


@pytest.mark.parametrize("name", ["events.jsonl", "wagons.json"])
def test_a_folder_in_the_place_of_a_judged_file_is_replaced_when_judged_again(tmp_path: Path, name: str) -> None:
    judged = _judged(tmp_path)
    (judged / name).unlink()
    (judged / name).mkdir()
    judge_fleet(tmp_path / "windows", judged)
    assert (judged / name).is_file() and write_report(judged, tmp_path / "report").wagons == 2
