"""The fleet plot's broken time axis (fleet/svg.py: broken_axis, BrokenAxis, axis_ticks, day_labels),
checked against a direct reference written as a walk along the stretches."""

from __future__ import annotations

import math
from datetime import UTC, datetime

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.fleet import svg

LEFT_PX, RIGHT_PX = 58.0, 986.0
MAX_IDLE_S, GAP_PX = 600.0, 24.0


def _utc(year: int, month: int, day: int, hour: int = 0, minute: int = 0) -> float:
    return datetime(year, month, day, hour, minute, tzinfo=UTC).timestamp()


def reference_axis(times: list[float], left_px: float, right_px: float, max_idle_s: float, gap_px: float, share: float = 1 / 3, min_span_s: float = 60.0):
    """The stretches, the gap width, the scale and time -> pixel as a plain walk: obviously right, slow."""
    ts = sorted(times)
    stretches = [[ts[0], ts[0]]]
    for t in ts[1:]:
        if t - stretches[-1][1] > max_idle_s:
            stretches.append([t, t])
        else:
            stretches[-1][1] = t
    data_s = sum(b - a for a, b in stretches)
    if data_s < min_span_s:
        stretches[0][0] -= (min_span_s - data_s) / 2
        stretches[-1][1] += (min_span_s - data_s) / 2
        data_s = min_span_s
    n_gaps = len(stretches) - 1
    gap = min(gap_px, share * (right_px - left_px) / n_gaps) if n_gaps else 0.0
    scale = (right_px - left_px - n_gaps * gap) / data_s

    def px(t: float) -> float:
        x = left_px
        for k, (a, b) in enumerate(stretches):
            if t <= b or k == len(stretches) - 1:
                return x + (t - a) * scale  # in this stretch (or before the first, after the last)
            x += (b - a) * scale
            following = stretches[k + 1][0]
            if t < following:
                return x + (t - b) / (following - b) * gap  # in the gap after it
            x += gap
        raise AssertionError("unreachable")

    return stretches, gap, scale, px


@st.composite
def recorded_times(draw) -> list[float]:
    """Window times of a wagon: runs at a few seconds' hop, pauses under the idle limit, nights over it, repeats."""
    start_s = draw(st.floats(1.7e9, 1.8e9))
    steps = draw(st.lists(st.one_of(st.just(0.0), st.floats(1.0, 60.0), st.floats(120.0, 590.0), st.floats(610.0, 3 * 86400.0)), max_size=40))
    times = (start_s + np.concatenate(([0.0], np.cumsum(steps)))).tolist()
    return draw(st.permutations(times))  # broken_axis takes them in any order


def _gap_middles(stretches: list[list[float]]) -> list[float]:
    return [(b + a2) / 2 for (_, b), (a2, _) in zip(stretches[:-1], stretches[1:], strict=True)]


@settings(max_examples=150, deadline=None)
@given(recorded_times(), st.floats(-2000.0, 2000.0))
def test_the_axis_maps_every_time_as_the_direct_reference_does(times: list[float], beyond_s: float) -> None:
    axis = svg.broken_axis(np.array(times), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    stretches, gap, scale, px = reference_axis(times, LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    assert axis.start_s.tolist() == pytest.approx([a for a, _ in stretches], abs=1e-6)
    assert axis.end_s.tolist() == pytest.approx([b for _, b in stretches], abs=1e-6)
    assert axis.gap_px == pytest.approx(gap) and axis.px_per_s == pytest.approx(scale, rel=1e-12)
    queries = times + _gap_middles(stretches) + [stretches[0][0] - abs(beyond_s), stretches[-1][1] + abs(beyond_s)]
    assert axis.px(np.array(queries)).tolist() == pytest.approx([px(t) for t in queries], abs=1e-6)


@settings(max_examples=150, deadline=None)
@given(recorded_times(), st.lists(st.floats(0.0, 1.0), min_size=2, max_size=50))
def test_the_axis_is_monotonic_and_its_inverse_undoes_it(times: list[float], fractions: list[float]) -> None:
    axis = svg.broken_axis(np.array(times), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    lo_s, hi_s = float(axis.start_s[0]) - 100.0, float(axis.end_s[-1]) + 100.0
    queries = np.sort(lo_s + np.array(fractions) * (hi_s - lo_s))
    x = axis.px(queries)
    assert np.all(np.diff(x) >= -1e-9)
    assert axis.time_s(x) == pytest.approx(queries, abs=1e-4)
    columns = np.linspace(LEFT_PX, RIGHT_PX, 97)
    assert axis.px(axis.time_s(columns)) == pytest.approx(columns, abs=1e-4)  # via a time near 1.7e9 s: good to 2e-7 s


@settings(max_examples=150, deadline=None)
@given(recorded_times())
def test_stretches_keep_one_scale_gaps_get_the_fixed_width_and_the_axis_fills_the_plot(times: list[float]) -> None:
    axis = svg.broken_axis(np.array(times), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    start_px, end_px = axis.px(axis.start_s), axis.px(axis.end_s)
    durations_s = axis.end_s - axis.start_s
    assert end_px - start_px == pytest.approx(durations_s * axis.px_per_s, abs=1e-6)  # one scale for every stretch
    n_gaps = axis.start_s.size - 1
    expected_gap_px = min(GAP_PX, (RIGHT_PX - LEFT_PX) / 3 / n_gaps) if n_gaps else 0.0
    assert start_px[1:] - end_px[:-1] == pytest.approx(np.full(n_gaps, expected_gap_px), abs=1e-6)
    assert all(g.right_px - g.left_px == pytest.approx(expected_gap_px) and g.duration_s > MAX_IDLE_S for g in axis.gaps)
    # abs 1e-4: a padded end is a float near 1.7e9 s, good to 2e-7 s, at up to 15 px/s
    assert start_px[0] == pytest.approx(LEFT_PX, abs=1e-9) and end_px[-1] == pytest.approx(RIGHT_PX, abs=1e-4)


@settings(max_examples=150, deadline=None)
@given(recorded_times())
def test_a_time_on_the_data_maps_exactly_and_one_in_a_gap_snaps_to_the_gaps_start(times: list[float]) -> None:
    axis = svg.broken_axis(np.array(times), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    stretches, _, _, px = reference_axis(times, LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    on_data = np.array(times)
    assert axis.snap(on_data).tolist() == on_data.tolist()  # exactly: an event at a window's end stays there
    assert axis.px(on_data).tolist() == pytest.approx([px(t) for t in times], abs=1e-6)
    middles = _gap_middles(stretches)
    assert axis.snap(np.array(middles)).tolist() == pytest.approx([b for _, b in stretches[:-1]], abs=1e-6)
    outside = np.array([stretches[0][0] - 50.0, stretches[-1][1] + 50.0])
    assert axis.snap(outside).tolist() == pytest.approx([stretches[0][0], stretches[-1][1]], abs=1e-6)


def test_many_gaps_share_a_third_of_the_width_so_the_runs_keep_the_rest() -> None:
    times = np.concatenate([_utc(2026, 11, 1) + day * 86400.0 + np.arange(0.0, 600.0, 10.0) for day in range(300)])
    axis = svg.broken_axis(times, LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    assert len(axis.gaps) == 299 and axis.gap_px == pytest.approx((RIGHT_PX - LEFT_PX) / 3 / 299)
    assert float(np.sum(axis.end_s - axis.start_s)) * axis.px_per_s == pytest.approx((RIGHT_PX - LEFT_PX) * 2 / 3)


def test_a_lone_window_is_centred_on_a_minute_wide_axis() -> None:
    t = _utc(2026, 11, 30, 6, 2)
    axis = svg.broken_axis(np.array([t]), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    assert float(axis.px(t)) == pytest.approx((LEFT_PX + RIGHT_PX) / 2)
    assert axis.px_per_s == pytest.approx((RIGHT_PX - LEFT_PX) / 60.0) and axis.gaps == []


# --- the labels ---------------------------------------------------------------------------------


def _two_days_of_two_runs() -> np.ndarray:
    # The report fixture's shape: runs from 06:02 to 07:01:50 and 11:02 to 12:01:50 UTC on two days.
    runs = [_utc(2026, 11, 30, 6, 2), _utc(2026, 11, 30, 11, 2), _utc(2026, 12, 1, 6, 2), _utc(2026, 12, 1, 11, 2)]
    return np.concatenate([start + np.arange(360) * 10.0 for start in runs])


def test_the_fixtures_axis_has_round_ticks_on_each_run_dates_at_each_day_and_its_gaps_lengths() -> None:
    axis = svg.broken_axis(_two_days_of_two_runs(), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    ticks = svg.axis_ticks(axis)
    assert [label for _, label in ticks] == ["06:30", "07:00", "11:30", "12:00"] * 2
    assert all(t % 1800 == 0 for t, _ in ticks)
    assert svg.day_labels(axis) == [(_utc(2026, 11, 30, 6, 2), "2026-11-30"), (_utc(2026, 12, 1, 6, 2), "2026-12-01")]
    assert [svg.duration_label(g.duration_s) for g in axis.gaps] == ["4 h", "18 h", "4 h"]


def test_a_run_across_midnight_has_its_date_at_midnight_within_the_run() -> None:
    times = np.arange(_utc(2026, 11, 30, 23, 30), _utc(2026, 12, 1, 0, 30), 10.0)
    axis = svg.broken_axis(times, LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    assert svg.day_starts(axis) == [_utc(2026, 11, 30, 23, 30), _utc(2026, 12, 1)]


@settings(max_examples=100, deadline=None)
@given(recorded_times())
def test_ticks_fall_on_round_utc_times_on_the_data_with_labels_that_do_not_overlap(times: list[float]) -> None:
    axis = svg.broken_axis(np.array(times), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    ticks = svg.axis_ticks(axis)
    ends_px = -math.inf
    for t, label in ticks:
        assert t % 10 == 0 and float(axis.snap(t)) == t  # round, and on a data stretch
        moment = datetime.fromtimestamp(t, UTC)
        assert label in (moment.strftime("%H:%M"), moment.strftime("%H:%M:%S"), moment.strftime("%m-%d"))
        x, half = float(axis.px(t)), len(label) * svg.CHAR_PX / 2
        assert x - half >= ends_px + 6.0
        ends_px = x + half
    days = svg.day_starts(axis)
    # One per UTC day the stretches touch (a lone window's padding may reach over a midnight).
    touched = {d for a, b in zip(axis.start_s.tolist(), axis.end_s.tolist(), strict=True) for d in range(math.floor(a / 86400), math.floor(b / 86400) + 1)}
    assert [math.floor(t / 86400) for t in days] == sorted(touched)
    assert all(float(axis.snap(t)) == t for t in days)


@pytest.mark.parametrize(
    ("duration_s", "label"),
    [(610.0, "10 min"), (5120.0, "85 min"), (6000.0, "1.7 h"), (4 * 3600.0 + 10, "4 h"), (14 * 3600.0, "14 h"), (2.5 * 86400, "2.5 d"), (3 * 86400.0, "3 d")],
)
def test_a_gaps_length_is_written_in_its_natural_unit(duration_s: float, label: str) -> None:
    assert svg.duration_label(duration_s) == label
