"""Small recordings trees for the back office's tests: simulated runs placed on given days and times."""

from __future__ import annotations

import datetime as dt
import shutil
from dataclasses import dataclass
from pathlib import Path

from bogiemon.cli.main import main
from bogiemon.drivers.recording import read_csv_recording, write_csv_recording

REPO = Path(__file__).resolve().parents[2]
DEMO_CALIBRATION = REPO / "config" / "demo_calibration.toml"
# The demo wagon is commissioned at full load (config/demo_calibration.toml); its config fixes the
# load so that a few minutes of running are judged as they are in `make demo`.
WAGON_CONFIG = '[decision]\nload = "full"\n'
FAULT = "type_a:rear_outer:0.0@leading-left"


@dataclass(frozen=True)
class Runs:
    """Simulated runs, relative times (the simulator's own origin)."""

    healthy: tuple[Path, ...]
    faulty: Path  # the spring breaks FAULT_AT_S into the run


FAULT_AT_S = 20.0


def simulate_runs(folder: Path, duration_s: float = 300.0) -> Runs:
    folder.mkdir(parents=True, exist_ok=True)
    healthy = []
    for seed in (1, 2):
        path = folder / f"healthy-{seed}.csv"
        main(["simulate", "-q", "--load", "full", "--duration-s", str(duration_s), "--seed", str(seed), "-o", str(path)])
        healthy.append(path)
    faulty = folder / "faulty.csv"
    main(["simulate", "-q", "--load", "full", "--duration-s", str(duration_s), "--seed", "3", "--fault", FAULT,
          "--fault-at-s", str(FAULT_AT_S), "-o", str(faulty)])  # fmt: skip
    return Runs(tuple(healthy), faulty)


def place(run: Path, wagon_dir: Path, date: str, hhmm: str, suffix: str = ".csv.gz") -> Path:
    """Copy a run into wagon_dir/date/, its times moved to Unix time at that UTC day and time."""
    day = dt.datetime.strptime(f"{date} {hhmm}", "%Y-%m-%d %H:%M").replace(tzinfo=dt.UTC).timestamp()
    recording = read_csv_recording(run)
    out = wagon_dir / date / f"{hhmm.replace(':', '')}00_{run.stem}{suffix}"
    out.parent.mkdir(parents=True, exist_ok=True)
    write_csv_recording(out, recording.time_s - recording.time_s[0] + day, recording.accel_mps2)
    return out


def wagon(root: Path, wagon_id: str, commissioned: bool) -> Path:
    folder = root / wagon_id
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "bogiemon.toml").write_text(WAGON_CONFIG, encoding="utf-8")
    if commissioned:
        shutil.copy(DEMO_CALIBRATION, folder / "calibration.toml")
    return folder
