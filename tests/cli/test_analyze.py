"""`bogiemon analyze` and `bogiemon check-config` as a user runs them: real processes, real files."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bogiemon.cli.main import main
from bogiemon.drivers.recording import write_csv_recording

# Short windows: the fused method's model needs 120 s ones, so these windows go with thresholds
# (a config `run` could not start is refused by every command since issue 17).
FAST_CONFIG = '[processing]\nfs_hz = 100.0\nwindow_s = 6.0\nhop_s = 2.0\nmax_lag_s = 1.5\n[decision]\nmethod = "thresholds"\n'
BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    n = 1400  # 14 s at 100 Hz: windows at 0, 2, 4, 6, 8 s
    path = tmp_path / "run.csv"
    write_csv_recording(path, 50.0 + np.arange(n) / 100.0, rng.standard_normal((n, 3)) + 9.81)
    return path


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "fast.toml"
    path.write_text(FAST_CONFIG)
    return path


def test_analyze_prints_a_line_per_window(recording: Path, config: Path, capsys) -> None:
    assert main(["analyze", str(recording), "--config", str(config)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith(f"# {recording}: 1400 samples at 100 Hz (14.0 s)")
    assert lines[1].split() == ["start_s", "end_s", "I1", "I2", "I3", "I4", "I1n", "I2n", "I3n", "I4n"]
    rows = [line.split() for line in lines[2:]]
    assert [float(r[0]) for r in rows] == [50.0, 52.0, 54.0, 56.0, 58.0]
    assert all(len(r) == 10 for r in rows)


def test_analyze_json_has_every_field_and_the_file(recording: Path, config: Path, capsys) -> None:
    assert main(["analyze", str(recording), str(recording), "--config", str(config), "--json"]) == 0
    records = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert len(records) == 10
    assert set(records[0]) == {
        "file", "start_s", "end_s", "i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm",
        "rms_mps2", "rms_bounce_mps2", "rms_pitch_radps2", "rms_roll_radps2", "channels", "spectra",
    }  # fmt: skip
    assert set(records[0]["channels"]) == {"mean_mps2", "peak_abs_mps2", "repeat_fraction", "longest_run_s", "clipped_fraction", "hop_rms_min_mps2", "hop_rms_max_mps2"}
    assert records[0]["file"] == str(recording)
    assert records[0] == {**records[5], "file": str(recording)}


@pytest.mark.parametrize(
    ("content", "message"),
    [
        ("time,a1\n", "line 1: expected the header"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.01,1,2,3\n", "is shorter than one analysis window"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.01,a,2,3\n", "line 3: a1 is not a number"),
    ],
)
def test_analyze_reports_a_bad_file_in_one_line_with_status_2(tmp_path: Path, config: Path, content, message) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_text(content)
    proc = subprocess.run([*BOGIEMON, "analyze", str(bad), "--config", str(config)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"bogiemon: error: {bad}: ")
    assert message in proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1


def test_analyze_with_a_bad_config_exits_2_naming_the_field(tmp_path: Path, recording: Path) -> None:
    cfg = tmp_path / "typo.toml"
    cfg.write_text("[processing]\nhop = 5\n")
    proc = subprocess.run([*BOGIEMON, "analyze", str(recording), "--config", str(cfg)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert "processing.hop: unknown field (did you mean 'hop_s'?)" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_check_config_prints_the_resolved_config(config: Path) -> None:
    proc = subprocess.run([*BOGIEMON, "check-config", str(config)], capture_output=True, text=True)
    assert proc.returncode == 0
    assert proc.stdout.startswith(f"# {config}: valid (digest ")
    assert "fs_hz = 100.0" in proc.stdout and 'a1 = "leading-left"' in proc.stdout


def test_the_console_script_is_installed() -> None:
    script = Path(sys.executable).with_name("bogiemon")
    proc = subprocess.run([str(script), "check-config"], capture_output=True, text=True)
    assert proc.returncode == 0 and "valid" in proc.stdout


def rows_at(fs_hz: float, n: int = 50) -> bytes:
    return ("time_s,a1,a2,a3\n" + "".join(f"{i / fs_hz!r},0.1,0.2,9.81\n" for i in range(n))).encode()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,\xc3", r"line 4: not UTF-8 text, byte 0xc3 at column 11 \(cut in the middle"),
        (rows_at(10.0), r"recorded at 10 Hz, a rate the config's \[processing\] cannot run at: .*lowpass_hz \(10 Hz\) must lie between 0 and Nyquist"),
        (rows_at(333.33), r"recorded at 333.33 Hz, a rate the config's \[processing\] cannot run at: .*whole number of hops"),
        (rows_at(0.01), r"recorded at 0.01 Hz, a rate the config's \[processing\] cannot run at: .*fs_hz 0.01 Hz is outside the sample rates the core handles"),
        (
            b"time_s,a1,a2,a3\n" + b"".join(f"{i * 4.9e-324!r},1,2,3\n".encode() for i in range(10)),
            r"time steps of 4.94066e-324 s give no finite sample rate",
        ),
    ],
    ids=["truncated-utf8", "10-hz", "333.33-hz", "0.01-hz", "step-4.9e-324"],
)
def test_analyze_reports_a_recording_the_config_cannot_use_in_one_line_with_status_2(tmp_path: Path, content: bytes, message: str) -> None:
    bad = tmp_path / "bad.csv"
    bad.write_bytes(content)
    proc = subprocess.run([*BOGIEMON, "analyze", str(bad)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert re.match(f"bogiemon: error: {re.escape(str(bad))}: {message}", proc.stderr), proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr.count("\n") == 1


# What an analysis does not need: scipy (the core transforms with numpy.fft), pandas (pyarrow's
# to_numpy imports it for nothing), numpy.ma (np.median's), structlog and asyncio (the daemon's log).
NOT_FOR_ANALYSIS = ("scipy", "pandas", "numpy.ma", "structlog", "asyncio")


@pytest.mark.parametrize("suffix", [".csv.gz", ".parquet"])
def test_analyze_loads_neither_scipy_nor_pandas_nor_the_daemons_logging(tmp_path: Path, config: Path, suffix: str) -> None:
    from bogiemon.drivers.recording import write_recording

    rng = np.random.default_rng(0)
    path = tmp_path / f"run{suffix}"
    write_recording(path, np.arange(1400) / 100.0, rng.standard_normal((1400, 3)) + 9.81)
    # Without the mf4 extra: python-can imports asammdf (and pandas) wherever it is installed.
    code = (
        "import contextlib, io, json, sys\nsys.modules['asammdf'] = None\nfrom bogiemon.cli.main import main\n"
        f"with contextlib.redirect_stdout(io.StringIO()):\n    assert main(['analyze', {str(path)!r}, '--config', {str(config)!r}]) == 0\n"
        "print(json.dumps(sorted(sys.modules)))"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    modules = json.loads(proc.stdout.splitlines()[-1])
    assert "bogiemon.detection.indicators" in modules and "pyarrow" in modules
    assert [m for m in modules if any(m == bad or m.startswith(bad + ".") for bad in NOT_FOR_ANALYSIS)] == []
