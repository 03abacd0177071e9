"""The commands that read one bogie today refuse a wagon's recording (time_s,a1,a2,a3,b1,b2,b3) in one
line naming the file and the command, exit 2, rather than misread its columns: analyze, calibrate,
replay, play, run (and its recorder; check-config as run) and fleet analyze. Real files; run as a
real process."""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bogiemon.cli.main import main
from bogiemon.drivers.recording import write_recording
from tests.fleet import tree

FS_HZ = 500.0


def refusal(path: Path, command: str) -> str:
    return f"{path}: a wagon's recording (both bogies): {command} reads one bogie today; give it one bogie's recording (time_s,a1,a2,a3)"


def write_wagon(path: Path, start_s: float = 0.0, n: int = 2000) -> Path:
    rng = np.random.default_rng(0)
    write_recording(path, start_s + np.arange(n) / FS_HZ, rng.normal(9.81, 1.0, size=(n, 6)))
    return path


@pytest.fixture(params=["wagon.csv.gz", "wagon.parquet"])
def wagon(request: pytest.FixtureRequest, tmp_path: Path) -> Path:
    return write_wagon(tmp_path / request.param)


def test_analyze_refuses_a_wagons_recording_in_one_line_with_status_2(wagon: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "bogiemon", "analyze", str(wagon)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert proc.stderr == f"bogiemon: error: {refusal(wagon, 'analyze')}\n"
    assert proc.stdout == ""


@pytest.mark.parametrize(
    ("argv", "command"),
    [
        (["calibrate", "{wagon}", "--load", "full", "-o", "{out}"], "calibrate"),
        (["calibrate", "--full", "{wagon}", "-o", "{out}"], "calibrate"),
        (["replay", "{wagon}"], "replay"),
        (["play", "{wagon}", "--interface", "virtual", "--channel", "wagon-refusal", "--rate", "0"], "play"),
    ],
    ids=["calibrate-load", "calibrate-full", "replay", "play"],
)
def test_a_command_that_reads_one_bogie_refuses_a_wagons_recording(
    wagon: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], command: str
) -> None:
    out = tmp_path / "calibration.toml"
    assert main([a.format(wagon=wagon, out=out) for a in argv]) == 2
    captured = capsys.readouterr()
    assert captured.err == f"bogiemon: error: {refusal(wagon, command)}\n"
    assert captured.out == ""
    assert not out.exists()


def test_run_refuses_a_wagons_recording_and_its_recorder_writes_nothing(wagon: Path, tmp_path: Path) -> None:
    recordings = tmp_path / "recordings"
    config = tmp_path / "bogiemon.toml"
    config.write_text(
        f'[source]\nkind = "replay"\npath = "{wagon}"\nrealtime = false\n'
        f'[recorder]\nenabled = true\ndirectory = "{recordings}"\nperiodic_every_h = 0.001\nperiodic_s = 1.0\n'
    )
    proc = subprocess.run(
        [sys.executable, "-m", "bogiemon", "run", "--config", str(config), "--state-dir", str(tmp_path / "state")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.splitlines()[-1] == f"bogiemon: error: {refusal(wagon, 'run')}"
    assert "Traceback" not in proc.stderr
    assert not recordings.exists() or not any(recordings.iterdir())


def test_fleet_analyze_names_a_wagons_recording_as_skipped_and_analyses_the_rest(tmp_path: Path) -> None:
    from bogiemon.fleet.analyze import analyze_day, day_tasks
    from bogiemon.fleet.layout import scan_fleet

    folder = tree.wagon(tmp_path / "fleet", "W1", commissioned=False)
    midnight_s = dt.datetime(2026, 11, 2, tzinfo=dt.UTC).timestamp()
    (folder / "2026-11-02").mkdir()
    wagon = write_wagon(folder / "2026-11-02" / "060000_wagon.csv.gz", start_s=midnight_s + 6 * 3600.0)
    (task,) = day_tasks(scan_fleet(tmp_path / "fleet"), tmp_path / "windows")
    result = analyze_day(task)
    assert [(i.path, i.reason) for i in result.skipped] == [
        (str(wagon), "does not parse: a wagon's recording (both bogies): fleet analyze reads one bogie today; "
                     "give it one bogie's recording (time_s,a1,a2,a3)"),
    ]  # fmt: skip
    assert result.windows == 0


def test_check_config_refuses_a_replay_source_of_a_wagons_recording_as_run_would(
    wagon: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config = tmp_path / "bogiemon.toml"
    config.write_text(f'[source]\nkind = "replay"\npath = "{wagon}"\n')
    assert main(["check-config", str(config)]) == 2
    assert capsys.readouterr().err == f"bogiemon: error: {refusal(wagon, 'run')}\n"
