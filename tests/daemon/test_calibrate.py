"""`bogiemon calibrate`: the wagon's healthy baseline from recordings, as a fragment the daemon reads."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.calibrate import MIN_WINDOWS, CalibrationError, calibrate
from bogiemon.cli.main import main
from bogiemon.daemon.config import load_config
from bogiemon.judgement.health import assess_window
from bogiemon.judgement.models import coupling_features
from bogiemon.detection import IndicatorStream
from bogiemon.drivers.recording import read_csv_recording
from bogiemon.simulator import Scenario, simulate
from bogiemon.simulator.scenario import SpeedProfile
from bogiemon.simulator.run import write_recording

CONFIG = load_config(None)


@pytest.fixture(scope="module")
def recordings(tmp_path_factory) -> dict[str, list[Path]]:
    folder = tmp_path_factory.mktemp("healthy")
    out: dict[str, list[Path]] = {"full": [], "tare": []}
    for load in out:
        for seed, track in ((1, "erri-low"), (2, "erri-high")):
            path = folder / f"{load}-{seed}.csv"
            write_recording(simulate(Scenario(load=load, track=track, speed=SpeedProfile(((0.0, 70.0 + 10 * seed),)), duration_s=300.0, seed=seed)), path)
            out[load].append(path)
    return out


def judged_windows(paths: list[Path]) -> list:
    health, geometry = CONFIG.health_settings(), CONFIG.bogie_geometry()
    out = []
    for path in paths:
        rec = read_csv_recording(path)
        stream = IndicatorStream(CONFIG.processing_settings(rec.fs_hz), geometry, clip_level_mps2=health.clip_level_mps2)
        out += [w for w in stream.process(rec.accel_mps2) if assess_window(w, health, geometry=geometry).judgeable]
    return out


def test_the_fused_center_is_the_mean_coupling_vector_and_the_thresholds_center_the_median(recordings) -> None:
    result = calibrate(recordings["full"], CONFIG, "full")
    (full,) = result.loads
    windows = judged_windows(recordings["full"])
    assert full.n_judged == len(windows) >= MIN_WINDOWS
    features = [f for w in windows if (f := coupling_features(w, CONFIG.bogie_geometry())) is not None]
    assert len(features) == len(windows)
    want = np.mean(features, axis=0)
    assert full.fused is not None
    np.testing.assert_allclose(full.fused.center, want, rtol=1e-12)
    assert full.fused.level_factor >= 1.0
    for ind in full.indicators:
        assert ind.threshold.center == pytest.approx(float(np.median([getattr(w, ind.name) for w in windows])))
        assert ind.threshold.warning <= ind.threshold.alarm
        assert ind.threshold.alarm >= 1.1 * ind.max_deviation


def test_auto_calibrates_each_load_state_from_its_own_windows(recordings) -> None:
    result = calibrate(recordings["full"] + recordings["tare"], CONFIG, "auto")
    assert [c.load for c in result.loads] == ["full", "tare"]
    for c in result.loads:
        assert c.n_judged == len(judged_windows(recordings[c.load]))


def test_the_cli_writes_a_fragment_the_daemon_reads(recordings, tmp_path: Path, capsys) -> None:
    fragment = tmp_path / "calibration.toml"
    files = [str(p) for p in recordings["full"] + recordings["tare"]]
    assert main(["calibrate", *files, "--load", "auto", "-o", str(fragment)]) == 0
    assert "full (" in capsys.readouterr().err
    site = tmp_path / "bogiemon.toml"
    site.write_text(f'include = ["{fragment.name}"]\n')
    config = load_config(site)
    expected = calibrate(recordings["full"] + recordings["tare"], CONFIG, "auto")
    for c in expected.loads:
        assert c.fused is not None
        np.testing.assert_allclose(config.decision.fused[c.load].center, c.fused.center, rtol=1e-9)
        assert config.decision.fused[c.load].trend_alarm == pytest.approx(c.fused.levels.trend_alarm)
    baselines = config.fused_baselines()
    assert {b.name for b in baselines.values()} == {"calibrated"}
    assert main(["check-config", str(site)]) == 0


def test_too_short_a_recording_is_one_clear_error(recordings, tmp_path: Path, capsys) -> None:
    with pytest.raises(CalibrationError, match="calibration needs at least 30"):
        calibrate(recordings["full"][:1], CONFIG, "full")
    assert main(["calibrate", str(recordings["full"][0]), "--load", "full", "-o", str(tmp_path / "x.toml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("bogiemon: error: only ") and "record longer runs" in err and "Traceback" not in err
