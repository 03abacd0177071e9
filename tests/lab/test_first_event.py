"""The first-event measurement's counting (bogiemon/lab/robust/first_event.py), on events made by
hand: which event a fault's sequence showed first, and when it was confirmed."""

from __future__ import annotations

from bogiemon.judgement.events import Event, EventDetails, EventKind, SensorFaultDetails, SuspensionHint
from bogiemon.lab.robust.first_event import Tally, after_onset, tally_trend
from bogiemon.lab.robust.judge import JudgedRun
from tests.judgement.event_examples import event_of

NOISY = {"a3": ("noisy",)}


def event(time_s: float, details: EventDetails) -> Event:
    return Event.of(time_s, details, "test")


def sensor_fault(time_s: float, suspension: SuspensionHint | None = None) -> Event:
    return event(time_s, SensorFaultDetails(window_start_s=time_s - 120.0, window_end_s=time_s, rms_mps2=(1.0, 1.0, 1.0), problems=NOISY,
                                            suspension=suspension))  # fmt: skip


def other(time_s: float, kind: str) -> Event:
    """An event of a suspension kind: only its kind and time are counted."""
    return event_of(EventKind(kind), time_s)


def test_events_are_timed_from_the_onset_across_the_runs_and_those_before_it_left_out() -> None:
    late, confirmed = sensor_fault(50.0), other(300.0, "CONFIRMED")
    runs = [JudgedRun(events=(other(100.0, "SUSPECTED"),), loads=()), JudgedRun(events=(late, confirmed), loads=())]
    assert after_onset(150.0, [450.0, 450.0], runs) == [(350.0, late), (600.0, confirmed)]


def test_a_sensor_fault_first_is_alone_only_when_it_names_no_suspension() -> None:
    pair = SuspensionHint(("leading-left", "trailing-right"), 80.0, 67.0, "")
    t = Tally()
    tally_trend(t, [(10.0, sensor_fault(10.0)), (90.0, other(90.0, "CONFIRMED"))])
    tally_trend(t, [(20.0, sensor_fault(20.0, pair))])
    tally_trend(t, [(30.0, other(30.0, "SUSPECTED")), (40.0, sensor_fault(40.0)), (70.0, other(70.0, "CONFIRMED"))])
    tally_trend(t, [])
    assert (t.sequences, t.sensor_alone_first, t.sensor_first, t.sensor_any) == (4, 1, 2, 3)
    assert (t.confirmed, t.confirm_s) == (2, [90.0, 70.0])
