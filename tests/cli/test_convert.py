"""`bogiemon convert`: a recording to a candump -L log and back, bit for bit at the codec's
resolution; through Parquet and .csv.gz the same; a gap kept; wrong outputs refused in one line."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from bogiemon.cli.main import main
from bogiemon.drivers.recording import write_csv_recording
from tests.drivers.frames import coded_accel

START_S = 1764500000.0


def on_the_codec_grid(path: Path, n: int = 3000) -> None:
    write_csv_recording(path, START_S + np.arange(n) / 500.0, coded_accel(np.arange(n)))


def test_csv_to_candump_log_and_back_is_the_same_file_bit_for_bit(tmp_path: Path) -> None:
    on_the_codec_grid(tmp_path / "in.csv")
    assert main(["convert", str(tmp_path / "in.csv"), "-o", str(tmp_path / "run.log")]) == 0
    assert (tmp_path / "run.log").read_text().splitlines()[0] == "(1764500000.000000) can0 100#000000000000F0D8"
    assert main(["convert", str(tmp_path / "run.log"), "-o", str(tmp_path / "back.csv")]) == 0
    assert (tmp_path / "back.csv").read_bytes() == (tmp_path / "in.csv").read_bytes()


def test_through_parquet_and_csv_gz_the_samples_are_the_same(tmp_path: Path) -> None:
    on_the_codec_grid(tmp_path / "in.csv")
    assert main(["convert", str(tmp_path / "in.csv"), "-o", str(tmp_path / "x.parquet")]) == 0
    assert main(["convert", str(tmp_path / "x.parquet"), "-o", str(tmp_path / "y.csv.gz")]) == 0
    assert gzip.decompress((tmp_path / "y.csv.gz").read_bytes()) == (tmp_path / "in.csv").read_bytes()


def test_a_gap_in_a_candump_log_stays_a_gap(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    on_the_codec_grid(tmp_path / "in.csv")
    assert main(["convert", str(tmp_path / "in.csv"), "-o", str(tmp_path / "run.log")]) == 0
    lines = (tmp_path / "run.log").read_text().splitlines()
    (tmp_path / "gap.log").write_text("\n".join(lines[:1000] + lines[2000:]) + "\n")  # 2 s of frames lost
    assert main(["convert", str(tmp_path / "gap.log"), "-o", str(tmp_path / "gap.csv")]) == 0
    assert capsys.readouterr().err.splitlines()[-1].endswith("2000 samples at 500 Hz from " + str(tmp_path / "gap.log") + ", 1 gap(s) kept")


def test_an_output_of_no_known_kind_is_one_line_before_anything_is_read(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    on_the_codec_grid(tmp_path / "in.csv", 10)
    assert main(["convert", str(tmp_path / "in.csv"), "-o", str(tmp_path / "out.mp3")]) == 2
    assert capsys.readouterr().err == (
        f"bogiemon: error: {tmp_path / 'out.mp3'}: convert writes a recording (.csv, .csv.gz, .parquet) or a candump -L log (.log): name the output so\n"
    )
    assert not list(tmp_path.glob("*out*"))
