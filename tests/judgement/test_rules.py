"""The daemon's decision rules (judgement/rules.py), which the lab calls too: each against a direct reference."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import BogieGeometry
from bogiemon.judgement.decision import Decider, DecisionSettings
from bogiemon.judgement.events import EventKind
from bogiemon.judgement.rules import Level, Threshold, first_confirmation, fit_threshold, level_of, suspicion_k, sustained_level, two_sided_z
from bogiemon.detection import WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats

finite = st.floats(-1e3, 1e3, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(st.lists(finite, min_size=1, max_size=300), st.sampled_from([1e-2, 5e-2]), st.sampled_from([1e-4, 1e-3]))
def test_fit_threshold_is_the_stated_rule(values: list[float], warning_rate: float, alarm_rate: float) -> None:
    x = np.array(values)
    d = np.abs(x - np.median(x))
    sigma = 1.4826 * np.median(d)
    warning = max(stats.norm.isf(warning_rate / 2) * sigma, np.quantile(d, 1 - warning_rate), np.finfo(float).tiny)
    alarm = max(stats.norm.isf(alarm_rate / 2) * sigma, 1.1 * d.max(), warning)
    fit = fit_threshold(x, warning_rate, alarm_rate)
    assert (fit.center, fit.warning, fit.alarm, fit.robust_sigma, fit.max_deviation, fit.n_windows) == pytest.approx(
        (np.median(x), warning, alarm, sigma, d.max(), len(x)), rel=1e-12, abs=1e-300
    )
    assert isinstance(fit, Threshold) and fit.level(fit.center) is Level.OK


@given(st.floats(1e-12, 0.9))
def test_two_sided_z_is_scipys_normal_quantile(rate: float) -> None:
    assert two_sided_z(rate) == pytest.approx(stats.norm.isf(rate / 2), rel=1e-12)


def test_fit_threshold_refuses_no_values() -> None:
    with pytest.raises(ValueError, match="at least one healthy value"):
        fit_threshold([], 1e-2, 1e-4)


@given(st.lists(st.floats(0, 10) | st.just(math.nan), min_size=1, max_size=50), st.floats(0.1, 5), st.floats(0, 5))
def test_the_level_of_an_array_is_the_level_of_each_value(deviations: list[float], warning: float, gap: float) -> None:
    alarm = warning + gap
    expected = [Level.ALARM if d >= alarm else Level.WARNING if d >= warning else Level.OK for d in deviations]
    assert [Level(int(v)) for v in level_of(np.array(deviations), warning, alarm)] == expected
    assert [Level.of(d, warning, alarm) for d in deviations] == expected


def _first_confirmation_reference(alarms: list[bool], k: int, n: int) -> int | None:
    for i in range(len(alarms)):
        if sum(alarms[max(0, i - n + 1) : i + 1]) >= k:
            return i
    return None


@given(st.lists(st.booleans(), max_size=40), st.integers(1, 6), st.integers(0, 4))
def test_first_confirmation_counts_k_alarms_among_the_last_n_windows(alarms: list[bool], k: int, extra: int) -> None:
    assert first_confirmation(alarms, k, k + extra) == _first_confirmation_reference(alarms, k, k + extra)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(0, 100, allow_nan=False), min_size=1, max_size=30), st.integers(1, 4), st.integers(0, 3))
def test_the_sustained_level_is_the_highest_alarm_level_the_rule_confirms_at(scores: list[float], k: int, extra: int) -> None:
    n = k + extra
    level = sustained_level(scores, k, n)
    x = np.array(scores)
    if len(x) < k:
        assert level == -math.inf
        return
    assert first_confirmation(x >= level, k, n) is not None
    assert first_confirmation(x >= np.nextafter(level, math.inf), k, n) is None


QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)


def _window(i4_norm: float, t: float) -> WindowIndicators:
    return WindowIndicators(
        start_s=t, end_s=t + 60, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=i4_norm,
        rms_mps2=(1.0, 1.0, 1.0), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=QUIET,
    )  # fmt: skip


@settings(max_examples=200, deadline=None)
@given(st.lists(st.booleans(), min_size=1, max_size=40), st.integers(1, 6), st.integers(0, 4))
def test_first_confirmation_of_a_run_is_where_the_deciders_state_machine_confirms(alarms: list[bool], k: int, extra: int) -> None:
    n = k + extra
    # The Decider also clears its history after clear_after_windows clean windows; with
    # clear_after_windows >= n (the defaults: 6 and 5) that never drops an alarm still in the last n.
    decision = DecisionSettings({LoadState.FULL: {"i4_norm": Threshold(warning=0.5, alarm=0.5)}}, k, n, clear_after_windows=n)
    decider = Decider(decision, "test", geometry=BogieGeometry(), hop_s=10.0)
    confirmed_at = None
    for i, alarm in enumerate(alarms):
        _, events = decider.update(_window(1.0 if alarm else 0.0, 10.0 * i), LoadState.FULL)
        if confirmed_at is None and any(e.kind is EventKind.CONFIRMED for e in events):
            confirmed_at = i
    assert first_confirmation(alarms, k, n) == confirmed_at


def test_a_suspicion_asks_one_window_fewer_than_a_confirmation_and_at_least_one() -> None:
    assert [suspicion_k(k) for k in (1, 2, 3, 5)] == [1, 1, 2, 4]
