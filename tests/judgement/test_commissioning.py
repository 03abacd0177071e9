"""What commissioning learns from the wagon: its load states (and what is unlike them), its own spread."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.calibrate import calibrate_loads, fragment
from bogiemon.judgement.commissioning import LIMIT_MIN, SUSTAINED_ALARM_FLOOR, SUSTAINED_WARNING_FLOOR, fit_discriminant, fit_spread, runs_of, shrunk_covariance
from bogiemon.daemon.config import load_config
from bogiemon.judgement.models import excitation_of, load_features, shipped_models
from bogiemon.judgement.running import JUDGED_DOWN_TO, choose_load, level_margin
from bogiemon.judgement.vocabulary import LoadSetting, LoadState
from bogiemon.judgement.verdict import WindowJudge
from bogiemon.detection import IndicatorStream
from bogiemon.simulator import Scenario, simulate
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.run import write_recording
from bogiemon.simulator.scenario import SpeedProfile

CONFIG = load_config(None)


def _scenario(load: str, seed: int, track: str, speed_kmh: float, parameters: dict | None = None) -> Scenario:
    return Scenario(load=load, track=track, speed=SpeedProfile(((0.0, speed_kmh),)), duration_s=300.0, seed=seed, parameters=parameters)


@pytest.fixture(scope="module")
def commissioned(tmp_path_factory: pytest.TempPathFactory):
    """A wagon commissioned per load from its own recordings (two tracks and speeds each), as the
    README asks; its fragment included in the config."""
    folder = tmp_path_factory.mktemp("commissioning")
    paths: dict[str, list[Path]] = {"full": [], "tare": []}
    for load in paths:
        for seed, track, speed in ((11, "erri-low", 60.0), (12, "erri-high", 95.0), (13, "fra-5", 80.0)):
            path = folder / f"{load}-{seed}.csv"
            write_recording(simulate(_scenario(load, seed, track, speed)), path)
            paths[load].append(path)
    result = calibrate_loads(paths, CONFIG)
    (folder / "calibration.toml").write_text(fragment(result))
    (folder / "bogiemon.toml").write_text('include = ["calibration.toml"]\n[decision]\nload = "auto"\n')
    return result, load_config(folder / "bogiemon.toml")


def _windows(scenario: Scenario, config):
    result = simulate(scenario)
    stream = IndicatorStream(config.processing_settings(scenario.fs_hz), config.bogie_geometry())
    return stream.process(result.accel_mps2)


def test_each_load_is_commissioned_from_its_own_recordings_with_its_own_spread(commissioned) -> None:
    result, config = commissioned
    assert [c.load for c in result.loads] == ["full", "tare"]
    for c in result.loads:
        assert c.signature is not None and c.signature.limit >= LIMIT_MIN
        assert c.fused is not None and c.fused.runs == 3 and c.fused.out_of_sample_median is not None
        assert c.fused.level_factor >= 1.0
    assert set(config.decision.load_states) == {"full", "tare"}
    assert len(config.decision.fused["full"].covariance) == 10
    # The sensors' noise floors of both loads together, in force through the fragment.
    assert result.noise_floor is not None and result.noise_floor.windows == sum(c.n_judged for c in result.loads)
    np.testing.assert_allclose(config.health_settings().noise_floor_psd, result.noise_floor.psd, rtol=1e-3)
    np.testing.assert_allclose(config.health_settings().noise_floor_ratio, result.noise_floor.ratio, rtol=1e-3)


def test_windows_of_other_runs_go_to_their_own_load_state(commissioned) -> None:
    _, config = commissioned
    for load, seed, track, speed in (("full", 21, "erri-low", 75.0), ("tare", 22, "fra-5", 70.0)):
        discriminant = config.load_discriminant()
        assert discriminant is not None and discriminant.separation >= 2 * discriminant.margin
        got = [_load_of(w, config) for w in _windows(_scenario(load, seed, track, speed), config)]
        # Right, or not judged (between the states or far outside their excitation); never the other load.
        assert got.count(load) >= 0.9 * len(got) and not set(got) - {load, None}, got


def _load_of(window, config):
    x = load_features(window, config.bogie_geometry())
    settings = config.monitor_settings()
    return choose_load(LoadSetting.AUTO, x, excitation_of(window), settings.load_states, settings.load_discriminant, settings.load_model).load


def test_a_half_loaded_wagon_raises_no_alarm_and_says_how_far_it_is_from_the_commissioning(commissioned) -> None:
    # The load vector moves with the track and the speed as much as with a partial load (daemon/
    # commissioning.py), so a half load is judged in the nearest commissioned state with its
    # distance stated, or not judged when beyond the state's limit; never an alarm for it.
    _, config = commissioned
    parameters = copy.deepcopy(default_parameter_set())
    wagon = parameters["fault_cases"]["wagon"]
    wagon["carbody_mass_full_kg"] = 0.5 * (float(wagon["carbody_mass_full_kg"]) + float(wagon["carbody_mass_tare_kg"]))
    judge = WindowJudge(config.monitor_settings())
    judged = [judge.judge(w) for w in _windows(_scenario("full", 23, "erri-low", 80.0, parameters), config)]
    assert judged and not [e for j in judged for e in j.events if e.kind.value in ("SUSPECTED", "CONFIRMED")]
    for j in judged:
        assert (j.unfamiliar is not None) != (j.judgement is not None)
    first = next(j for j in judged if j.judgement is not None)
    assert judge.decider.state.mode.value == "normal" and first.load == "full"


def test_the_shrunk_covariance_is_the_stated_mix() -> None:
    rng = np.random.default_rng(3)
    x = rng.normal(size=(200, 4)) @ np.diag([1.0, 2.0, 0.5, 1.5])
    prior = np.eye(4)
    got, lam = shrunk_covariance(x, prior, independent=20.0)
    own = np.cov(x.T)
    assert lam == pytest.approx(4 / 24)
    np.testing.assert_allclose(got, (1 - lam) * own + lam * prior * np.trace(own) / 4)


def test_runs_are_stretches_of_consecutive_windows() -> None:
    class W:
        def __init__(self, start_s: float) -> None:
            self.start_s = start_s

    windows = [W(t) for t in (30.0, 0.0, 10.0, 20.0, 500.0, 510.0, 2000.0)]
    assert runs_of(windows, hop_s=10.0) == [[1, 2, 3, 0], [4, 5], [6]]  # type: ignore[arg-type]


def test_a_wagon_that_scatters_more_out_of_sample_gets_higher_levels() -> None:
    model = shipped_models().fused[LoadState.FULL]
    rng = np.random.default_rng(5)
    p = model.covariance.shape[0]
    steady = rng.multivariate_normal(np.zeros(p), model.covariance, size=300)
    # The same within-run scatter, but each run's mean elsewhere: healthy runs that differ a lot.
    offsets = np.repeat(rng.normal(0.0, 3.0 * np.sqrt(np.diag(model.covariance)), size=(6, p)), 50, axis=0)
    runs = [list(range(i * 50, (i + 1) * 50)) for i in range(6)]
    calm, restless = fit_spread(steady, runs, model, 10.0), fit_spread(steady + offsets, runs, model, 10.0)
    assert restless.level_factor > calm.level_factor >= 1.0
    assert restless.levels.trend_alarm > calm.levels.trend_alarm >= model.levels.trend_alarm


def test_the_window_levels_stay_above_what_the_wagons_own_runs_sustained_out_of_sample() -> None:
    model = shipped_models().fused[LoadState.FULL]
    rng = np.random.default_rng(6)
    p = model.covariance.shape[0]
    rows = rng.multivariate_normal(np.zeros(p), model.covariance, size=300)
    rows[140:145] += 6.0 * np.sqrt(np.diag(model.covariance))  # one run holds a stretch far off
    runs = [list(range(i * 50, (i + 1) * 50)) for i in range(6)]
    fit = fit_spread(rows, runs, model, 10.0, confirm_k=3, confirm_n=5)
    confirming, suspecting = [], []
    for run in runs:
        others = np.setdiff1d(np.arange(len(rows)), run)
        cov, _ = shrunk_covariance(rows[others], model.covariance, len(others) / (model.window_s / model.hop_s))
        z = (rows[run] - rows[others].mean(axis=0)) @ np.linalg.inv(np.linalg.cholesky(cov)).T
        score = np.einsum("ij,ij->i", z, z)
        confirming.append([sorted(score[k : k + 5])[-3] for k in range(len(score) - 4)])  # 3 of 5 reach it
        suspecting.append([sorted(score[k : k + 5])[-2] for k in range(len(score) - 4)])  # 2 of 5
    largest = max(max(c) for c in confirming)
    assert fit.levels.alarm == pytest.approx(max(model.levels.alarm * fit.level_factor, SUSTAINED_ALARM_FLOOR * largest))
    assert fit.levels.alarm > model.levels.alarm * fit.level_factor  # the far-off stretch set it
    assert fit.levels.warning >= min(SUSTAINED_WARNING_FLOOR * max(max(s) for s in suspecting), fit.levels.alarm)


def test_a_window_gentler_than_the_commissioning_is_judged_with_raised_levels_and_far_gentler_not_at_all(commissioned) -> None:
    # The dampers stick more the gentler the running: a smooth track at walking pace on a loaded
    # wagon is unlike the commissioning, whatever its load vector says. Down to half the gentlest
    # commissioning window it is judged with its levels raised (stated in its limits); below, not.
    result, config = commissioned
    full = next(c for c in result.loads if c.load == "full")
    assert full.signature is not None and 0 < full.signature.lowest_excitation_mps2 < full.signature.highest_excitation_mps2
    written = config.decision.load_states["full"]
    assert written.lowest_excitation_mps2 == pytest.approx(full.signature.lowest_excitation_mps2, abs=1e-4)
    assert written.highest_excitation_mps2 == pytest.approx(full.signature.highest_excitation_mps2, abs=1e-4)
    lowest = full.signature.lowest_excitation_mps2
    windows = _windows(_scenario("full", 24, "erri-low", 35.0), config)
    gentle = [w for w in windows if excitation_of(w) < lowest]
    assert gentle, "the gentle run should lie below the commissioning's excitation"
    for settings in (config.monitor_settings(), config.monitor_settings(load="full")):
        judge = WindowJudge(settings)
        for w in gentle:
            judged = judge.judge(w)
            if excitation_of(w) < JUDGED_DOWN_TO * lowest:
                assert judged.judgement is None and judged.unfamiliar is not None and "excitation" in judged.unfamiliar
            elif judged.judgement is not None:  # the gentle run's sensors and gate allowing
                margin = level_margin(lowest / excitation_of(w))
                assert judged.judgement.level_margin == pytest.approx(margin) and margin > 1.0
                assert judged.load is not None
                plain = judge.decider.judge(w, judged.load)
                assert judged.judgement.limits["fused_score"].alarm == pytest.approx(margin * plain.limits["fused_score"].alarm)


def test_priors_can_come_from_another_folder_and_a_missing_one_is_a_clear_error(tmp_path: Path) -> None:
    from importlib import resources

    from bogiemon.daemon.config import ConfigError, parse_config

    for name in ("load_model.toml", "fused_model.toml"):
        (tmp_path / name).write_text(resources.files("bogiemon.config").joinpath(name).read_text())
    text = (tmp_path / "fused_model.toml").read_text().replace("calibration_median_score = ", "calibration_median_score = 1", 1)
    (tmp_path / "fused_model.toml").write_text(text)
    refitted = parse_config(f'[decision]\nmodels_dir = "{tmp_path}"\n', "test")
    assert shipped_models(str(tmp_path)).fused[LoadState.FULL].calibration_median_score != shipped_models().fused[LoadState.FULL].calibration_median_score
    assert refitted.load_model() == shipped_models().load
    with pytest.raises(ConfigError, match="no such model file in .*nowhere"):
        parse_config(f'[decision]\nmodels_dir = "{tmp_path / "nowhere"}"\n', "test")


def test_the_commissioning_puts_the_structure_that_held_in_both_loads_in_force(commissioned) -> None:
    # The fragment carries [health] layout_checks: the checks of the sensors' places and signs that
    # held on every healthy window of both loads, so a swap after maintenance is a sensor fault.
    result, config = commissioned
    assert result.structure is not None and result.structure.windows == result.n_judged
    assert config.health_settings().layout_checks == result.structure.checks
    for c in result.structure.checks:
        assert result.structure.smallest[c] >= 0.2


def test_the_load_discriminant_weighs_features_that_move_together_and_scatters_by_one() -> None:
    # Two features that move together with the track (a common factor) and apart with the load:
    # nearest-centre with each feature's own scale misjudges such windows, the discriminant does not.
    rng = np.random.default_rng(5)
    common = rng.normal(size=(2, 4000))
    own = 0.05 * rng.normal(size=(2, 4000, 2))
    full = np.stack([common[0], common[0]], axis=1) + own[0] + np.array([0.4, -0.4])
    tare = np.stack([common[1], common[1]], axis=1) + own[1] - np.array([0.4, -0.4])
    d = fit_discriminant(full, tare, overlap=1.0)
    assert d is not None
    values_full = full @ d.weights + d.offset
    values_tare = tare @ d.weights + d.offset
    pooled_sd = np.sqrt((np.var(values_full, ddof=1) + np.var(values_tare, ddof=1)) / 2)
    assert pooled_sd == pytest.approx(1.0, rel=0.05)
    assert d.separation > 10 and d.margin == pytest.approx(max(2.0, d.separation / 10))
    assert np.mean(values_full >= d.margin) > 0.99 and np.mean(values_tare <= -d.margin) > 0.99
    nearest = np.abs(full - full.mean(axis=0)).sum(axis=1) < np.abs(full - tare.mean(axis=0)).sum(axis=1)
    assert nearest.mean() < 0.8  # the per-feature distance cannot tell them apart
    assert fit_discriminant(full, full + 0.01, overlap=1.0) is None  # no line between one load and itself
