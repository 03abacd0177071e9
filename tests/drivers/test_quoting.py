"""Text from a file in a message (drivers/quoting.py): escaped, on one line, cut; the recordings',
the CAN database's and the command line's messages quote it so."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bogiemon.drivers.candb import DbcError, load_layout
from bogiemon.drivers.quoting import printable, quoted
from bogiemon.drivers.recording import RecordingError, open_recording_reader, read_recording

HOSTILE = "a\nb\x1b[2J\x07\r\u2028c"  # a newline, a screen clear, a bell, a carriage return, a line separator


def test_quoted_text_is_one_line_of_printable_characters_with_the_controls_written_out() -> None:
    assert quoted(HOSTILE) == "a\\nb\\x1b[2J\\x07\\r\\u2028c"
    assert quoted("plain words, ü and 中") == "plain words, ü and 中"


def test_quoted_bytes_that_are_not_utf8_are_written_as_hex() -> None:
    assert quoted(b"ok\xff\x1b") == "ok\\xff\\x1b"


def test_quoted_text_is_cut_to_its_limit_and_says_so() -> None:
    assert quoted("x" * 100, 10) == "xxxxxxx..." and quoted("x" * 10, 10) == "x" * 10
    assert len(quoted("\x1b" * 100, 20)) == 20


def test_printable_keeps_a_messages_own_line_breaks_and_escapes_the_rest() -> None:
    assert printable("site.toml: 2 problem(s):\n  a\x1b[2J\n  b\tc") == "site.toml: 2 problem(s):\n  a\\x1b[2J\n  b\tc"


def _message(path: Path) -> str:
    with pytest.raises(RecordingError) as raised:
        open_recording_reader(path)
    return str(raised.value)


def test_a_csv_header_with_a_terminal_escape_is_quoted_escaped(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    path.write_bytes(b"time_s,a1\x1b[2J\x1b]0;owned\x07,a2,a3\n0.0,1,2,3\n0.01,1,2,3\n")
    message = _message(path)
    assert "\\x1b[2J\\x1b]0;owned\\x07" in message and message.isprintable()


def test_a_csv_value_with_a_terminal_escape_is_quoted_escaped(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    path.write_bytes(b"time_s,a1,a2,a3\n0.0,1,2,3\n0.01,1\x1b[2J,2,3\n0.02,1,2,3\n")
    with pytest.raises(RecordingError) as raised:
        read_recording(path)  # the bad row is found when the reading reaches it
    assert "\\x1b[2J" in str(raised.value) and str(raised.value).isprintable()


def test_parquet_column_names_with_newlines_are_quoted_on_one_line(tmp_path: Path) -> None:
    path = tmp_path / "run.parquet"
    table = pa.table({"time_s\nINJECTED": [0.0, 0.01], "a1": [1.0, 1.0], "a2\x1b[2J": [2.0, 2.0], "a3": [3.0, 3.0]})
    pq.write_table(table, path)
    message = _message(path)
    assert "time_s\\nINJECTED" in message and "a2\\x1b[2J" in message and message.isprintable()


def test_a_dbc_the_parser_refuses_is_named_with_its_text_escaped(tmp_path: Path) -> None:
    path = tmp_path / "bus.dbc"
    path.write_text('VERSION "x"\n\nBO_ 1 \x1b[2JHub: 8 Vector__XXX\n SG_ A : 0|8@1+ (1,0) [0|1] "" X\x1b]0;t\x07\n')
    with pytest.raises(DbcError) as raised:
        load_layout(path, "hub")
    assert str(raised.value).isprintable()


def test_the_command_line_prints_a_file_s_text_escaped(tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    path.write_bytes(b"time_s,a1\x1b[2J,a2,a3\n0.0,1,2,3\n0.01,1,2,3\n")
    proc = subprocess.run([sys.executable, "-m", "bogiemon.cli.main", "replay", str(path), "--state-dir", str(tmp_path / "state")],
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 2 and "\x1b" not in proc.stderr and "\\x1b[2J" in proc.stderr
