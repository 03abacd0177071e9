"""`bogiemon replay`: recordings through the daemon's own pipeline, CSV and CAN logs alike, with the
config's [source] settings; what a log holds that cannot be used is counted, skipped and said."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import parse_config
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.replay import replay
from bogiemon.daemon.service import Service
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.sources import open_source
from bogiemon.daemon.store import EventStore
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.drivers.candb import load_layout
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import RecordingError, write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config

CONFIG_TEXT = short_windows_config(clear_after_windows=2)
CONFIG = parse_config(CONFIG_TEXT, "test")
BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]


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


def per_node_config(tmp_path: Path, log: Path) -> str:
    """The test config with [source] a replay of log in the per-node layout, its state in tmp_path."""
    return short_windows_config(clear_after_windows=2, state_dir=tmp_path / "state") + (
        f'[source]\nkind = "replay"\npath = "{log}"\nrealtime = false\nlayout = "per-node"\n'
    )


def test_replay_honours_the_per_node_layout_of_source_like_run(tmp_path: Path, faulty_then_healthy) -> None:
    log = tmp_path / "nodes.log"
    write_can_log(log, load_layout(None, "per-node"), faulty_then_healthy, FS_HZ, start_s=1.7e9)
    (tmp_path / "cfg.toml").write_text(per_node_config(tmp_path, log))
    run_sink, run_windows = MemorySink(), list[WindowVerdict]()
    service = Service(tmp_path / "cfg.toml", open_source, sinks=[run_sink], observers=[run_windows.append])
    assert service.run() == 0
    replay_sink = MemorySink()
    summary = replay([log], parse_config(per_node_config(tmp_path, log), "t"), sinks=[replay_sink])
    assert kinds(run_sink.events) == kinds(replay_sink.events) == ["SUSPECTED", "CONFIRMED", "CLEARED"]
    assert [e.time_s for e in replay_sink.events] == [e.time_s for e in run_sink.events]
    assert summary.counters.windows == len(run_windows) > 0


def test_a_log_that_decodes_to_no_samples_is_an_error_naming_the_layout(tmp_path: Path, faulty_then_healthy) -> None:
    log = tmp_path / "nodes.log"
    frames = write_can_log(log, load_layout(None, "per-node"), faulty_then_healthy[:500], FS_HZ, start_s=1.7e9)
    with pytest.raises(RecordingError) as info:
        replay([log], CONFIG)  # the hub layout: every frame is one of the DBC's other messages
    assert str(info.value) == (
        f"{log}: no samples decoded from {frames} frame(s) ({frames} of the DBC's other messages): check that "
        "[source] layout ('hub') and dbc_path ('the shipped DBC') are those of the log"
    )


def test_the_cli_replays_past_an_unparseable_log_line_and_says_so(tmp_path: Path, faulty_then_healthy) -> None:
    log = tmp_path / "run.log"
    write_can_log(log, load_layout(None, "hub"), faulty_then_healthy, FS_HZ, start_s=1.7e9)
    lines = log.read_text().splitlines()
    lines[len(lines) // 2] = "(1700000030.000000) can0 10"  # one torn line in the middle
    log.write_text("\n".join(lines) + "\n")
    (tmp_path / "cfg.toml").write_text(CONFIG_TEXT)
    proc = subprocess.run([*BOGIEMON, "replay", str(log), "--config", str(tmp_path / "cfg.toml")], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary, skipped = proc.stderr.splitlines()
    assert summary.startswith("replayed 1 recording(s): ") and " 0 windows" not in summary
    assert skipped == f"{log}: skipped 1 unreadable log line"


@pytest.mark.parametrize("stamp", ["nan", "inf"])
def test_a_log_with_a_non_finite_first_time_stamp_stores_only_finite_event_times(tmp_path: Path, faulty_then_healthy, stamp: str) -> None:
    log = tmp_path / "run.log"
    write_can_log(log, load_layout(None, "hub"), faulty_then_healthy, FS_HZ, start_s=1.7e9)
    lines = log.read_text().splitlines()
    lines[0] = f"({stamp})" + lines[0][lines[0].index(")") + 1 :]
    log.write_text("\n".join(lines) + "\n")
    summary = replay([log], CONFIG, state_dir=tmp_path / "state")
    stored = EventStore(tmp_path / "state", readonly=True).events()
    assert kinds(stored) == ["SUSPECTED", "CONFIRMED", "CLEARED"]
    assert all(1.7e9 <= e.time_s < 1.7e9 + 60 for e in stored)
    assert summary.reports[0].skipped_text() == f"{log}: skipped 1 frame with an unusable time stamp"


@pytest.mark.parametrize(
    ("fs_hz", "message"),
    [
        (10.0, r"recorded at 10 Hz, a rate the config's \[processing\] cannot run at: .*lowpass_hz"),
        # Times with 6 decimals: the file's own rate is 333.329 Hz.
        (333.33, r"recorded at 333.329 Hz, a rate the config's \[processing\] cannot run at: .*whole number of hops"),
        (0.01, r"recorded at 0.01 Hz, a rate the config's \[processing\] cannot run at: .*fs_hz 0.01 Hz is outside the sample rates"),
    ],
)
def test_the_cli_refuses_a_csv_at_a_rate_the_config_cannot_run_in_one_line(tmp_path: Path, fs_hz: float, message: str) -> None:
    path = tmp_path / "run.csv"
    write_csv_recording(path, 1.7e9 + np.arange(50) / fs_hz, bogie_accel(0.5, 1))
    proc = subprocess.run([*BOGIEMON, "replay", str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert re.match(f"bogiemon: error: {re.escape(str(path))}: {message}", proc.stderr) and proc.stderr.count("\n") == 1
    assert "Traceback" not in proc.stderr
