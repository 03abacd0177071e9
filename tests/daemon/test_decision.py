"""The suspension decision: k-of-n confirmation, hysteresis, and what the events carry."""

import dataclasses

import pytest

from bogiemon.daemon.decision import Decider, DecisionSettings, DecisionState, Level, Mode, Threshold
from bogiemon.daemon.events import EventKind, Severity
from bogiemon.detection import WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats

QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)
SETTINGS = DecisionSettings(
    thresholds={"full": {"i4_norm": Threshold(warning=0.1, alarm=0.2, center=0.05)}},
    confirm_k=3,
    confirm_n=5,
    clear_after_windows=2,
)


def window(i4_norm: float, t: float = 0.0) -> WindowIndicators:
    return WindowIndicators(
        start_s=t, end_s=t + 60, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=i4_norm,
        rms_mps2=(1.0, 1.0, 1.0), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=QUIET,
    )  # fmt: skip


def run(decider: Decider, values: list[float]) -> list[tuple[int, EventKind]]:
    out = []
    for i, v in enumerate(values):
        _, events = decider.update(window(v, t=10.0 * i), "full")
        out += [(i, e.kind) for e in events]
    return out


@pytest.mark.parametrize(
    ("value", "level"),
    [(0.05, Level.OK), (0.149, Level.OK), (0.151, Level.WARNING), (-0.05, Level.WARNING), (0.25, Level.ALARM), (-0.2, Level.ALARM)],
)
def test_levels_apply_to_the_deviation_from_the_center(value: float, level: Level) -> None:
    assert Threshold(warning=0.1, alarm=0.2, center=0.05).level(value) is level


def test_confirmation_needs_k_of_the_last_n_alarm_windows() -> None:
    # warning, alarm, ok, alarm, ok, alarm: the 3rd alarm within 5 judged windows confirms.
    events = run(Decider(SETTINGS, "cfg"), [0.16, 0.3, 0.0, 0.3, 0.0, 0.3])
    assert events == [(0, EventKind.SUSPECTED), (5, EventKind.CONFIRMED)]


def test_alarms_spread_wider_than_n_never_confirm() -> None:
    events = run(Decider(SETTINGS, "cfg"), [0.3, 0.16, 0.16, 0.16, 0.16, 0.3, 0.16, 0.16, 0.16, 0.16, 0.3])
    assert [kind for _, kind in events] == [EventKind.SUSPECTED]


def test_clearing_needs_consecutive_windows_below_warning() -> None:
    # Confirm, then warning-level windows (below alarm) keep the alarm: hysteresis.
    events = run(Decider(SETTINGS, "cfg"), [0.3, 0.3, 0.3, 0.16, 0.16, 0.0, 0.16, 0.0, 0.0])
    assert events == [(0, EventKind.SUSPECTED), (2, EventKind.CONFIRMED), (8, EventKind.CLEARED)]


def test_a_suspicion_alone_clears_too() -> None:
    assert run(Decider(SETTINGS, "cfg"), [0.16, 0.0, 0.0]) == [(0, EventKind.SUSPECTED), (2, EventKind.CLEARED)]


def test_confirmed_event_carries_the_indicators_that_fired_and_the_config_hash() -> None:
    decider = Decider(SETTINGS, "abc123")
    run(decider, [0.3, 0.3])
    _, events = decider.update(window(-0.4, t=20.0), "full")
    (event,) = events
    assert event.kind is EventKind.CONFIRMED and event.severity is Severity.ALARM
    assert event.indicators == {"i4_norm": -0.4}
    assert event.config_hash == "abc123"
    assert event.time_s == 80.0
    assert event.details["thresholds"] == {"i4_norm": {"center": 0.05, "warning": 0.1, "alarm": 0.2}}


def test_state_survives_a_round_trip_and_a_restart() -> None:
    first = Decider(SETTINGS, "cfg")
    run(first, [0.3, 0.3])
    saved = first.state.as_dict()
    second = Decider(SETTINGS, "cfg", DecisionState.from_dict(saved))
    assert second.state.mode is Mode.SUSPECTED
    _, events = second.update(window(0.3), "full")
    assert [e.kind for e in events] == [EventKind.CONFIRMED]


def test_nan_indicators_never_raise_a_level() -> None:
    assert Decider(SETTINGS, "cfg").judge(window(float("nan")), "full").worst is Level.OK


def test_unknown_load_state_is_an_error() -> None:
    with pytest.raises(KeyError, match="tare"):
        Decider(SETTINGS, "cfg").judge(window(0.0), "tare")


def test_settings_reject_k_above_n_and_unknown_indicators() -> None:
    with pytest.raises(ValueError, match="confirm_k"):
        dataclasses.replace(SETTINGS, confirm_k=6)
    with pytest.raises(ValueError, match="unknown indicators"):
        DecisionSettings(thresholds={"full": {"i5": Threshold(0.1, 0.2)}})
