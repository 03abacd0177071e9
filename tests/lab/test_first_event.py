"""The first-event measurement's counting (bogiemon/lab/robust/first_event.py), on events made by
hand: which event a fault's sequence showed first, and when it was confirmed."""

from __future__ import annotations

from bogiemon.lab.robust.first_event import Tally, after_onset, tally_trend
from bogiemon.lab.robust.judge import JudgedRun, Outcome


def judged(*events: tuple[str, float, dict]) -> JudgedRun:
    return JudgedRun(events=tuple(Outcome(kind, time_s, details) for kind, time_s, details in events), loads=())


def test_events_are_timed_from_the_onset_across_the_runs_and_those_before_it_left_out() -> None:
    runs = [judged(("SUSPECTED", 100.0, {})), judged(("SENSOR_FAULT", 50.0, {"x": 1}), ("CONFIRMED", 300.0, {}))]
    assert after_onset(150.0, [450.0, 450.0], runs) == [(350.0, "SENSOR_FAULT", {"x": 1}), (600.0, "CONFIRMED", {})]


def test_a_sensor_fault_first_is_alone_only_when_it_names_no_suspension() -> None:
    t = Tally()
    tally_trend(t, [(10.0, "SENSOR_FAULT", {}), (90.0, "CONFIRMED", {})])
    tally_trend(t, [(20.0, "SENSOR_FAULT", {"suspension": {"corners": ["leading-left", "trailing-right"]}})])
    tally_trend(t, [(30.0, "SUSPECTED", {}), (40.0, "SENSOR_FAULT", {}), (70.0, "CONFIRMED", {})])
    tally_trend(t, [])
    assert (t.sequences, t.sensor_alone_first, t.sensor_first, t.sensor_any) == (4, 1, 2, 3)
    assert (t.confirmed, t.confirm_s) == (2, [90.0, 70.0])
