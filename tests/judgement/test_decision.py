"""The suspension decision: k-of-n confirmation, hysteresis, and what the events carry."""

import dataclasses

import pytest

from bogiemon.judgement.vocabulary import LoadState
from bogiemon.judgement.decision import Decider, DecisionSettings, DecisionState, Level, Mode, Threshold
from bogiemon.judgement.events import ConfirmedDetails, EventKind, KOfN, Severity, SuspectedDetails, Trigger
from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats

GEOMETRY = BogieGeometry()
HOP_S = 10.0
QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)
SETTINGS = DecisionSettings(
    thresholds={LoadState.FULL: {"i4_norm": Threshold(warning=0.1, alarm=0.2, center=0.05)}},
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
        _, events = decider.update(window(v, t=10.0 * i), LoadState.FULL)
        out += [(i, e.kind) for e in events]
    return out


@pytest.mark.parametrize(
    ("value", "level"),
    [(0.05, Level.OK), (0.149, Level.OK), (0.151, Level.WARNING), (-0.05, Level.WARNING), (0.25, Level.ALARM), (-0.2, Level.ALARM)],
)
def test_levels_apply_to_the_deviation_from_the_center(value: float, level: Level) -> None:
    assert Threshold(warning=0.1, alarm=0.2, center=0.05).level(value) is level


def test_confirmation_needs_k_of_the_last_n_alarm_windows() -> None:
    # warning, alarm (2 of 2 at warning or above: suspected), ok, alarm, ok, alarm (the 3rd alarm
    # within 5 judged windows: confirmed).
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.16, 0.3, 0.0, 0.3, 0.0, 0.3])
    assert events == [(1, EventKind.SUSPECTED), (5, EventKind.CONFIRMED)]


def test_a_gross_fault_is_suspected_a_window_before_it_is_confirmed() -> None:
    assert run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.0, 0.3, 0.3, 0.3]) == [(2, EventKind.SUSPECTED), (3, EventKind.CONFIRMED)]


def test_alarms_spread_wider_than_n_never_confirm() -> None:
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.3, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.3])
    assert events == []


def test_suspicion_needs_k_minus_one_of_the_last_n_windows_at_warning() -> None:
    # One warning window within five is the healthy wagon's scatter; a second within five is a suspicion.
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.16, 0.0, 0.0, 0.0, 0.0, 0.16, 0.0, 0.0, 0.0, 0.16])
    assert events == [(9, EventKind.SUSPECTED)]  # windows 5 and 9: two within five


def test_single_warning_windows_never_raise_a_suspicion() -> None:
    assert run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.16, 0.0, 0.0, 0.0, 0.0, 0.16, 0.0, 0.0, 0.0, 0.0, 0.16]) == []


def test_with_one_window_to_confirm_one_window_suspects() -> None:
    settings = dataclasses.replace(SETTINGS, confirm_k=1, confirm_n=1)
    assert run(Decider(settings, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.0, 0.16, 0.3]) == [(1, EventKind.SUSPECTED), (2, EventKind.CONFIRMED)]


def test_the_suspicion_states_how_many_windows_raised_it() -> None:
    decider = Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    run(decider, [0.16, 0.0])
    _, events = decider.update(window(0.16, t=20.0), LoadState.FULL)
    (event,) = events
    assert event.kind is EventKind.SUSPECTED and isinstance(event.details, SuspectedDetails) and event.details.warning_windows == KOfN(2, 3)


def test_clearing_needs_consecutive_windows_below_warning() -> None:
    # Confirm, then warning-level windows (below alarm) keep the alarm: hysteresis.
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.3, 0.3, 0.3, 0.16, 0.16, 0.0, 0.16, 0.0, 0.0])
    assert events == [(1, EventKind.SUSPECTED), (2, EventKind.CONFIRMED), (8, EventKind.CLEARED)]


def test_a_suspicion_alone_clears_too() -> None:
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.16, 0.16, 0.0, 0.0])
    assert events == [(1, EventKind.SUSPECTED), (3, EventKind.CLEARED)]


def test_a_cleared_suspicion_needs_new_warning_windows_again() -> None:
    events = run(Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S), [0.16, 0.16, 0.0, 0.0, 0.16, 0.0, 0.16])
    assert events == [(1, EventKind.SUSPECTED), (3, EventKind.CLEARED), (6, EventKind.SUSPECTED)]


def test_confirmed_event_carries_the_indicators_that_fired_and_the_config_hash() -> None:
    decider = Decider(SETTINGS, "abc123", geometry=GEOMETRY, hop_s=HOP_S)
    run(decider, [0.3, 0.3])
    _, events = decider.update(window(-0.4, t=20.0), LoadState.FULL)
    (event,) = events
    assert event.kind is EventKind.CONFIRMED and event.severity is Severity.ALARM
    assert event.indicators == {"i4_norm": -0.4}
    assert event.config_hash == "abc123"
    assert event.time_s == 80.0
    details = event.details
    assert isinstance(details, ConfirmedDetails)
    assert details.thresholds == {"i4_norm": Threshold(warning=0.1, alarm=0.2, center=0.05)}
    assert details.alarm_windows == KOfN(3, 3) and details.trigger is Trigger.WINDOWS
    assert (details.window_start_s, details.window_end_s, details.load) == (20.0, 80.0, LoadState.FULL)


def test_state_survives_a_round_trip_and_a_restart() -> None:
    first = Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    run(first, [0.16, 0.16, 0.0, 0.3, 0.3])
    saved = first.state.as_dict()
    second = Decider(SETTINGS, "cfg", DecisionState.from_dict(saved), geometry=GEOMETRY, hop_s=HOP_S)
    assert second.state.mode is Mode.SUSPECTED
    _, events = second.update(window(0.3), LoadState.FULL)
    assert [e.kind for e in events] == [EventKind.CONFIRMED]


def test_a_state_saved_before_the_warning_history_loads_with_none() -> None:
    saved = Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S).state.as_dict()
    del saved["recent_warnings"]
    state = DecisionState.from_dict(saved)
    assert list(state.recent_warnings) == [] and state.mode is Mode.NORMAL


def test_nan_indicators_never_raise_a_level() -> None:
    assert Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S).judge(window(float("nan")), LoadState.FULL).worst is Level.OK


def test_unknown_load_state_is_an_error() -> None:
    with pytest.raises(KeyError, match="tare"):
        Decider(SETTINGS, "cfg", geometry=GEOMETRY, hop_s=HOP_S).judge(window(0.0), LoadState.TARE)


def test_settings_reject_k_above_n_and_unknown_indicators() -> None:
    with pytest.raises(ValueError, match="confirm_k"):
        dataclasses.replace(SETTINGS, confirm_k=6)
    with pytest.raises(ValueError, match="unknown indicators"):
        DecisionSettings(thresholds={LoadState.FULL: {"i5": Threshold(0.1, 0.2)}})
