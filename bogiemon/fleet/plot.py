"""A wagon's plot on the fleet's page: the fused score and the trend over its running time.

Two log-scale panels over one broken time axis (fleet/svg.py: idle stretches cut to a marked
band), the levels in force as dashed lines, the decision's mode as a strip, the events as marks.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from html import escape
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.vocabulary import Mode
from bogiemon.fleet import svg
from bogiemon.fleet.judged_files import EMPTY_SERIES, Series, WagonPage

if TYPE_CHECKING:
    from bogiemon.daemon.messages import EventMessage

# The colours a keeper learns once: the badges, the event markers and the plot lines.
STATE_COLOURS = {"CONFIRMED": "#c62828", "SUSPECTED": "#ffb300", "SENSOR_FAULT": "#7b1fa2", "NOT_JUDGED": "#d84315", "NORMAL": "#2e7d32", "NO_DATA": "#757575"}
EVENT_COLOURS = {
    "SUSPECTED": "#e69500", "CONFIRMED": "#c62828", "CLEARED": "#2e7d32", "SENSOR_FAULT": "#7b1fa2", "SENSOR_CLEARED": "#546e7a",
    "NOT_JUDGED": "#d84315", "JUDGED_AGAIN": "#546e7a",
}  # fmt: skip
EVENT_TEXT_COLOURS = {**EVENT_COLOURS, "SUSPECTED": "#b36b00"}  # the amber of a line is too light for text
SCORE_COLOUR, TREND_COLOUR = "#1565c0", "#00838f"
WARNING_COLOUR, ALARM_COLOUR = "#e69500", "#c62828"

MAX_POINTS_PER_PANEL = 1500  # a line's points after decimation: about 1.6 per pixel column
MAX_GAP_HOPS = 3.5  # consecutive drawn windows further apart (in hops) are a gap: the line breaks
DEFAULT_HOP_S = 10.0  # the daemon's default hop, for a series too short to measure its own

# The plot's layout, in viewBox pixels.
W_PX, LEFT_PX, RIGHT_PX = 1000.0, 58.0, 986.0
LANES_PX = (12.0, 24.0, 36.0)  # the baselines of the event labels' rows
MODE_TOP_PX, MODE_BOTTOM_PX = 42.0, 48.0
SCORE_TOP_PX, SCORE_BOTTOM_PX = 50.0, 210.0
GAP_LABEL_PX = 223.5  # the baseline of the gaps' lengths, in the free strip between the panels
TREND_TOP_PX, TREND_BOTTOM_PX = 230.0, 330.0
TICKS_PX, DATES_PX = 344.0, 358.0  # the baselines of the time labels and of the dates under them
H_PX = 364.0
# The broken time axis: an idle stretch longer than MAX_IDLE_S (a night, a stop between runs) is
# cut to GAP_PX, enough for its break mark and mostly for its length; shorter pauses keep their
# true width, so the runs of a day still read as a day.
MAX_IDLE_S = 600.0
GAP_PX = 24.0
GAP_CHAR_PX = 5.7  # a character of the gaps' 10 px labels


@dataclass
class _Plot:
    parts: list[str] = field(default_factory=list)
    points: int = 0


def _hop_s(time_s: NDArray[np.float64]) -> float:
    if time_s.size < 2:
        return DEFAULT_HOP_S
    diffs = np.diff(time_s)
    diffs = diffs[diffs > 0]
    return float(np.median(diffs)) if diffs.size else DEFAULT_HOP_S


def _panel(plot: _Plot, series: Series, names: tuple[str, str, str], top_px: float, bottom_px: float, axis: svg.BrokenAxis, label: str) -> None:
    value_name, warning_name, alarm_name = names
    values: NDArray[np.float64] = getattr(series, value_name)
    judged = series.judged & np.isfinite(values)
    time_s = series.time_s[judged]
    v = values[judged]
    warning = getattr(series, warning_name)[judged]
    alarm = getattr(series, alarm_name)[judged]
    levels = np.concatenate((warning[np.isfinite(warning)], alarm[np.isfinite(alarm)]))
    lo, hi = svg.log_range(v, [float(levels.min()), float(levels.max())] if levels.size else [])
    p = plot.parts
    for value, tick in svg.decade_ticks(lo, hi):
        y = float(svg.log_px(np.array([value]), lo, hi, top_px, bottom_px)[0])
        p.append(svg.line(LEFT_PX, y, RIGHT_PX, y, "g"))
        p.append(svg.text(LEFT_PX - 4, y + 4, tick, anchor="end"))
    p.append(svg.rect(LEFT_PX, top_px, RIGHT_PX - LEFT_PX, bottom_px - top_px, "ax"))
    _breaks(plot, axis, top_px, bottom_px)
    p.append(svg.text(LEFT_PX + 6, top_px + 13, label))
    if time_s.size == 0:
        p.append(svg.text((LEFT_PX + RIGHT_PX) / 2, (top_px + bottom_px) / 2, "no judged windows", anchor="middle"))
        return
    segments = svg.gap_segments(time_s, MAX_GAP_HOPS * _hop_s(series.time_s))
    n_segments = int(segments[-1]) + 1
    buckets = max(MAX_POINTS_PER_PANEL - n_segments, 100)
    # The buckets are columns of the drawn (broken) axis, not stretches of time: a run keeps its
    # share of the points whatever the nights around it.
    dx, dv, ds = svg.decimate_max(axis.px(time_s), v, segments, LEFT_PX, RIGHT_PX, buckets)
    for cls, level in (("lw", warning), ("la", alarm)):
        ok = np.isfinite(level)
        keep = svg.run_ends(level[ok], segments[ok])
        lt, lv, ls = time_s[ok][keep], level[ok][keep], segments[ok][keep]
        d = svg.path_d(axis.px(lt), svg.log_px(lv, lo, hi, top_px, bottom_px), ls)
        if d:
            p.append(f'<path class="{cls}" d="{d}"/>')
    p.append(f'<path class="{"s" if value_name == "score" else "t"}" d="{svg.path_d(dx, svg.log_px(dv, lo, hi, top_px, bottom_px), ds)}"/>')
    plot.points += int(dx.size)


def _breaks(plot: _Plot, axis: svg.BrokenAxis, top_px: float, bottom_px: float) -> None:
    # Each cut gap as a shaded band over the panel, interrupting its frame, with a double slash
    # across the frame's top and bottom edges (left out where many gaps leave too little room).
    for gap in axis.gaps:
        width = gap.right_px - gap.left_px
        tip = f"no data for {svg.duration_label(gap.duration_s)}: {svg.utc_label(gap.start_s)} to {svg.utc_label(gap.end_s)} (cut from the axis)"
        plot.parts.append(svg.rect(gap.left_px, top_px - 1, width, bottom_px - top_px + 2, "brk", tip))
        if width < 8.0:
            continue
        mid = (gap.left_px + gap.right_px) / 2
        for y in (top_px, bottom_px):
            for dx in (-2.5, 2.5):
                plot.parts.append(svg.line(mid + dx - 2.5, y + 4, mid + dx + 2.5, y - 4, "bk"))


def _time_axis(plot: _Plot, axis: svg.BrokenAxis) -> None:
    # Ticks at round UTC times on the data stretches, each day's date at its first data, and the
    # length of each cut gap where it fits.
    p = plot.parts
    for t, label in svg.axis_ticks(axis):
        x = float(axis.px(t))
        half = svg.CHAR_PX * len(label) / 2
        if x - half < LEFT_PX - 2 or x + half > W_PX:  # into the "UTC" on the left, or off the plot
            continue
        p.append(svg.line(x, SCORE_TOP_PX, x, TREND_BOTTOM_PX, "g"))
        p.append(svg.text(x, TICKS_PX, label, anchor="middle"))
    starts_px = set(np.round(axis.start_px, 6).tolist())
    for t, label in svg.day_labels(axis):
        x = float(axis.px(t))
        if round(x, 6) not in starts_px:  # a midnight within a run; after a cut night the band is the boundary
            p.append(svg.line(x, SCORE_TOP_PX, x, SCORE_BOTTOM_PX, "gd"))
            p.append(svg.line(x, TREND_TOP_PX, x, TREND_BOTTOM_PX, "gd"))
        p.append(svg.line(x, TREND_BOTTOM_PX, x, DATES_PX - 10, "gd"))
        p.append(svg.text(min(x + 2, W_PX - svg.CHAR_PX * len(label)), DATES_PX, label, cls="dl"))  # a last day near the end stays on the plot
    end_px = -math.inf
    for gap in axis.gaps:
        text = svg.duration_label(gap.duration_s)
        width = GAP_CHAR_PX * len(text)
        mid = (gap.left_px + gap.right_px) / 2
        if mid - width / 2 >= max(end_px + 4, LEFT_PX) and mid + width / 2 <= RIGHT_PX:
            p.append(svg.text(mid, GAP_LABEL_PX, text, cls="gl", anchor="middle"))
            end_px = mid + width / 2
    p.append(svg.text(LEFT_PX - 4, TICKS_PX, "UTC", anchor="end"))


def _mode_strip(plot: _Plot, series: Series, axis: svg.BrokenAxis) -> None:
    # The decision's mode after each window, as a thin band: when the wagon was suspected or in alarm.
    if series.time_s.size == 0:
        return
    x = axis.px(series.time_s)
    segments = svg.gap_segments(series.time_s, MAX_GAP_HOPS * _hop_s(series.time_s))
    change = np.ones(x.size, dtype=bool)
    change[1:] = (series.mode[1:] != series.mode[:-1]) | (segments[1:] != segments[:-1])
    starts = np.flatnonzero(change)
    ends = np.concatenate((starts[1:] - 1, [x.size - 1]))
    runs: list[list[Any]] = []  # [mode, x0, x1]
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        mode = str(series.mode[s])
        if mode not in (Mode.SUSPECTED, Mode.CONFIRMED):
            continue
        x0, x1 = float(x[s]), max(float(x[e]), float(x[s]) + 1.0)
        if runs and runs[-1][0] == mode and x0 - runs[-1][2] < 1.0:
            runs[-1][2] = x1  # within a pixel of the last run of the same mode: one rectangle
        else:
            runs.append([mode, x0, x1])
    for mode, x0, x1 in runs:
        plot.parts.append(svg.rect(x0, MODE_TOP_PX, x1 - x0, MODE_BOTTOM_PX - MODE_TOP_PX, f"m-{mode}"))


def _event_marks(plot: _Plot, events: Sequence[EventMessage], axis: svg.BrokenAxis) -> None:
    lane_end = [-1e9] * len(LANES_PX)
    for ev in events:
        # At its true time: an event is a window's end, so it lies on the data; one that does not
        # (a stray line) is drawn at the start of the gap it falls in, never inside a cut band.
        x = float(axis.px(axis.snap(ev.time_s)))
        tip = f"{ev.kind} {svg.utc_label(ev.time_s)} (seq {ev.seq})"
        plot.parts.append(svg.line(x, MODE_TOP_PX, x, TREND_BOTTOM_PX, f"e e-{ev.kind}", tip))
        # A label in the first row where it does not overlap the one before; none if no row is free
        # (the line and its tooltip still say it).
        width = svg.CHAR_PX * len(ev.kind)
        anchor_right = x + width > RIGHT_PX
        start, end = (x - width - 2, x) if anchor_right else (x + 2, x + 2 + width)
        for lane, end_before in enumerate(lane_end):
            if start > end_before + 4:
                lane_end[lane] = end
                plot.parts.append(svg.text(x - 2 if anchor_right else x + 2, LANES_PX[lane], ev.kind, cls=f"el el-{ev.kind}", anchor="end" if anchor_right else ""))
                break


def _broken_axis(series: Series, events: Sequence[EventMessage]) -> svg.BrokenAxis | None:
    """The plot's broken time axis: from the series' windows (the events' times when there is no
    series), idle gaps over MAX_IDLE_S cut; None when there is no time at all."""
    time_s = series.time_s if series.time_s.size else np.array([m.time_s for m in events], dtype=np.float64)
    if time_s.size == 0:
        return None
    # Never cut a pause the line does not break at: a series with a long hop keeps its line whole.
    max_idle_s = max(MAX_IDLE_S, MAX_GAP_HOPS * _hop_s(series.time_s))
    return svg.broken_axis(time_s, LEFT_PX, RIGHT_PX, max_idle_s, GAP_PX)


def wagon_plot(page: WagonPage) -> tuple[str, int]:
    """The wagon's plot as inline SVG, and how many points it draws."""
    s = page.series if page.series is not None else EMPTY_SERIES
    found = _broken_axis(s, page.events)
    # Without any time the panels are drawn empty on a placeholder axis, with no time labels.
    axis = found if found is not None else svg.broken_axis(np.zeros(1), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    plot = _Plot()
    if found is not None:
        _time_axis(plot, axis)
    _mode_strip(plot, s, axis)
    _panel(plot, s, ("score", "warning", "alarm"), SCORE_TOP_PX, SCORE_BOTTOM_PX, axis, "fused score")
    _panel(plot, s, ("trend", "trend_warning", "trend_alarm"), TREND_TOP_PX, TREND_BOTTOM_PX, axis, "trend")
    _event_marks(plot, page.events, axis)
    label = f"fused score and trend of {page.entry['wagon']} over time"
    body = "".join(plot.parts)
    return (
        f'<svg class="plot" viewBox="0 0 {W_PX:g} {H_PX:g}" width="{W_PX:g}" height="{H_PX:g}" role="img" aria-label="{escape(label, quote=True)}">{body}</svg>',
        plot.points,
    )


