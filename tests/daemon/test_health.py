"""Sensor health and gating: sensor faults and standstill are told apart from the suspension."""

import pytest

from bogiemon.daemon.events import EventKind
from bogiemon.daemon.health import Gate, HealthSettings, HealthTracker, SensorProblem, assess_window
from bogiemon.detection import WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats
from bogiemon.drivers.base import SensorStatus

SETTINGS = HealthSettings()
OK = SensorStatus.OK


def window(rms=(1.0, 1.1, 0.9), repeat=(0.0, 0.0, 0.0), clipped=(0.0, 0.0, 0.0), t=0.0, run_s=(0.002, 0.002, 0.002)) -> WindowIndicators:
    stats = ChannelStats((9.81,) * 3, (10.0,) * 3, tuple(repeat), tuple(run_s), tuple(clipped))
    return WindowIndicators(
        start_s=t, end_s=t + 60, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=0,
        rms_mps2=tuple(rms), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=stats,
    )  # fmt: skip


def test_a_running_healthy_bogie_is_judgeable() -> None:
    health = assess_window(window(), SETTINGS)
    assert health.judgeable and health.gate is None and health.problems == {}


@pytest.mark.parametrize(
    ("kwargs", "status", "gaps", "expected"),
    [
        ({"rms": (0.001, 1.0, 1.0)}, (OK, OK, OK), 0, {"a1": (SensorProblem.FLAT,)}),
        ({"repeat": (0.0, 0.9, 0.0)}, (OK, OK, OK), 0, {"a2": (SensorProblem.STUCK,)}),
        ({"run_s": (0.002, 0.002, 1.5)}, (OK, OK, OK), 0, {"a3": (SensorProblem.STUCK,)}),
        ({"clipped": (0.0, 0.0, 0.01)}, (OK, OK, OK), 0, {"a3": (SensorProblem.CLIPPING,)}),
        ({"rms": (1.0, 9.0, 1.0)}, (OK, OK, OK), 0, {"a2": (SensorProblem.NOISY,)}),
        ({"rms": (60.0, 60.0, 60.0)}, (OK, OK, OK), 0, {c: (SensorProblem.NOISY,) for c in ("a1", "a2", "a3")}),
        ({}, (OK, SensorStatus.SENSOR_FAULT, OK), 0, {"a2": (SensorProblem.SENSOR_FAULT_BIT,)}),
        ({}, (SensorStatus.OVER_RANGE, OK, OK), 0, {"a1": (SensorProblem.OVER_RANGE,)}),
        ({}, (OK, OK, OK), 7, {"source": (SensorProblem.DROPOUTS,)}),
    ],
    ids=["flat", "stuck", "stuck-just-now", "clipping", "noisy-ratio", "noisy-absolute", "fault-bit", "over-range-bit", "dropouts"],
)
def test_each_sensor_problem_is_named_on_its_channel(kwargs, status, gaps, expected) -> None:
    health = assess_window(window(**kwargs), SETTINGS, status, gaps)
    assert health.problems == expected
    assert not health.judgeable


def test_all_channels_quiet_is_standstill_not_a_sensor_fault() -> None:
    health = assess_window(window(rms=(0.01, 0.01, 0.01), repeat=(0.5, 0.5, 0.5)), SETTINGS)
    assert health.gate is Gate.STANDSTILL and health.sensors_ok and not health.judgeable


def test_moving_gently_is_weak_excitation() -> None:
    health = assess_window(window(rms=(0.1, 0.1, 0.1)), SETTINGS)
    assert health.gate is Gate.WEAK_EXCITATION and health.sensors_ok


def test_tracker_reports_a_fault_once_and_clears_after_healthy_moving_windows() -> None:
    tracker = HealthTracker("cfg", clear_after_windows=2)
    bad, good, still = window(rms=(0.001, 1, 1)), window(), window(rms=(0.01, 0.01, 0.01))
    kinds = []
    for w in (bad, bad, good, still, still, good, good, good):
        kinds.append([e.kind for e in tracker.update(w, assess_window(w, SETTINGS))])
    assert kinds == [[EventKind.SENSOR_FAULT], [], [], [], [], [EventKind.SENSOR_CLEARED], [], []]


def test_tracker_reports_again_when_a_new_problem_appears() -> None:
    tracker = HealthTracker("cfg")
    first = tracker.update(window(rms=(0.001, 1, 1)), assess_window(window(rms=(0.001, 1, 1)), SETTINGS))
    w = window(rms=(0.001, 1, 1), repeat=(0, 0.9, 0))
    second = tracker.update(w, assess_window(w, SETTINGS))
    assert first[0].details["problems"] == {"a1": ["flat"]}
    assert second[0].details["problems"] == {"a1": ["flat"], "a2": ["stuck"]}
    assert second[0].details["reported"] == {"a1": ["flat"], "a2": ["stuck"]}


def test_a_problem_that_comes_and_goes_while_the_fault_lasts_is_reported_once() -> None:
    tracker = HealthTracker("cfg")
    flat, flat_and_stuck = window(rms=(0.001, 1, 1)), window(rms=(0.001, 1, 1), repeat=(0.9, 0, 0))
    events = []
    for w in (flat, flat_and_stuck, flat, flat_and_stuck, flat):
        events += tracker.update(w, assess_window(w, SETTINGS))
    assert [e.details["problems"] for e in events] == [{"a1": ["flat"]}, {"a1": ["flat", "stuck"]}]
