"""Files written whole or not at all (drivers/atomic.py)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from bogiemon.drivers.atomic import final_name_of, temporary_name, write_atomically, write_text_atomically


def test_a_file_is_written_whole_over_the_old_one_and_no_temporary_is_left(tmp_path: Path) -> None:
    target = tmp_path / "wagons.json"
    target.write_text("old")
    write_text_atomically(target, "new ü")
    assert target.read_text(encoding="utf-8") == "new ü" and os.listdir(tmp_path) == ["wagons.json"]


def test_a_writer_that_fails_leaves_the_old_file_and_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "report.html"
    target.write_text("old")

    def half(temporary: Path) -> None:
        temporary.write_text("half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomically(target, half)
    assert target.read_text() == "old" and os.listdir(tmp_path) == ["report.html"]


def test_the_temporary_is_hidden_beside_the_file_and_ends_as_its_name_does(tmp_path: Path) -> None:
    # A writer that takes the format from the suffix (.csv.gz: gzip) writes the same bytes there.
    final = tmp_path / "20261203T101500Z_confirmed.csv.gz"
    temporary = temporary_name(final)
    assert temporary.parent == tmp_path and temporary.name.startswith(".") and temporary.name.endswith(".csv.gz")
    assert temporary_name(final) != temporary  # two writers never share one
    assert final_name_of(temporary.name) == final.name
    assert final_name_of(final.name) is None and final_name_of(".csv.gz") is None and final_name_of(".1234567.x") is None
