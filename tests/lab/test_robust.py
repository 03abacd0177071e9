"""Detection on a varied wagon, on small simulated sets: load state, localisation, sensor faults.

One wagon of the evaluation's fleet (its own masses, springs, dampers and sensor errors) is
commissioned on healthy runs with `calibrate`'s code and judged by the daemon's own WindowJudge
with the shipped models, as in docs/robust.
"""

from __future__ import annotations

import numpy as np
import pytest

from bogiemon.daemon.calibrate import calibrate_windows, combine_loads, fragment
from bogiemon.daemon.config import BogiemonConfig, load_config
from bogiemon.judgement.events import ConfirmedDetails, Event, SensorFaultDetails
from bogiemon.judgement.vocabulary import LoadSource
from bogiemon.judgement.verdict import WindowJudge
from bogiemon.detection import Corner, IndicatorStream
from bogiemon.lab.robust.fleet import EXPECTED_PROBLEM, HEALTHY, SENSOR_DAMAGE, RunSpec, damage_sensors, scenario_for
from bogiemon.lab.robust.wagons import make_wagon
from bogiemon.lab.robust.judge import with_fragment
from bogiemon.simulator.run import simulate_batch
from tests.judgement.event_examples import details_as

CONFIG = load_config(None)
SETTINGS, GEOMETRY = CONFIG.processing_settings(), CONFIG.bogie_geometry()
WAGON = make_wagon("test wagon", seed=7)


def spec(role: str, load: str, number: int, duration_s: float, key: str = HEALTHY, severity: float = 1.0, corner: Corner | None = None) -> RunSpec:
    onset = 150.0 if key != HEALTHY else 0.0
    return RunSpec(role, 0, load, key, severity, corner, number, duration_s, onset)


def simulate(specs: list[RunSpec]) -> dict[RunSpec, np.ndarray]:
    """Each run's windows, and the raw accelerations of the healthy test runs."""
    results = simulate_batch([scenario_for(s, WAGON, SETTINGS.fs_hz, GEOMETRY) for s in specs])
    return {s: r.accel_mps2 for s, r in zip(specs, results, strict=True)}


def windows(accel) -> list:
    return IndicatorStream(SETTINGS, GEOMETRY, clip_level_mps2=CONFIG.health.clip_level_mps2).process(accel)


FAULTS = [
    ("tare", "type_a.tare.rear_outer", Corner.LEADING_LEFT),
    ("tare", "type_a.tare.rear_outer", Corner.TRAILING_RIGHT),  # the corner without a sensor
    ("tare", "type_a.tare.front_outer", Corner.LEADING_RIGHT),
    ("full", "type_a.full.rear_outer", Corner.TRAILING_LEFT),
]


@pytest.fixture(scope="module")
def fleet_runs() -> dict[RunSpec, np.ndarray]:
    specs = [spec("calibration", ld, k, 450.0) for ld in ("full", "tare") for k in range(6)]
    specs += [spec("healthy", ld, k, 450.0) for ld in ("full", "tare") for k in range(2)]
    specs += [spec("fault", ld, 0, 450.0, key, 0.0, corner) for ld, key, corner in FAULTS]
    return simulate(specs)


@pytest.fixture(scope="module")
def commissioned(fleet_runs) -> BogiemonConfig:
    parts = []
    for load in ("full", "tare"):
        cal = [w for s, a in fleet_runs.items() if s.role == "calibration" and s.load == load for w in windows(a)]
        parts.append(calibrate_windows(cal, CONFIG, load))
    return with_fragment(CONFIG, fragment(combine_loads(parts, CONFIG)))


def judge(config, accel) -> tuple[list, list]:
    judge = WindowJudge(config.monitor_settings())
    events: list[Event] = []
    loads = []
    for w in windows(accel):
        judged = judge.judge(w)
        events += judged.events
        loads.append(judged.load)
    return events, loads


def test_the_load_state_is_estimated_right_in_every_window(fleet_runs) -> None:
    assert CONFIG.decision.load == "auto"
    for s, accel in fleet_runs.items():
        if s.role in ("healthy", "fault"):
            _, loads = judge(CONFIG, accel)
            judged = [ld for ld in loads if ld is not None]
            assert len(judged) >= 30 and all(ld == s.load for ld in judged), (s.name, judged)


def test_the_commissioned_load_states_are_right_in_every_judged_window(fleet_runs, commissioned) -> None:
    # Each load commissioned from its own runs: the window goes to the nearest state (or is not
    # judged), with no load model from our simulator.
    for s, accel in fleet_runs.items():
        if s.role in ("healthy", "fault"):
            _, loads = judge(commissioned, accel)
            judged = [ld for ld in loads if ld is not None]
            assert len(judged) >= 30 and all(ld == s.load for ld in judged), (s.name, judged)


def test_healthy_runs_of_the_commissioned_wagon_confirm_nothing(fleet_runs, commissioned) -> None:
    for s, accel in fleet_runs.items():
        if s.role == "healthy":
            events, _ = judge(commissioned, accel)
            # A SUSPECTED now and then is the warning level doing its job (about one per 100 h by design).
            assert {e.kind.value for e in events} <= {"SUSPECTED", "CLEARED"}, s.name


@pytest.mark.parametrize(("load", "key", "corner"), FAULTS, ids=[f"{k.split('.')[1]}-{k.split('.')[2]}-{c.value}" for _, k, c in FAULTS])
def test_a_broken_spring_is_confirmed_at_its_corner(fleet_runs, commissioned, load, key, corner) -> None:
    accel = fleet_runs[spec("fault", load, 0, 450.0, key, 0.0, corner)]
    events, _ = judge(commissioned, accel)
    confirmed = [e for e in events if e.kind.value == "CONFIRMED"]
    assert confirmed, [e.kind.value for e in events]
    first = confirmed[0]
    assert first.time_s > 150.0  # after the spring broke, never before
    # The diagonal pair from the geometry, or "unknown" when the pitch-roll sign is not clear: never
    # a pair without the corner (judgement/diagnosis.py).
    details = details_as(first, ConfirmedDetails)
    assert details.diagnosis is not None
    named = details.diagnosis.corners
    assert named == () or corner in named
    assert details.load == load and details.running is not None and details.running.load_source is LoadSource.COMMISSIONED


# "hiss a2" (white noise well below the frame's own signal) is measured by the transfer evaluation
# (docs/robust/transfer) against issue 16's target, not asserted here: the health checks that are
# to see it are being built (lab/robust/health_check.py).
@pytest.mark.parametrize("damage", [d for d in SENSOR_DAMAGE if d != "hiss a2"])
def test_a_damaged_sensor_is_a_sensor_fault_never_a_suspension_alarm(fleet_runs, commissioned, damage) -> None:
    healthy = next(a for s, a in fleet_runs.items() if s.role == "healthy" and s.load == "full")
    events, _ = judge(commissioned, damage_sensors(healthy, damage, SETTINGS.fs_hz, seed=3))
    kinds = {e.kind.value for e in events}
    assert not kinds & {"SUSPECTED", "CONFIRMED"}, kinds
    problem, channels = EXPECTED_PROBLEM[damage]
    named = {(ch, p) for e in events if isinstance(e.details, SensorFaultDetails) for ch, ps in e.details.problems.items() for p in ps}
    assert {(ch, problem) for ch in channels} <= named, named
