"""The fused decision: the window score, the trend over many windows, their events and state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bogiemon.judgement.vocabulary import LoadState, Method, Mode
from bogiemon.judgement.decision import FUSED_SCORE, FUSED_TREND, Decider, DecisionSettings, DecisionState, Level
from bogiemon.judgement.events import ConfirmedDetails, EventDetails, EventKind, Trigger
from bogiemon.lab.modelfit import trend_runs
from bogiemon.judgement.models import Baseline, Levels
from bogiemon.judgement.rules import Threshold
from bogiemon.detection import BogieGeometry, Corner, WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats
from bogiemon.detection.features import COUPLING_FEATURES, COUPLING_NAMES, coupling_vector
from bogiemon.detection.spectra import BANDS_HZ, WindowSpectra

GEOMETRY = BogieGeometry()
QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)
HOP_S = 10.0
N = len(COUPLING_NAMES)


def spectra_with_couplings(x: np.ndarray) -> WindowSpectra:
    """Band spectra of a1, a2, a3 whose modal coherencies are the coupling vector x (unit modal powers)."""
    modal = np.tile(np.eye(3, dtype=np.complex128), (len(BANDS_HZ) - 1, 1, 1))
    for value, (_, i, j, band) in zip(x, COUPLING_FEATURES, strict=True):
        modal[band, i, j] = modal[band, j, i] = value
    s = GEOMETRY.sensor_matrix()  # channels = S modal
    return WindowSpectra(BANDS_HZ, np.einsum("ai,bij,cj->bac", s, modal, s))


def window(x: np.ndarray, t_s: float = 0.0) -> WindowIndicators:
    return WindowIndicators(
        start_s=t_s, end_s=t_s + 120.0, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=0,
        rms_mps2=(1.0, 1.0, 1.0), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=QUIET,
        spectra=spectra_with_couplings(x),
    )  # fmt: skip


# A baseline with center 0 and a spread of 0.1 in every coupling: z = 10 x.
LEVELS = Levels(warning=20.0, alarm=40.0, trend_warning=4.0, trend_alarm=8.0)
BASELINE = Baseline("calibrated", np.zeros(N), np.eye(N) * 10.0, LEVELS, trend_tau_s=600.0)


def settings(baseline: Baseline = BASELINE) -> DecisionSettings:
    return DecisionSettings({}, confirm_k=3, confirm_n=5, clear_after_windows=2, method=Method.FUSED, baselines={LoadState.FULL: baseline})


def feed(decider: Decider, xs: list[np.ndarray]) -> list[tuple[int, EventKind, EventDetails]]:
    out = []
    for i, x in enumerate(xs):
        _, events = decider.update(window(x, HOP_S * i), LoadState.FULL)
        out += [(i, e.kind, e.details) for e in events]
    return out


def test_the_designed_spectra_give_back_their_couplings() -> None:
    x = np.linspace(-0.3, 0.3, N)
    np.testing.assert_allclose(coupling_vector(spectra_with_couplings(x), GEOMETRY), x, atol=1e-12)


def test_the_window_score_is_the_squared_whitened_shift() -> None:
    x = np.zeros(N)
    x[0], x[5] = 0.5, -0.4
    judgement = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S).judge(window(x), LoadState.FULL)
    assert judgement.values[FUSED_SCORE] == pytest.approx(100 * (0.5**2 + 0.4**2))  # 41
    assert judgement.levels[FUSED_SCORE] is Level.ALARM
    assert judgement.shift is not None
    np.testing.assert_allclose(judgement.shift, 10 * x, atol=1e-9)
    assert judgement.alarm_ratio == pytest.approx(41.0 / 40.0)
    x[0] = 0.3  # 25: between the warning and the alarm level
    assert Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S).judge(window(x), LoadState.FULL).levels[FUSED_SCORE] is Level.WARNING


def test_three_alarm_windows_of_five_confirm_by_windows() -> None:
    # Score 74.5 per window: alarm; 3.5 healthy sd at 4-8 Hz, where the diagnosis reads the signs.
    gross = np.array([0.35 if band == 3 else 0.25 for *_, band in COUPLING_FEATURES])
    events = feed(Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S), [gross] * 3)
    kinds = [(i, k) for i, k, _ in events]
    assert kinds == [(1, EventKind.SUSPECTED), (2, EventKind.CONFIRMED)]
    details = events[-1][2]
    assert isinstance(details, ConfirmedDetails) and details.diagnosis is not None
    assert details.trigger is Trigger.WINDOWS
    assert details.diagnosis.corner == "leading-left or trailing-right"


def test_a_small_standing_shift_is_confirmed_by_the_trend_not_the_windows() -> None:
    # Score 12.5 per window: below the window warning (20); the trend converges to 12.5 > 8. The
    # 4-8 Hz couplings, which the diagnosis reads, carry a little more of it (3.4 sd of the trend's
    # healthy spread: a clear sign).
    small = np.array([0.15 if band == 3 else 0.1 for *_, band in COUPLING_FEATURES])
    decider = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    events = feed(decider, [small] * 200)
    confirmed = [(i, d) for i, k, d in events if k is EventKind.CONFIRMED]
    assert len(confirmed) == 1
    i, details = confirmed[0]
    weight = 1 - math.exp(-HOP_S / 600.0)
    # The first window at which 12.5 (1 - (1 - w)^(i+1))^2 reaches the trend alarm level of 8.
    expected = next(k for k in range(200) if 12.5 * (1 - (1 - weight) ** (k + 1)) ** 2 >= 8.0)
    assert i == expected
    assert isinstance(details, ConfirmedDetails) and details.diagnosis is not None
    assert details.trigger is Trigger.TREND
    assert details.diagnosis.corners == (Corner.LEADING_LEFT, Corner.TRAILING_RIGHT) and details.diagnosis.kind == "unknown"
    assert details.trend == pytest.approx(12.5 * (1 - (1 - weight) ** (i + 1)) ** 2)
    assert [k for _, k, _ in events][0] is EventKind.SUSPECTED


def test_healthy_scatter_around_the_center_never_alarms() -> None:
    rng = np.random.default_rng(1)
    xs = [rng.normal(0.0, 0.1, N) for _ in range(500)]  # z ~ N(0, I): score ~ chi2(10)
    events = feed(Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S), xs)
    assert not any(k is EventKind.CONFIRMED for _, k, _ in events)


def test_the_decider_trend_equals_the_fitting_rule() -> None:
    rng = np.random.default_rng(2)
    runs = [rng.normal(0.05, 0.1, (n, N)) for n in (7, 13, 4)]
    decider = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    got = [[decider.update(window(x), LoadState.FULL)[0].trend for x in run] for run in runs]
    want = trend_runs([10.0 * r for r in runs], HOP_S, tau_s=600.0)
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=1e-9)


def test_the_trend_survives_a_restart_and_restarts_with_a_new_baseline() -> None:
    small = np.full(N, 0.1)
    decider = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    feed(decider, [small] * 20)
    saved = DecisionState.from_dict(decider.state.as_dict())
    again = Decider(settings(), "cfg", saved, geometry=GEOMETRY, hop_s=HOP_S)
    before = decider.update(window(small), LoadState.FULL)[0].trend
    after = again.update(window(small), LoadState.FULL)[0].trend
    assert after == pytest.approx(before) and before > 0.5
    moved = Baseline("calibrated", np.full(N, 0.05), np.eye(N) * 10.0, LEVELS, trend_tau_s=600.0)
    fresh = Decider(settings(moved), "cfg", DecisionState.from_dict(decider.state.as_dict()), geometry=GEOMETRY, hop_s=HOP_S)
    weight = 1 - math.exp(-HOP_S / 600.0)
    # Started from zero against the new center: one window's weight of the shift (0.5 per coupling).
    assert fresh.update(window(small), LoadState.FULL)[0].trend == pytest.approx(N * (weight * 0.5) ** 2)


def test_a_cleared_alarm_needs_the_trend_back_below_its_warning() -> None:
    decider = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    feed(decider, [np.full(N, 0.1)] * 200)  # confirmed by the trend, which settles near 10
    assert decider.state.mode is Mode.CONFIRMED
    mean = np.asarray(decider.state.trend_mean["full"])
    start = float(mean @ mean)
    # Healthy windows again: every window is clean at once, the trend decays by (1 - w)^2 a window.
    events = feed(decider, [np.zeros(N)] * 400)
    cleared = [i for i, k, _ in events if k is EventKind.CLEARED]
    weight = 1 - math.exp(-HOP_S / 600.0)
    below = next(k for k in range(400) if start * (1 - weight) ** (2 * (k + 1)) < LEVELS.trend_warning)
    # Clearing needs clear_after_windows (2) clean windows in a row, the first of them `below`.
    assert cleared == [below + 1]


def test_the_confirmed_event_names_the_trend_and_its_levels() -> None:
    decider = Decider(settings(), "cfg", geometry=GEOMETRY, hop_s=HOP_S)
    events = feed(decider, [np.full(N, 0.25)] * 3)
    details = events[-1][2]
    assert isinstance(details, ConfirmedDetails)
    assert details.thresholds == {FUSED_SCORE: Threshold(warning=20.0, alarm=40.0), FUSED_TREND: Threshold(warning=4.0, alarm=8.0)}
