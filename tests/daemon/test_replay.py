"""`bogiemon replay`: recordings through the daemon's own pipeline, CSV and CAN logs alike."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import parse_config
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.replay import replay
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.candb import load_layout
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config

CONFIG_TEXT = short_windows_config(clear_after_windows=2)
CONFIG = parse_config(CONFIG_TEXT, "test")
BOGIEMON = [sys.executable, "-m", "bogiemon.daemon.cli.main"]


@pytest.fixture
def faulty_then_healthy() -> np.ndarray:
    return np.concatenate([bogie_accel(20, 3, pitch_roll_coupling=1.0), bogie_accel(40, 4)])


def kinds(events) -> list[str]:
    return [e.kind.value for e in events]


def test_replay_gives_what_the_monitor_gives_fed_directly(tmp_path: Path, faulty_then_healthy) -> None:
    path = tmp_path / "run.csv"
    t = 1.7e9 + np.arange(faulty_then_healthy.shape[0]) / FS_HZ
    write_csv_recording(path, t, faulty_then_healthy)
    sink = MemorySink()
    summary = replay([path], CONFIG, sinks=[sink])
    direct = Monitor(CONFIG.monitor_settings(), EventStore(tmp_path / "direct"))
    direct_events = []
    for block in as_blocks(np.round(faulty_then_healthy, 6), start_s=1.7e9):
        direct_events += direct.feed(block)
    assert kinds(sink.events) == kinds(direct_events) == ["SUSPECTED", "CONFIRMED", "CLEARED"]
    assert [e.time_s for e in sink.events] == pytest.approx([e.time_s for e in direct_events])
    assert summary.counters.windows == direct.counters.windows and summary.final_mode == "normal"


def test_a_can_log_replays_to_the_same_events_as_its_csv(tmp_path: Path, faulty_then_healthy) -> None:
    t = 1.7e9 + np.arange(faulty_then_healthy.shape[0]) / FS_HZ
    write_csv_recording(tmp_path / "run.csv", t, faulty_then_healthy)
    write_can_log(tmp_path / "run.log", load_layout(None, "hub"), faulty_then_healthy, FS_HZ, start_s=1.7e9)
    from_csv, from_log = MemorySink(), MemorySink()
    replay([tmp_path / "run.csv"], CONFIG, sinks=[from_csv])
    replay([tmp_path / "run.log"], CONFIG, sinks=[from_log])
    assert kinds(from_log.events) == kinds(from_csv.events) == ["SUSPECTED", "CONFIRMED", "CLEARED"]


def test_alarm_state_carries_from_one_recording_to_the_next(tmp_path: Path) -> None:
    paths = []
    for i, coupling in enumerate([1.0, 0.0]):
        path = tmp_path / f"part{i}.csv"
        write_csv_recording(path, 1.7e9 + i * 100 + np.arange(1200) / FS_HZ, bogie_accel(12, 10 + i, pitch_roll_coupling=coupling))
        paths.append(path)
    sink = MemorySink()
    summary = replay(paths, CONFIG, sinks=[sink])
    assert kinds(sink.events) == ["SUSPECTED", "CONFIRMED", "CLEARED"]
    assert summary.counters.segments == 2


def test_the_cli_prints_json_events_and_a_summary(tmp_path: Path, faulty_then_healthy) -> None:
    write_csv_recording(tmp_path / "run.csv", 1.7e9 + np.arange(faulty_then_healthy.shape[0]) / FS_HZ, faulty_then_healthy)
    (tmp_path / "cfg.toml").write_text(CONFIG_TEXT)
    proc = subprocess.run(
        [*BOGIEMON, "replay", str(tmp_path / "run.csv"), "--config", str(tmp_path / "cfg.toml"), "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    events = [json.loads(line) for line in proc.stdout.splitlines()]
    assert [e["kind"] for e in events] == ["SUSPECTED", "CONFIRMED", "CLEARED"]
    assert "final mode normal" in proc.stderr


def test_the_cli_names_a_missing_recording(tmp_path: Path) -> None:
    proc = subprocess.run([*BOGIEMON, "replay", str(tmp_path / "nope.csv")], capture_output=True, text=True)
    assert proc.returncode == 2 and "nope.csv" in proc.stderr and "Traceback" not in proc.stderr
