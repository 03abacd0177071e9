"""The gateway's install (pyproject.toml's base dependencies, no extra): its commands run without
what the extras bring, and a command that needs an extra says which, in one line."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np

from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, bogie_accel, short_windows_config

# What the extras bring (cli/main.py EXTRA_OF_PACKAGE): hidden, `import` of them fails as on a
# gateway installed from its bundle.
EXTRAS = ("pyarrow", "scipy", "numba", "matplotlib", "dask", "distributed")
HIDE = f"import sys\nfor name in {EXTRAS!r}:\n    sys.modules[name] = None\n"


def bogiemon_without_extras(*args: str) -> subprocess.CompletedProcess[str]:
    code = HIDE + f"from bogiemon.cli.main import main\nsys.exit(main({list(args)!r}))\n"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)


def test_the_gateways_commands_run_without_the_extras(tmp_path: Path) -> None:
    config = tmp_path / "bogiemon.toml"
    config.write_text(short_windows_config(state_dir=tmp_path / "state"), encoding="utf-8")
    recording = tmp_path / "run.csv.gz"
    accel = bogie_accel(80, seed=3)
    write_csv_recording(recording, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)

    checked = bogiemon_without_extras("check-config", str(config))
    assert checked.returncode == 0, checked.stderr
    replayed = bogiemon_without_extras("replay", str(recording), "--config", str(config), "--state-dir", str(tmp_path / "state"))
    assert replayed.returncode == 0, replayed.stderr
    assert "replayed 1 recording(s): 38 windows" in replayed.stderr
    listed = bogiemon_without_extras("events", "--config", str(config))
    assert listed.returncode == 0, listed.stderr
    calibrated = bogiemon_without_extras("calibrate", str(recording), "--load", "full", "--config", str(config), "-o", str(tmp_path / "cal.toml"))
    assert calibrated.returncode == 0, calibrated.stderr
    assert "[decision.thresholds.full" in (tmp_path / "cal.toml").read_text()
    played = bogiemon_without_extras("play", str(recording), "--interface", "virtual", "--channel", f"gw-{tmp_path.name}", "--rate", "0")
    assert played.returncode == 0, played.stderr


def test_a_command_needing_an_extra_says_which_to_install_in_one_line(tmp_path: Path) -> None:
    done = bogiemon_without_extras("simulate", "--duration-s", "10", "-o", str(tmp_path / "sim.csv"))
    assert done.returncode == 2
    assert done.stderr.splitlines() == ["bogiemon: error: this command needs scipy, which this install leaves out: pip install 'bogiemon[sim]'"]
