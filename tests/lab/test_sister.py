"""The sister study (lab/sister): its plan's runs, its scenarios of both bogies, the cache, the
measurements, the fitted prior and the guard on a tiny fleet."""

from __future__ import annotations

import numpy as np
import pytest

from bogiemon.daemon.config import default_config_text, parse_config
from bogiemon.detection import Corner
from bogiemon.judgement.models import shipped_models
from bogiemon.judgement.sister import load_sister_model
from bogiemon.lab.robust.fleet import MIRROR
from bogiemon.lab.sister.features import FEATURES, table_of
from bogiemon.lab.sister.fit import fit_sister_model, write_sister_model
from bogiemon.lab.sister.guard import guard_study
from bogiemon.lab.sister.plan import TRAINING_SHARE_SPREAD, UNEVEN_SHARE, SisterPlan, SisterRun, scenario_for, simulate_sister
from bogiemon.lab.sister.study import detection_shares, measure

CONFIG = parse_config(default_config_text(), "default")
SETTINGS, GEOMETRY, HEALTH = CONFIG.processing_settings(), CONFIG.bogie_geometry(), CONFIG.health_settings()
PLAN = SisterPlan.quick("a")


def test_the_default_plan_has_every_fault_case_on_either_bogie_and_held_out_wagons() -> None:
    plan = SisterPlan.default("a")
    runs = plan.runs()
    faults = {(r.key, r.severity, r.bogie) for r in runs if r.role == "train-fault"}
    assert len(faults) == 32 * 2  # every cell of the paper's tables, both bogies
    assert {r.bogie for r in runs if r.role == "fault"} == {1, 2}
    training = {w.seed for w in plan.training_fleet()}
    assert training.isdisjoint(w.seed for w in plan.fleet())
    shares: dict[int, list[float]] = {}
    for r in runs:
        if r.role == "train-healthy" and r.load == "full":
            shares.setdefault(r.wagon, []).append(r.leading_share)
    # Drawn per run: a training wagon's loading changes from one run to the next, within the spread.
    assert all(len(set(s)) > 1 for s in shares.values())
    assert all(abs(x - 0.5) <= TRAINING_SHARE_SPREAD for s in shares.values() for x in s)
    assert {r.leading_share for r in runs if r.role == "train-healthy" and r.load == "tare"} == {0.5}


def _run_of(reversed_: bool, **kwargs: object) -> SisterRun:
    """A fault run on bogie 2 whose drawn direction is the one asked."""
    for number in range(40):
        run = SisterRun("fault", 0, "full", "type_a.full.rear_outer", 0.0, Corner.LEADING_LEFT, 2, number, **kwargs)  # type: ignore[arg-type]
        if run.conditions().reversed == reversed_:
            return run
    raise AssertionError("no run of that direction")


@pytest.mark.parametrize("reversed_", [False, True])
def test_a_run_the_other_way_round_puts_the_fault_on_the_wagons_own_bogie_2_mirrored(reversed_: bool) -> None:
    run = _run_of(reversed_)
    scenario, swapped = scenario_for(run, PLAN.fleet()[0], SETTINGS.fs_hz, GEOMETRY)
    assert swapped is reversed_
    (fault,) = scenario.faults
    # The wagon's bogie 2 trails when it runs its own way, leads the other way round.
    assert fault.bogie == ("leading" if reversed_ else "trailing")
    assert fault.corner == (MIRROR[Corner.LEADING_LEFT] if reversed_ else Corner.LEADING_LEFT)
    assert scenario.bogies == 2 and len(scenario.standing_faults) == 7


@pytest.mark.parametrize("reversed_", [False, True])
def test_a_wagon_loaded_60_40_carries_the_more_on_its_own_bogie_1_whichever_way_it_runs(reversed_: bool) -> None:
    run = _run_of(reversed_, leading_share=UNEVEN_SHARE)
    scenario, _ = scenario_for(run, PLAN.fleet()[0], SETTINGS.fs_hz, GEOMETRY)
    assert scenario.parameters is not None
    offset = scenario.parameters["vehicle"]["carbody"]["centre_of_mass_offset_m"]
    assert (offset < 0) is reversed_ and abs(offset) > 0.5  # towards the kernel's leading bogie when bogie 1 leads


@pytest.fixture(scope="module")
def training(tmp_path_factory: pytest.TempPathFactory):
    cache = tmp_path_factory.mktemp("sister")
    first = simulate_sister(PLAN, SETTINGS, GEOMETRY, cache, roles=("train-healthy", "train-fault"))
    return first, simulate_sister(PLAN, SETTINGS, GEOMETRY, cache, roles=("train-healthy", "train-fault"))


def test_a_rerun_reads_every_run_from_the_cache(training) -> None:
    first, again = training
    assert first.new_s == first.simulated_s > 0 and again.new_s == 0.0
    assert [len(p.windows[0]) for p in again.runs] == [len(p.windows[0]) for p in first.runs]
    assert again.runs[0].windows[1][0].i2 == first.runs[0].windows[1][0].i2


def test_the_measurements_give_every_feature_its_spreads_and_fault_scores(training) -> None:
    data, _ = training
    healthy, faults = table_of(data.select(role="train-healthy"), GEOMETRY), table_of(data.select(role="train-fault"), GEOMETRY)
    rows = measure("a", healthy, faults)
    assert [r.feature for r in rows] == list(FEATURES)
    by_name = {r.feature: r for r in rows}
    # Two bogies on one track: their amplitudes move together, far more than any coupling.
    assert by_name["log_rms_roll"].correlation > 0.9 and by_name["log_rms_roll"].ratio > 3.0
    assert by_name["log_rms_roll"].ratio > by_name["c_br_6"].ratio
    assert by_name["c_pr_6"].fault_runs["broken spring"] == 2
    shares = detection_shares(healthy.where(healthy.load == "full"), faults.where((faults.load == "full") & faults.faulty), ["log_i2", "c_pr_6"])
    assert all(0.0 <= s <= 1.0 for s in shares)


def test_the_fitted_prior_reads_back_and_its_guard_refuses_no_healthy_training_commissioning(training, tmp_path) -> None:
    data, _ = training
    fused = {str(k): v for k, v in shipped_models().fused.items()}
    fitted = fit_sister_model({"a": data}, {"full": ("log_i2", "c_pr_6")}, HEALTH, fused, 3, 5)
    path = write_sister_model(fitted, tmp_path / "sister_model.toml", "a test", "a tiny fleet")
    prior = load_sister_model(path)
    assert set(prior.loads) == {"full"} and prior.loads["full"].features == ("log_i2", "c_pr_6")
    assert np.all(np.linalg.eigvalsh(prior.loads["full"].population_covariance) > 0)
    stretches = [s for s in guard_study({"a": data}, prior, fused, HEALTH) if s.fleet == "training"]
    assert stretches and not any(s.sister_refused for s in stretches if s.group is None)
