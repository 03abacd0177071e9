"""The robustness evaluation's machinery: the fleet, the plan, sequences, scoring and the report."""

from __future__ import annotations

import json
import math
import pickle
from dataclasses import replace

import numpy as np
import pytest

from bogiemon.daemon.config import load_config
from bogiemon.detection import Corner
from bogiemon.judgement.events import ConfirmedDetails, Event, EventKind, Trigger
from bogiemon.lab.robust.evaluate import EvaluateError, daemon_methods, load_or_simulate, report_sections
from bogiemon.lab.robust.fleet import (
    HEALTHY,
    SENSOR_DAMAGE,
    TRACKS,
    EvaluationPlan,
    RunSpec,
    damage_sensors,
    draw_conditions,
    simulate_plan,
)
from bogiemon.lab.robust.wagons import make_wagon
from bogiemon.lab.robust.judge import JudgedRun, judge_runs, sequences
from bogiemon.lab.robust.judge import _sequence_result as sequence_result
from bogiemon.lab.robust.report import write_report
from bogiemon.lab.robust.score import score_method
from tests.judgement.event_examples import details_as, event_of

CONFIG = load_config(None)


def test_a_wagon_is_drawn_from_its_seed_within_the_stated_spreads() -> None:
    a, b = make_wagon("a", 11), make_wagon("b", 11)
    assert a.spread == b.spread and a.corner_kz_scale == b.corner_kz_scale and a.sensor == b.sensor
    other = make_wagon("c", 12)
    assert other.spread != a.spread
    assert all(0.9 <= f <= 1.1 for k, f in a.spread.items() if "mass" in k or "inertia" in k)
    assert all(0.95 <= f <= 1.05 for f in a.corner_kz_scale)
    assert all(0.97 <= g <= 1.03 for g in a.sensor.gain)
    assert all(abs(x) <= 0.3 for x in a.sensor.bias_mps2)


def test_a_runs_conditions_are_reproducible_and_the_speed_stays_in_its_range() -> None:
    run = RunSpec("healthy", 0, "full", HEALTHY, 1.0, None, 3, 600.0)
    first, again = draw_conditions(run), draw_conditions(run)
    assert first == again
    speeds = [v for _, v in first.speed.points]
    assert all(50.0 <= v <= 110.0 for v in speeds)
    assert draw_conditions(replace(run, number=4)) != first


def test_commissioning_runs_cover_every_track_both_directions_and_both_ends_of_the_speed_range() -> None:
    # As the README asks a keeper; the running that follows keeps its random draw.
    plan = EvaluationPlan.default()
    runs = [r for r in plan.runs() if r.role == "calibration" and r.wagon == 0 and r.load == "full"]
    assert all(r.commissioning for r in runs) and len(runs) == plan.calibration_runs
    conditions = [draw_conditions(r) for r in runs]
    assert {c.track for c in conditions} == set(TRACKS)
    assert [c.reversed for c in conditions] == [k % 2 == 1 for k in range(len(runs))]
    starts = [c.speed.points[0][1] for c in conditions]
    assert all(v <= 65.0 for k, v in enumerate(starts) if (k // 2) % 2 == 0)
    assert all(v >= 95.0 for k, v in enumerate(starts) if (k // 2) % 2 == 1)
    training = [r for r in plan.runs() if r.role == "train-healthy" and r.wagon == 0 and r.load == "full"]
    assert [r.commissioning for r in training] == [r.number < plan.calibration_runs for r in training]
    assert not any(r.commissioning for r in plan.runs() if r.role in ("healthy", "fault", "trend", "sensor"))


def test_the_default_plan_holds_every_fault_cell_on_every_corner_and_100_healthy_hours() -> None:
    plan = EvaluationPlan.default()
    runs = plan.runs()
    healthy_h = sum(r.duration_s for r in runs if r.role == "healthy") / 3600
    assert healthy_h == pytest.approx(100.0)
    faults = {(r.key, r.severity, r.corner) for r in runs if r.role == "fault"}
    assert len(faults) == 40 * 4  # Table 4's 32 cells and the 8 tare inner ones, four corners each
    trend = [r for r in runs if r.role == "trend"]
    assert len(trend) == 40 * 4 * plan.trend_runs
    assert {r.onset_s for r in trend if r.number == 0} == {plan.lead_in_s}
    assert {r.onset_s for r in trend if r.number > 0} == {0.0}
    # Training and evaluation fleets never share a wagon.
    assert not {w.seed for w in plan.fleet()} & {w.seed for w in plan.training_fleet()}
    assert len({r.seed for r in runs}) == len(runs)


def test_sensor_damage_changes_only_the_named_channels() -> None:
    rng = np.random.default_rng(0)
    accel = rng.standard_normal((60_000, 3)) + 9.81
    for damage in SENSOR_DAMAGE:
        out = damage_sensors(accel, damage, 500.0, seed=1)
        touched = {f"a{c + 1}" for c in range(3) if not np.array_equal(out[:, c], accel[:, c])}
        kind, what = damage.split(" ")
        assert touched == set(what.split("-")), damage


def judged(events: list[Event]) -> JudgedRun:
    return JudgedRun(tuple(events), ())


def test_a_sequence_counts_running_time_from_the_onset_across_its_runs() -> None:
    from bogiemon.lab.robust.fleet import Conditions, RunWindows, SpeedProfile

    runs = [
        RunWindows(RunSpec("trend", 0, "full", "type_b.full", 0.5, Corner.LEADING_LEFT, k, 450.0, 150.0 if k == 0 else 0.0),
                   Conditions("erri-low", SpeedProfile(((0.0, 80.0),)), False), (), ())
        for k in range(3)
    ]  # fmt: skip
    confirmed = event_of(EventKind.CONFIRMED, 200.0)
    by_trend = Event.of(200.0, replace(details_as(confirmed, ConfirmedDetails), trigger=Trigger.TREND), "c0ffee")
    events = [judged([]), judged([event_of(EventKind.SUSPECTED, 300.0)]), judged([by_trend])]
    result = sequence_result(runs, events)
    assert result.confirmed_after_s == pytest.approx(450.0 - 150.0 + 450.0 + 200.0)
    assert result.fault_running_s == pytest.approx(3 * 450.0 - 150.0)
    assert result.trigger is Trigger.TREND and not result.confirmed_before_onset
    assert result.diagnosis == details_as(confirmed, ConfirmedDetails).diagnosis


@pytest.fixture(scope="module")
def tiny():
    """A tiny plan: one wagon, one load, one corner; the shipped models (no fitting here)."""
    plan = EvaluationPlan(
        name="tiny", n_wagons=1, n_training_wagons=1, calibration_runs=1, calibration_s=450.0, healthy_runs=2, healthy_s=300.0,
        fault_runs=1, lead_in_s=150.0, fault_s=240.0, trend_runs=2, trend_run_s=240.0, sensor_runs=1, sensor_s=300.0,
        loads=("full",), corners=(Corner.LEADING_LEFT,),
    )  # fmt: skip
    roles = {"calibration", "healthy", "fault", "trend", "sensor"}
    return simulate_plan(plan, CONFIG.processing_settings(), CONFIG.bogie_geometry(), roles=roles)


def test_the_sequences_group_the_healthy_runs_and_each_trend_sequence(tiny) -> None:
    groups = sequences(tiny, 0)
    healthy = [g for g in groups if g[0].run.role == "healthy"]
    assert len(healthy) == 1 and [r.run.number for r in healthy[0]] == [0, 1]
    trend = [g for g in groups if g[0].run.role == "trend"]
    assert len(trend) == 20 and all([r.run.number for r in g] == [0, 1] for g in trend)
    assert all(len(g) == 1 for g in groups if g[0].run.role in ("fault", "sensor"))


def test_a_cached_simulation_is_reused_and_one_from_an_older_bogiemon_refused(tiny, tmp_path) -> None:
    path = tmp_path / "data.pkl"
    path.write_bytes(pickle.dumps(tiny))
    reused = load_or_simulate(tiny.plan, CONFIG, path, None)
    assert reused.runs == tiny.runs and reused.elapsed_s == tiny.elapsed_s  # not simulated again
    # A pickle restores an old dataclass without its new fields; the judging would fail later.
    stale = pickle.loads(path.read_bytes())
    for run in stale.runs:
        for window in run.windows:
            object.__delattr__(window.channels, "longest_run_s")
    path.write_bytes(pickle.dumps(stale))
    with pytest.raises(EvaluateError, match=r"older bogiemon, its windows lack channels.longest_run_s: delete it"):
        load_or_simulate(tiny.plan, CONFIG, path, None)


def test_every_method_is_judged_and_the_report_is_written(tiny, tmp_path) -> None:
    scores = []
    methods = daemon_methods(tiny, CONFIG, paper=False)
    for method in methods:
        result = judge_runs(tiny, method)
        scores.append(score_method(tiny, method.name, method.description, result.runs, result.sequences))
    default = scores[-1]
    assert default.method == "fused, calibrated"
    assert default.healthy_runs == 2 and default.healthy_hours == pytest.approx(600 / 3600)
    assert sum(c.runs for c in default.cells) == 20 and sum(c.sequences for c in default.sequence_cells) == 20
    assert default.load_accuracy() == 1.0  # in the commissioned load states (no p_full margin: not estimated)
    assert {s.damage for s in default.sensors} == set(SENSOR_DAMAGE)
    # "hiss a2" is scored against issue 16's targets by the transfer evaluation, not asserted here
    # (tests/lab/test_robust.py says why).
    assert all(s.suspension_runs == 0 for s in default.sensors if s.damage != "hiss a2")
    doc = write_report(tiny, scores, tmp_path, "bogiemon evaluate -o x", 1.0, report_sections(), figures=True)
    readme = (tmp_path / "README.md").read_text()
    for heading in ("## Targets", "## Detection rate per fault case", "## Detection while the wagon runs on", "## False alarms",
                    "## Load state", "## Where is the fault", "## Sensor faults", "## Why some faults stay hidden", "## Discussion"):
        assert heading in readme, heading  # fmt: skip
    for figure in ("figures/detection_by_severity.png", "figures/alarm_ratio.png", "figures/time_to_confirm.png"):
        assert (tmp_path / figure).stat().st_size > 10_000
    again = json.loads((tmp_path / "results.json").read_text())
    assert again["default_method"] == "fused, calibrated" == doc["default_method"]
    targets = {t["target"]: t for t in again["methods"][-1]["targets"]}
    broken = targets["broken spring (0 %), full load, detected"]
    cell_runs = sum(c["runs"] for c in again["methods"][-1]["cells"] if c["key"].startswith("type_a.full") and c["severity"] == 0.0)
    assert broken["count"].endswith(f"of {cell_runs}") and cell_runs == 4
    assert math.isclose(broken["value"], int(broken["count"].split()[0]) / cell_runs)
