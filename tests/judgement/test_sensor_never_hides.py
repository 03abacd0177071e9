"""A sensor fault never hides a suspension fault (judgement/health.py): noise the floor alone sees
holds back no judgement of the couplings, and a SENSOR_FAULT says when they point at a corner."""

from __future__ import annotations

import dataclasses

import pytest

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.judgement.events import SensorFaultDetails, SuspensionHint
from bogiemon.judgement.health import SensorProblem, WindowHealth
from bogiemon.judgement.gating import Gate
from bogiemon.judgement.sensor_tracker import HealthState, HealthTracker
from bogiemon.judgement.verdict import MonitorSettings, Outcome, WindowJudge
from tests.judgement.test_noise_floor import GEOMETRY, commissioned, frame_run

NOISY = (SensorProblem.NOISY,)


@pytest.fixture(scope="module")
def settings() -> MonitorSettings:
    base = BogiemonConfig().monitor_settings(load="full")
    return dataclasses.replace(base, health=commissioned(), geometry=GEOMETRY)


def _through(settings: MonitorSettings, through: bool) -> MonitorSettings:
    return dataclasses.replace(settings, health=dataclasses.replace(settings.health, judge_through_floor_noise=through))


def test_only_floor_noise_on_a_running_window_leaves_its_couplings_readable() -> None:
    assert WindowHealth(None, {"a2": NOISY}, floor_only=("a2",)).couplings_readable
    assert not WindowHealth(None, {"a2": NOISY, "a3": NOISY}, floor_only=("a2",)).couplings_readable  # a3 seen by another check
    assert not WindowHealth(Gate.STANDSTILL, {"a2": NOISY}, floor_only=("a2",)).couplings_readable
    assert not WindowHealth(None, {}, floor_only=()).couplings_readable  # nothing flagged: judgeable as it is


def test_a_window_whose_noise_the_floor_alone_sees_is_judged_and_the_sensor_reported(settings: MonitorSettings) -> None:
    judge = WindowJudge(_through(settings, True))
    verdicts = [judge.judge(w) for w in frame_run(11, hiss_mps2=(0.0, 0.4, 0.0))]
    assert all(v.health.floor_only == ("a2",) and v.outcome is Outcome.JUDGED for v in verdicts)
    faults = [e for v in verdicts for e in v.events if e.kind.value == "SENSOR_FAULT"]
    (fault,) = [e.details for e in faults if isinstance(e.details, SensorFaultDetails)]
    assert len(faults) == 1 and fault.problems == {"a2": ("noisy",)} and fault.suspension is None
    assert judge.health.faulted and not judge.health.holds_judgement


def test_without_judging_through_floor_noise_the_same_windows_are_held_back(settings: MonitorSettings) -> None:
    judge = WindowJudge(_through(settings, False))
    verdicts = [judge.judge(w) for w in frame_run(11, hiss_mps2=(0.0, 0.4, 0.0))]
    assert all(v.outcome is Outcome.SENSOR for v in verdicts) and judge.health.holds_judgement


def test_gross_noise_holds_the_judgement_back_until_it_clears_even_after_floor_noise(settings: MonitorSettings) -> None:
    judge = WindowJudge(_through(settings, True))
    faint, gross = frame_run(11, hiss_mps2=(0.0, 0.4, 0.0)), frame_run(12, hiss_mps2=(0.0, 3.0, 0.0))
    assert [judge.judge(w).outcome for w in faint[:2]] == [Outcome.JUDGED] * 2
    held = [judge.judge(w) for w in gross[:2]]
    assert held[0].health.floor_only == () and all(v.outcome is Outcome.SENSOR for v in held)
    # Faint noise again: the gross noise reported still holds it back (a problem reported is not forgotten).
    assert judge.judge(faint[2]).outcome is Outcome.SENSOR and judge.health.holds_judgement


def _health(channel: str = "a3") -> WindowHealth:
    return WindowHealth(None, {channel: NOISY}, floor_only=(channel,))


def test_a_sensor_fault_is_told_again_when_the_couplings_first_point_at_a_corner() -> None:
    window = frame_run(11)[0]
    tracker = HealthTracker("h")
    first = tracker.update(window, _health(), holds=False)
    pointed = SuspensionHint(("trailing-left", "leading-right"), 80.0, 67.0, "...")
    second = tracker.update(window, _health(), holds=False, suspension=pointed)
    third = tracker.update(window, _health(), holds=False, suspension=pointed)
    assert [e.kind.value for e in first + second] == ["SENSOR_FAULT", "SENSOR_FAULT"] and third == []
    told_first, told_again = first[0].details, second[0].details
    assert isinstance(told_first, SensorFaultDetails) and isinstance(told_again, SensorFaultDetails)
    assert told_first.suspension is None and told_again.suspension == pointed and told_again.reported == {"a3": ("noisy",)}


def test_the_sensor_state_keeps_whether_it_holds_the_judgement_and_an_older_state_holds_it() -> None:
    tracker = HealthTracker("h")
    tracker.update(frame_run(11)[0], _health(), holds=False)
    saved = tracker.state.as_dict()
    assert not HealthTracker("h", state=HealthState.from_dict(saved)).holds_judgement
    older = {k: v for k, v in saved.items() if k not in ("holding", "suspension")}
    assert HealthTracker("h", state=HealthState.from_dict(older)).holds_judgement  # saved before: held, as it then was
