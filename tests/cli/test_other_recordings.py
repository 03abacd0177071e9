"""Recordings as keepers' engineers have them, through `replay` and `analyze`: a wrong unit refused
in their words, --unit and --columns, jittered times resampled and said, a gap called a gap."""

from pathlib import Path

import numpy as np
import pytest

from bogiemon.cli.main import main
from bogiemon.drivers.columns import STANDARD_GRAVITY_MPS2
from bogiemon.drivers.recording import write_csv_recording

# Short windows (the fused method's model needs 120 s ones, so these go with thresholds).
FAST_CONFIG = '[processing]\nfs_hz = 100.0\nwindow_s = 6.0\nhop_s = 2.0\nmax_lag_s = 1.5\n[decision]\nmethod = "thresholds"\n'
FS_HZ = 100.0


@pytest.fixture
def config(tmp_path: Path) -> Path:
    path = tmp_path / "fast.toml"
    path.write_text(FAST_CONFIG)
    return path


def bogie_g(n: int) -> np.ndarray:
    """(n, 3) vertical accelerations in g: 1 g and some running."""
    return 1.0 + 0.1 * np.random.default_rng(0).standard_normal((n, 3))


def test_replay_of_a_recording_in_g_is_refused_naming_g_and_judged_with_unit_g(tmp_path: Path, config: Path, capsys) -> None:
    path = tmp_path / "ing.csv"
    write_csv_recording(path, np.arange(1400) / FS_HZ, bogie_g(1400))
    assert main(["replay", str(path), "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"bogiemon: error: {path}: these values look like g (1 g: static levels ")
    assert "set the unit: --unit g" in err[0]
    assert main(["replay", str(path), "--config", str(config), "--unit", "g"]) == 0
    summary = capsys.readouterr().err
    assert "replayed 1 recording(s): 5 windows, " in summary


def test_analyze_reads_another_loggers_columns_mapped_with_columns(tmp_path: Path, config: Path, capsys) -> None:
    t_ms = np.arange(1400) * (1000.0 / FS_HZ)
    a = bogie_g(1400) * STANDARD_GRAVITY_MPS2
    lines = ["speed_kmh;time_ms;acc_fl;acc_fr;acc_rl"] + [f"80;{t:.1f};{x:.6f};{y:.6f};{z:.6f}" for t, (x, y, z) in zip(t_ms, a, strict=True)]
    path = tmp_path / "logger.csv"
    path.write_text("\n".join(lines) + "\n")
    assert main(["analyze", str(path), "--config", str(config)]) == 2
    assert "no column 'a1', no column 'a2', no column 'a3'" in capsys.readouterr().err
    assert main(["analyze", str(path), "--config", str(config), "--columns", "a1=acc_fl,a2=acc_fr,a3=acc_rl"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"# {path}: 1400 samples at 100 Hz (14.0 s)") and len(out) == 2 + 5


def test_a_columns_option_naming_no_channel_is_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as exit_:
        main(["analyze", "x.csv", "--columns", "b1=x"])
    assert exit_.value.code == 2
    assert "argument --columns: 'b1' is no channel: use time or a1, a2, a3" in capsys.readouterr().err


def test_analyze_says_jittered_times_were_resampled_onto_the_grid(tmp_path: Path, config: Path, capsys) -> None:
    t = np.arange(1400) / FS_HZ + np.random.default_rng(1).uniform(-0.001, 0.001, 1400)  # +-1 ms at 100 Hz: 10 %
    path = tmp_path / "jitter.csv"
    write_csv_recording(path, t, bogie_g(1400) * STANDARD_GRAVITY_MPS2)
    assert main(["analyze", str(path), "--config", str(config)]) == 0
    out = capsys.readouterr().out
    assert f"# {path}: 1400 samples at 100 Hz" in out
    assert f"# {path}: 13" in out and "samples with jittered time stamps resampled onto the recording's nominal grid" in out


def test_replay_calls_twenty_seconds_missing_a_gap_not_a_rate(tmp_path: Path, config: Path, capsys) -> None:
    t = np.concatenate([np.arange(1000), np.arange(3000, 4000)]) / FS_HZ  # 10 s, 20 s missing, 10 s
    path = tmp_path / "gap.csv"
    write_csv_recording(path, t, bogie_g(t.size) * STANDARD_GRAVITY_MPS2)
    assert main(["replay", str(path), "--config", str(config)]) == 0
    err = capsys.readouterr().err
    assert f"{path}: a gap in the time stamps (samples missing): a new segment after each, no window spans one" in err
    assert "replayed 1 recording(s): 6 windows, " in err  # three in each 10 s segment, none across the gap
    assert "resample" not in err.replace("resampled", "")


def test_replay_and_analyze_of_a_folder_read_its_recordings_in_name_order(tmp_path: Path, config: Path, capsys) -> None:
    folder = tmp_path / "day"
    folder.mkdir()
    a = bogie_g(1000) * STANDARD_GRAVITY_MPS2
    write_csv_recording(folder / "0002.csv", 20.0 + np.arange(1000) / FS_HZ, a)
    write_csv_recording(folder / "0001.csv.gz", np.arange(1000) / FS_HZ, a)
    (folder / "README.txt").write_text("the logger's notes\n")
    assert main(["replay", str(folder), "--config", str(config)]) == 0
    assert "replayed 2 recording(s): 6 windows, " in capsys.readouterr().err
    assert main(["analyze", str(folder), "--config", str(config)]) == 0
    headers = [line for line in capsys.readouterr().out.splitlines() if line.startswith("# ")]
    assert [h.split(":")[0] for h in headers] == [f"# {folder / '0001.csv.gz'}", f"# {folder / '0002.csv'}"]


def test_a_folder_holding_no_recording_is_one_line(tmp_path: Path, config: Path, capsys) -> None:
    (tmp_path / "empty").mkdir()
    assert main(["analyze", str(tmp_path / "empty"), "--config", str(config)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"bogiemon: error: {tmp_path / 'empty'}: a folder holding no recording or CAN log (.csv, .csv.gz, .parquet, .mf4, .log, .asc, .blf, .trc, ...)"]


def test_convert_writes_another_loggers_recording_in_g_as_bogiemons_own_in_m_per_s2(tmp_path: Path, capsys) -> None:
    from bogiemon.drivers.recording import read_recording

    t = np.arange(1400) / FS_HZ
    a = np.round(bogie_g(1400), 6)
    lines = ["ts;acc_fl;acc_fr;acc_rl"] + [f"{float(x)!r};{y:.6f};{z:.6f};{w:.6f}" for x, (y, z, w) in zip(t, a, strict=True)]
    (tmp_path / "logger.csv").write_text("\n".join(lines) + "\n")
    args = ["convert", str(tmp_path / "logger.csv"), "-o", str(tmp_path / "own.parquet"), "--columns", "a1=acc_fl,a2=acc_fr,a3=acc_rl"]
    assert main(args) == 2
    assert "these values look like g" in capsys.readouterr().err
    assert main([*args, "--unit", "g"]) == 0
    rec = read_recording(tmp_path / "own.parquet")
    np.testing.assert_array_equal(rec.accel_mps2, a * STANDARD_GRAVITY_MPS2)
    np.testing.assert_allclose(rec.time_s, t, rtol=0, atol=1e-9)  # a block's times: its start + k / fs
