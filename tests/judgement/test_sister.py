"""The sister evidence (judgement/sister.py): features, baseline, attribution, the model file, the guard."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from bogiemon.detection import BogieGeometry
from bogiemon.judgement.models import ModelError
from bogiemon.judgement.rules import Level
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.sister import (
    SISTER_SCORE, SisterPrior, attribute, commissioning_guard, feature_vector, guard_bogie, guard_wagon, learn_baseline, mean_distance_sd,
    one_bogie_guard, pair_differences, parse_sister_model, sister_evidence,
)  # fmt: skip
from bogiemon.detection.features import COUPLING_NAMES, WindowFeatures
from tests.judgement.test_fused import window

NAMES = ("log_i2", "log_rms_pitch")


def _prior(within: float = 0.01, between: float = 0.04) -> SisterPrior:
    eye = np.eye(2)
    return SisterPrior(
        features=NAMES, within_covariance=within * eye, warning=20.0, alarm=40.0, calibration_median_score=2.0,
        population_center=np.zeros(2), population_covariance=(within + between) * eye, population_warning=30.0, population_alarm=50.0,
        between_covariance=between * eye, guard_margin_sd=3.0, population_guard_margin_sd=4.0,
    )  # fmt: skip


def test_a_windows_features_are_read_by_name_amplitudes_as_logs() -> None:
    x = np.linspace(-0.3, 0.3, len(COUPLING_NAMES))
    w = window(x)
    w = type(w)(**{**vars(w), "i2": 2.0, "rms_pitch_radps2": 0.5, "i4_norm": 0.25})
    assert w.spectra is not None
    got = feature_vector(w, WindowFeatures(w.spectra, BogieGeometry()), ("log_i2", "log_rms_pitch", "c_pr_4", "i4_norm"))
    assert got is not None
    np.testing.assert_allclose(got, [math.log(2.0), math.log(0.5), x[COUPLING_NAMES.index("c_pr_4")], 0.25], atol=1e-12)


def test_a_feature_that_is_not_finite_gives_no_vector() -> None:
    w = window(np.zeros(len(COUPLING_NAMES)))
    assert feature_vector(type(w)(**{**vars(w), "i2": 0.0}), None, ("log_i2",)) is None  # log of nothing
    assert feature_vector(w, None, ("c_pr_4",)) is None  # a coupling needs the window's features


def test_the_commissioned_baseline_centres_on_the_wagons_mean_difference_and_never_lowers_the_levels() -> None:
    rng = np.random.default_rng(0)
    prior = _prior()
    rows = np.array([0.3, -0.2]) + 0.1 * rng.standard_normal((600, 2))
    baseline = learn_baseline(rows, prior)
    np.testing.assert_allclose(baseline.center, rows.mean(axis=0))
    # Its own spread (0.1) matches the prior's: the median score is a chi-square(2)'s, 1.39, below
    # the prior's 2.0: the levels stand.
    assert (baseline.warning, baseline.alarm) == (prior.warning, prior.alarm)
    # Training wagons whose commissionings scored a median of 0.5: this one's 1.39 raises its levels.
    tight = dataclasses.replace(prior, calibration_median_score=0.5)
    raised = learn_baseline(rows, tight)
    median = np.median(np.sum(((rows - raised.center) @ raised.whitening.T) ** 2, axis=1))
    assert raised.alarm == pytest.approx(prior.alarm * median / 0.5) and raised.alarm > prior.alarm


def test_attribution_names_the_bogie_whose_own_score_is_clearly_larger_else_none() -> None:
    assert attribute(5.0, 30.0) == 2
    assert attribute(30.0, 5.0) == 1
    assert attribute(10.0, 15.0) is None
    assert attribute(math.nan, 100.0) is None


def test_the_evidence_scores_the_whitened_difference_and_joins_only_the_named_bogies_decision() -> None:
    baseline = _prior().baseline()  # the population's: spread 0.05 per feature
    evidence = sister_evidence(np.array([0.5, 0.0]), baseline, own_1=3.0, own_2=40.0)
    assert evidence.score == pytest.approx(0.5**2 / 0.05)
    assert evidence.level is Level.OK and evidence.blamed == 2
    assert set(evidence.extra_for(2)) == {SISTER_SCORE} and evidence.extra_for(1) == {}
    loud = sister_evidence(np.array([2.0, 0.0]), baseline, 3.0, 40.0)
    assert loud.level is Level.ALARM and loud.extra_for(2)[SISTER_SCORE][1].alarm == baseline.alarm


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[full]\nfeatures = ['c_zz_9']\n", r"features \['c_zz_9'\] are not sister features"),
        ("[full]\nfeatures = ['log_i2']\nwithin_covariance = [[1.0, 0.0]]\n", r"within_covariance: needs a finite 1 x 1 matrix"),
        ("[full]\nfeatures = ['log_i2']\n", r"\[full\]: missing or malformed field"),
        ("x = 1\n", r"no \[full\] or \[tare\] section"),
    ],
)
def test_a_bad_sister_model_is_one_error_naming_the_field(text: str, message: str) -> None:
    with pytest.raises(ModelError, match=message):
        parse_sister_model(text, "bad.toml")


def test_the_guard_measures_the_commissionings_mean_against_the_population_in_healthy_sds() -> None:
    prior = _prior()
    rows = np.tile([0.4, 0.0], (120, 1))  # 120 windows every 10 s of 120 s: 10 independent
    expected = math.sqrt(0.4**2 / (0.04 + 0.01 / 10.0))
    assert mean_distance_sd(rows, prior.population_center, prior.between_covariance, prior.within_covariance, 12.0) == pytest.approx(expected)
    verdict = commissioning_guard(rows, prior, own_distances_sd=(1.0, 6.0))
    assert verdict.refused is (expected > 3.0) and verdict.bogie == 2
    assert "bogie 2 already differs from bogie 1 by 2.0 standard deviations" in verdict.message() and "--force" in verdict.message()
    assert not commissioning_guard(rows * 0.1, prior).refused


def test_the_one_bogie_guard_refuses_a_commissioning_far_from_the_population() -> None:
    center, covariance = np.zeros(3), np.eye(3) * 0.01
    assert not one_bogie_guard([np.array([0.1, 0.0, 0.0])] * 5, center, covariance, 4.0).refused
    far = one_bogie_guard([np.array([0.5, 0.0, 0.0])] * 5, center, covariance, 4.0)
    assert far.refused and far.distance_sd == pytest.approx(5.0) and "population" in far.message()


def test_a_commissioning_pair_counts_only_where_both_windows_are_judgeable() -> None:
    x = np.zeros(len(COUPLING_NAMES))

    def amplitudes(t_s: float, i2: float) -> object:
        w = window(x, t_s)
        return type(w)(**{**vars(w), "i2": i2})

    ones = [amplitudes(10.0 * i, 1.0) for i in range(4)]
    twos = [amplitudes(10.0 * i, 2.0) for i in range(4)]
    # Bogie 2's third window stood still: every channel quiet, gated.
    quiet = twos[2]
    twos[2] = type(quiet)(**{**vars(quiet), "rms_mps2": (0.01, 0.01, 0.01)})
    rows = pair_differences(ones, twos[:3] + [amplitudes(35.0, 2.0)], BogieGeometry(), NAMES, HealthSettings(structure_checks=False))  # type: ignore[arg-type]
    np.testing.assert_allclose(rows, [[math.log(2.0), 0.0]] * 2)  # the third gated, the fourth not aligned


def test_the_calibrate_commands_guard_reads_the_windows_and_names_the_bogie_that_stands_out() -> None:
    n = len(COUPLING_NAMES)
    shifted = np.zeros(n)
    shifted[COUPLING_NAMES.index("c_pr_4")] = 0.3

    def windows(x: np.ndarray, i2: float) -> list:
        return [type(w)(**{**vars(w), "i2": i2}) for w in (window(x, 10.0 * i) for i in range(24))]

    health = HealthSettings(structure_checks=False)
    prior = dataclasses.replace(_prior(), features=("log_i2", "c_pr_4"))
    verdict = guard_wagon(windows(np.zeros(n), 1.0), windows(shifted, 2.0), BogieGeometry(), health, prior, np.zeros(n), np.eye(n) * 0.01)
    expected = math.sqrt(math.log(2.0) ** 2 / (0.04 + 0.01 / 2.0) + 0.3**2 / (0.04 + 0.01 / 2.0))
    assert verdict.distance_sd == pytest.approx(expected) and verdict.refused and (verdict.bogie, verdict.other) == (2, 1)
    alone = guard_bogie(windows(shifted, 1.0), BogieGeometry(), health, prior, np.zeros(n), np.eye(n) * 0.01)
    assert alone.distance_sd == pytest.approx(3.0) and not alone.refused  # the prior's one-bogie margin is 4
