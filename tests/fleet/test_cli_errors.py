"""`bogiemon fleet` options and output paths a careless operator gives: each one line on stderr and
exit status 2, never a traceback, a hang, or a file outside the outputs touched (a hostile-input
probe's finding 4)."""

from __future__ import annotations

import os
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest

from bogiemon.cli.main import EXIT_USER_ERROR, main
from bogiemon.fleet.judge import judge_fleet
from tests.fleet import tiny


@pytest.fixture(scope="module")
def trees(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """FLEET, WINDOWS and JUDGED of a tiny fleet, made once; the tests only read them."""
    base = tmp_path_factory.mktemp("trees")
    tiny.analyze(tiny.fleet(base / "fleet"), base / "windows")
    judge_fleet(base / "windows", base / "judged")
    return base


def _error(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one error line of a command that must fail as a user error."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code == EXIT_USER_ERROR, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("bogiemon: error: "), err
    return lines[0]


@pytest.mark.parametrize(("option", "message"), [
    (["--workers", "-2"], "--workers -2: expected 1 to"),
    (["--workers", "0"], "--workers 0: expected 1 to"),
    (["--workers", "100000"], "--workers 100000: expected 1 to"),
    (["--scheduler", "not-a-url"], "--scheduler 'not-a-url': expected a Dask scheduler's address"),
    (["--scheduler", "tcp://"], "--scheduler 'tcp://': expected a Dask scheduler's address"),
    (["--scheduler", "tcp://127.0.0.1:8786", "--workers", "2"], "--workers is for the local cluster"),
])  # fmt: skip
def test_an_option_of_analyze_that_cannot_work_is_one_line_before_anything_is_written(
    tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str], option: list[str], message: str
) -> None:
    line = _error(["fleet", "analyze", str(trees / "fleet"), "-o", str(tmp_path / "windows"), "--redo", *option], capsys)
    assert message in line and not (tmp_path / "windows").exists()


@pytest.fixture
def not_a_scheduler() -> Iterator[str]:
    """An address where an HTTP server answers: Dask reads its reply as a 3 EiB frame length."""
    server = socket.create_server(("127.0.0.1", 0))
    stop = threading.Event()

    def serve() -> None:
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                conn, _ = server.accept()
            except TimeoutError:
                continue
            with conn:
                conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 8)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    stop.set()
    thread.join()
    server.close()


def test_a_scheduler_address_where_something_else_answers_is_one_line(
    tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str], not_a_scheduler: str
) -> None:
    line = _error(["fleet", "analyze", str(trees / "fleet"), "-o", str(tmp_path / "windows"), "--scheduler", not_a_scheduler], capsys)
    assert f"{not_a_scheduler} did not answer as a Dask scheduler" in line


def test_windows_that_is_a_file_a_device_or_inside_fleet_is_one_line(tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "a-file"
    a_file.write_text("mine\n")
    fleet = str(trees / "fleet")
    assert "a-file: not a folder; WINDOWS is a folder" in _error(["fleet", "analyze", fleet, "-o", str(a_file)], capsys)
    assert "/dev/null: not a folder; WINDOWS is a folder" in _error(["fleet", "analyze", fleet, "-o", "/dev/null"], capsys)
    inside = _error(["fleet", "analyze", fleet, "-o", str(trees / "fleet" / "windows")], capsys)
    assert "WINDOWS lies inside FLEET" in inside and not (trees / "fleet" / "windows").exists()
    assert "WINDOWS lies inside FLEET" in _error(["fleet", "analyze", fleet, "-o", fleet], capsys)
    assert a_file.read_text() == "mine\n"


def test_judged_that_is_a_file_or_inside_its_inputs_is_one_line(tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a_file = tmp_path / "a-file"
    a_file.write_text("mine\n")
    windows = str(trees / "windows")
    assert "a-file: not a folder; JUDGED is a folder" in _error(["fleet", "judge", windows, "-o", str(a_file)], capsys)
    assert "JUDGED lies inside WINDOWS" in _error(["fleet", "judge", windows, "-o", str(trees / "windows" / "judged")], capsys)
    assert "JUDGED lies inside FLEET" in _error(["fleet", "judge", windows, "-o", str(trees / "fleet" / "judged")], capsys)
    assert "no such windows dataset" in _error(["fleet", "judge", str(tmp_path / "missing"), "-o", str(tmp_path / "j")], capsys)
    assert not (trees / "windows" / "judged").exists() and not (trees / "fleet" / "judged").exists()


def test_a_report_is_never_written_over_a_device_or_into_judged_itself(tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    judged = str(trees / "judged")
    assert "/dev/null: not a folder; the report is a folder" in _error(["fleet", "report", judged, "-o", "/dev/null"], capsys)
    os.mkfifo(tmp_path / "fifo")
    assert "fifo: not a folder" in _error(["fleet", "report", judged, "-o", str(tmp_path / "fifo")], capsys)
    assert "the report lies inside JUDGED" in _error(["fleet", "report", judged, "-o", str(trees / "judged" / "r")], capsys)
    assert "the report is a folder (index.html" in _error(["fleet", "report", judged, "-o", str(tmp_path / "r.html")], capsys)
    assert "no such folder" in _error(["fleet", "report", str(tmp_path / "missing"), "-o", str(tmp_path / "r")], capsys)
    assert "--since 'yesterday': expected a date" in _error(["fleet", "report", judged, "-o", str(tmp_path / "r"), "--since", "yesterday"], capsys)
    assert os.path.exists("/dev/null") and not Path("/dev/null").is_file()


def test_calibrate_with_force_onto_a_folder_is_one_line_and_leaves_it(tmp_path: Path, trees: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tiny.fleet(tmp_path / "fleet")
    tiny.analyze(root, tmp_path / "windows")
    (root / "W1" / "calibration.toml").mkdir()
    line = _error(["fleet", "calibrate", "W1", "--fleet", str(root), "--windows", str(tmp_path / "windows"), "--force"], capsys)
    assert "calibration.toml: a folder" in line and (root / "W1" / "calibration.toml").is_dir()
    windows_file = tmp_path / "a-file"
    windows_file.write_text("")
    assert "no such windows dataset" in _error(["fleet", "calibrate", "W2", "--fleet", str(root), "--windows", str(windows_file)], capsys)


def test_fleet_analyze_that_analysed_nothing_exits_1_saying_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Every wagon skipped (here: a wagon-day of one unreadable recording) is no success a cron job can miss."""
    day = tmp_path / "fleet" / "W1" / "2025-12-03"
    day.mkdir(parents=True)
    (day / "run.csv").write_text("not,a,recording\n")
    assert main(["fleet", "analyze", str(tmp_path / "fleet"), "-o", str(tmp_path / "windows"), "--workers", "1"]) == 1
    err = capsys.readouterr().err
    assert err.splitlines()[-1].startswith("bogiemon: analysed nothing: no wagon-day of ") and "(see the reasons above)" in err
