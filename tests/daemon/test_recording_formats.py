"""Recordings through the daemon's own commands: CSV and Parquet give the same windows bit for bit, a bad
row found late stops a replay after the windows before it were judged, an absurd burst is clipped to
the converter's range at the source and faults only the windows holding it, and the gateway's daemon
never loads pyarrow. A simulated broken spring, the demo's commissioned wagon; real files and processes."""

from __future__ import annotations

import json
import subprocess
import sys
import warnings
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.analysis import analyze_recording, indicators_as_dict, open_recording
from bogiemon.daemon.config import BogiemonConfig, load_config
from bogiemon.judgement.events import EventKind
from bogiemon.judgement.health import SensorProblem
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.daemon.replay import replay
from bogiemon.daemon.sinks import MemorySink
from bogiemon.drivers.recording import RecordingError, read_recording, write_csv_recording, write_parquet_recording

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
CALIBRATION = Path(str(resources.files("bogiemon.config").joinpath("demo_calibration.toml")))
SPRING_BREAKS_S, RUN_S = 240.0, 330.0
BURST_AT_S, BURST_N = 60.0, 10  # 20 ms of 1e308 in a2 at 500 Hz, long before the spring breaks


@pytest.fixture(scope="module")
def spring(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A CSV of the demo's wagon (full load, 80 km/h) whose rear outer coil at the leading-left corner breaks at 240 s."""
    from bogiemon.simulator import Scenario, parse_fault, simulate

    fault = parse_fault("type_a:rear_outer:0.0@leading-left")
    run = simulate(Scenario(load="full", duration_s=RUN_S, seed=1, faults=(fault,), fault_onset_s=SPRING_BREAKS_S))
    path = tmp_path_factory.mktemp("spring") / "spring.csv"
    write_csv_recording(path, np.arange(run.accel_mps2.shape[0]) / run.scenario.fs_hz, run.accel_mps2)
    return path


@pytest.fixture(scope="module")
def config_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("config") / "bogiemon.toml"
    path.write_text(f'allow_absolute_includes = true\ninclude = ["{CALIBRATION}"]\n[decision]\nload = "full"\n')
    return path


@pytest.fixture(scope="module")
def config(config_path: Path) -> BogiemonConfig:
    return load_config(config_path)


def replayed(path: Path, config: BogiemonConfig) -> tuple[list[WindowVerdict], MemorySink]:
    reports: list[WindowVerdict] = []
    sink = MemorySink()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow or an invalid value in the core fails the replay
        replay([path], config, sinks=[sink], observers=[reports.append])
    return reports, sink


def event_times(sink: MemorySink, kind: EventKind) -> list[float]:
    return [e.time_s for e in sink.events if e.kind is kind]


@pytest.mark.slow  # the simulator (its kernel compiles on a machine's first run) and three replays of 330 s
def test_a_burst_of_absurd_samples_is_clipped_and_faults_only_the_windows_holding_it(spring: Path, config: BogiemonConfig, tmp_path: Path) -> None:
    rec = read_recording(spring)
    accel = rec.accel_mps2.copy()
    first = int(BURST_AT_S * rec.fs_hz)
    accel[first : first + BURST_N, 1] = 1e308
    burst = tmp_path / "burst.csv"
    write_csv_recording(burst, rec.time_s, accel)

    clean_reports, clean = replayed(spring, config)
    reports, sink = replayed(burst, config)

    # The spring confirms when it does without the burst, with the same SUSPECTED before it.
    assert event_times(clean, EventKind.CONFIRMED) != []
    for kind in (EventKind.SUSPECTED, EventKind.CONFIRMED):
        assert event_times(sink, kind) == event_times(clean, kind)
    # CLIPPING, and nothing else, in exactly the windows holding the burst; those and the clean
    # windows the sensor tracker waits for before it clears are not judged; every other one is.
    burst_s = (rec.time_s[first], rec.time_s[first + BURST_N - 1])
    holding = [i for i, r in enumerate(reports) if r.window.start_s <= burst_s[0] and burst_s[1] < r.window.end_s]
    assert len(holding) == 7  # 120 s windows every 10 s, the first starting at 0
    assert {i: r.health.problems for i, r in enumerate(reports) if r.health.problems} == dict.fromkeys(holding, {"a2": (SensorProblem.CLIPPING,)})
    held = list(range(holding[0], holding[-1] + config.health.clear_after_windows))
    assert [i for i, r in enumerate(reports) if r.judgement is None] == held
    (cleared,) = [i for i, r in enumerate(reports) if any(e.kind is EventKind.SENSOR_CLEARED for e in r.events)]
    assert cleared == held[-1] + 1
    assert [i for i, r in enumerate(clean_reports) if r.judgement is None] == []


@pytest.mark.slow
def test_the_cli_says_how_many_samples_it_clipped_and_prints_no_warning(spring: Path, config_path: Path, tmp_path: Path) -> None:
    rec = read_recording(spring)
    accel = rec.accel_mps2.copy()
    accel[30_000:30_010, 1] = 1e308
    burst = tmp_path / "burst.csv"
    write_csv_recording(burst, rec.time_s, accel)
    proc = subprocess.run([*BOGIEMON, "replay", str(burst), "--config", str(config_path)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines()[1:] == [
        f"{burst}: clipped 10 samples beyond the converter's range to its full scale (-156.9064 .. +156.9016 m/s^2)"
    ]


@pytest.mark.slow
def test_csv_and_parquet_of_the_same_samples_give_the_same_windows_bit_for_bit(spring: Path, config: BogiemonConfig, tmp_path: Path) -> None:
    rec = read_recording(spring)  # the samples a CSV holds (6 decimals): written both ways
    write_parquet_recording(tmp_path / "spring.parquet", rec.time_s, rec.accel_mps2)
    windows = {
        name: [json.dumps(indicators_as_dict(w)) for w in analyze_recording(open_recording(path, config), config)]
        for name, path in (("csv", spring), ("parquet", tmp_path / "spring.parquet"))
    }
    assert len(windows["csv"]) == 22
    assert windows["parquet"] == windows["csv"]
    # So do the commands, as a user runs them.
    out = {
        path.suffix: subprocess.run([*BOGIEMON, "analyze", "--json", str(path)], capture_output=True, text=True, timeout=600, check=True).stdout
        for path in (spring, tmp_path / "spring.parquet")
    }
    strip = [{k: v for k, v in json.loads(line).items() if k != "file"} for line in out[".csv"].splitlines()]
    assert strip == [{k: v for k, v in json.loads(line).items() if k != "file"} for line in out[".parquet"].splitlines()]


@pytest.mark.slow
def test_a_bad_row_found_late_stops_the_replay_after_the_windows_before_it_were_judged(
    spring: Path, config: BogiemonConfig, config_path: Path, tmp_path: Path
) -> None:
    lines = spring.read_text().splitlines()
    bad_line = 2 + int(300.0 * 500)  # 300 s in: after the spring's CONFIRMED at 280 s
    lines[bad_line - 1] = lines[bad_line - 1].replace(",", ",x", 1)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")

    reports: list[WindowVerdict] = []
    sink = MemorySink()
    with pytest.raises(RecordingError, match=rf"bad.csv: line {bad_line}: a1 is not a number: 'x"):
        replay([bad], config, sinks=[sink], observers=[reports.append])
    # Every window that ends before the bad row was judged, and its events committed.
    assert [r.window.end_s for r in reports] == [120.0 + 10.0 * i for i in range(19)]  # the last ends at 300 s
    assert [e.kind for e in sink.events] == [EventKind.SUSPECTED, EventKind.CONFIRMED]

    state = tmp_path / "state"
    proc = subprocess.run([*BOGIEMON, "replay", str(bad), "--config", str(config_path), "--state-dir", str(state)], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 2
    assert proc.stderr.splitlines()[-1] == f"bogiemon: error: {bad}: line {bad_line}: a1 is not a number: '{lines[bad_line - 1].split(',')[1]}'"
    assert [line.split()[1] for line in proc.stdout.splitlines() if line.startswith("1970")] == ["SUSPECTED", "CONFIRMED"]
    stored = subprocess.run([*BOGIEMON, "events", "--state-dir", str(state), "--json"], capture_output=True, text=True, timeout=600, check=True)
    assert [json.loads(line)["kind"] for line in stored.stdout.splitlines()] == ["SUSPECTED", "CONFIRMED"]


def test_the_gateways_daemon_never_imports_pyarrow(tmp_path: Path) -> None:
    # `bogiemon run` on CAN, its recorder writing a .csv.gz snapshot: pyarrow is for reading recordings.
    # As on a gateway, which carries no asammdf (the mf4 extra): python-can imports it, and with it
    # pandas and pyarrow, wherever it is installed (can/io/mf4.py), as it is in the test venv.
    code = (
        "import json, sys\n"
        "sys.modules['asammdf'] = None\n"
        "import numpy as np\n"
        "import bogiemon.cli.run\n"
        "from bogiemon.daemon.config import load_config\n"
        "from bogiemon.daemon.service import Service\n"
        "from bogiemon.daemon.recorder import Recorder\n"
        "from bogiemon.daemon.sources import open_source\n"
        "from bogiemon.drivers.recording import write_csv_recording\n"
        "config = load_config(None)\n"
        "config.monitor_settings()\n"
        "open_source(config).close()\n"
        f"write_csv_recording({str(tmp_path / 'snapshot.csv.gz')!r}, np.arange(10) / 500.0, np.zeros((10, 3)), fsync=True)\n"
        "print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] == 'pyarrow')))\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.splitlines()[-1]) == []
    assert (tmp_path / "snapshot.csv.gz").stat().st_size > 0
