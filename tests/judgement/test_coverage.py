"""Never silent: running left unjudged for long is said (NOT_JUDGED), and its end (JUDGED_AGAIN)."""

from __future__ import annotations

from bogiemon.judgement.coverage import CoverageState, CoverageTracker
from bogiemon.judgement.events import EventKind, NotJudgedDetails, Severity
from bogiemon.detection import WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats

HOP_S = 10.0
UNLIKE = "between the commissioned load states (the wagon's line says neither, the load model full, the nearer state tare)"
QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)


def window(i: int) -> WindowIndicators:
    t = 1.7e9 + HOP_S * i
    return WindowIndicators(
        start_s=t, end_s=t + 120.0, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=0,
        rms_mps2=(1.0, 1.0, 1.0), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=QUIET,
    )  # fmt: skip


def feed(tracker: CoverageTracker, outcomes: str, start: int = 0) -> list[tuple[int, EventKind]]:
    """j: judged, u: running unlike the commissioning, g: gated or a sensor fault (neither)."""
    out = []
    for i, o in enumerate(outcomes, start=start):
        out += [(i, e.kind) for e in tracker.update(window(i), o == "j", UNLIKE if o == "u" else None)]
    return out


def test_two_hours_of_unfamiliar_running_raise_one_not_judged_and_a_judged_window_ends_it() -> None:
    tracker = CoverageTracker("cfg", HOP_S, 7200.0)
    events = feed(tracker, "j" + "u" * 719 + "u" * 100 + "j")
    assert events == [(720, EventKind.NOT_JUDGED), (820, EventKind.JUDGED_AGAIN)]
    assert tracker.state == CoverageState(0.0, False, window(820).end_s)


def test_standing_and_sensor_faults_add_no_unjudged_running() -> None:
    tracker = CoverageTracker("cfg", HOP_S, 7200.0)
    assert feed(tracker, ("u" * 100 + "g" * 1000) * 7) == []  # 700 unfamiliar windows: 7000 s, under 2 h
    assert tracker.state.unjudged_running_s == 7000.0
    assert feed(tracker, "u" * 20, start=7700)[0] == (7719, EventKind.NOT_JUDGED)


def test_the_not_judged_event_says_what_to_do_and_carries_the_figures() -> None:
    tracker = CoverageTracker("cfg", HOP_S, 600.0)
    feed(tracker, "j")
    (event,) = [e for i in range(1, 61) for e in tracker.update(window(i), False, UNLIKE)]
    assert event.kind is EventKind.NOT_JUDGED and event.severity is Severity.WARNING and event.time_s == window(60).end_s
    details = event.details
    assert isinstance(details, NotJudgedDetails)
    assert details.message.startswith("not judged for the last 0.2 h of running: the wagon is unlike its commissioning")
    assert "commission it again" in details.message
    assert details.unjudged_running_s == 600.0 and details.last_judged_s == window(0).end_s
    assert details.unlike == UNLIKE and (details.window_start_s, details.window_end_s) == (window(60).start_s, window(60).end_s)


def test_the_state_survives_a_restart_and_an_old_state_starts_empty() -> None:
    tracker = CoverageTracker("cfg", HOP_S, 7200.0)
    feed(tracker, "j" + "u" * 800)
    again = CoverageTracker("cfg", HOP_S, 7200.0, CoverageState.from_dict(tracker.state.as_dict()))
    assert again.state == tracker.state and again.state.reported
    assert feed(again, "u" * 5) == []  # reported once, not again after the restart
    assert CoverageState.from_dict(None) == CoverageState()
