"""Plain functions that draw time series as inline SVG: scales, ticks, decimation, compact paths.

No plotting library: the report must be one self-contained HTML file, small enough to mail, and
these few pieces are all a fleet page needs. Coordinates are pixels of the SVG's viewBox.

The time axis is broken (BrokenAxis): a wagon records minutes to an hour a day, so on a linear
axis its lines would be slivers between empty nights. Stretches with data keep one true scale;
each idle gap is cut to a fixed width.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from html import escape

import numpy as np
from numpy.typing import NDArray

# Steps of a UTC time axis, in seconds: the first that puts ticks far enough apart is used.
TIME_STEPS_S = (
    10, 30, 60, 300, 600, 1800, 3600, 2 * 3600, 3 * 3600, 6 * 3600, 12 * 3600,
    86400, 2 * 86400, 7 * 86400, 14 * 86400, 28 * 86400, 91 * 86400, 364 * 86400,
)  # fmt: skip
DAY_S = 86400
CHAR_PX = 6.2  # the advance of a character of the page's 11 px plot text, a little generous


def gap_segments(time_s: NDArray[np.float64], max_gap_s: float) -> NDArray[np.int64]:
    """A segment number per point (time in increasing order): a new segment after each gap over max_gap_s."""
    if time_s.size == 0:
        return np.zeros(0, dtype=np.int64)
    breaks = np.diff(time_s) > max_gap_s
    return np.concatenate(([0], np.cumsum(breaks))).astype(np.int64)


def decimate_max(
    position: NDArray[np.float64], values: NDArray[np.float64], segments: NDArray[np.int64], lo: float, hi: float, buckets: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """At most one point per bucket of [lo, hi] and segment: the bucket's largest value, at its own position.

    The maximum, not a mean or a sample, so that a short excursion over the alarm level stays
    visible however many windows share a pixel. Positions (times, or the pixel columns of a
    broken axis, so that buckets are columns of the plot) must be increasing. At most
    buckets + (number of segments) points come back (a segment may start inside a bucket).
    """
    n = position.size
    if n == 0 or buckets <= 0:
        return position[:0], values[:0], segments[:0]
    span = max(hi - lo, 1e-9)
    bucket = np.clip(((position - lo) / span * buckets).astype(np.int64), 0, buckets - 1)
    key = segments * buckets + bucket  # non-decreasing in time: segments and buckets both grow
    # Within each key, the first index in (key ascending, value descending) order is the maximum.
    order = np.lexsort((-values, key))
    first = np.ones(n, dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    keep = np.sort(order[first])
    return position[keep], values[keep], segments[keep]


def run_ends(values: NDArray[np.float64], segments: NDArray[np.int64]) -> NDArray[np.int64]:
    """Indices of the first and last point of each run of equal values within a segment.

    A level in force (warning, alarm) changes rarely: two points per run draw it exactly.
    """
    n = values.size
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    change = np.ones(n, dtype=bool)
    change[1:] = (values[1:] != values[:-1]) | (segments[1:] != segments[:-1])
    starts = np.flatnonzero(change)
    ends = np.concatenate((starts[1:] - 1, [n - 1]))
    return np.unique(np.concatenate((starts, ends)))


def log_range(values: NDArray[np.float64], also: Sequence[float] = (), max_decades: float = 4.0) -> tuple[float, float]:
    """Whole decades (lo, hi) that hold the positive values and the levels in also.

    Scores span decades, so the axis is logarithmic; it shows at most max_decades below its top,
    and anything under the bottom (zero and negative values included) is drawn on it.
    """
    levels = [float(v) for v in also if math.isfinite(v) and v > 0]
    positive = values[np.isfinite(values) & (values > 0)]
    seen = ([float(positive.min()), float(positive.max())] if positive.size else []) + levels
    top = max(seen) if seen else 1.0
    bottom = min(seen) if seen else 0.1
    hi = 10.0 ** math.ceil(math.log10(top) - 1e-9)  # 1e-9: 1000 is 10^3 though log10 says 2.9999...
    lo = 10.0 ** math.floor(math.log10(bottom) + 1e-9)
    lo = max(lo, hi / 10.0**max_decades)
    if lo >= hi:
        lo = hi / 10.0
    return lo, hi


def log_px(values: NDArray[np.float64], lo: float, hi: float, top_px: float, bottom_px: float) -> NDArray[np.float64]:
    """Pixel rows of values on a log axis from lo (at bottom_px) to hi (at top_px); clamped to the axis."""
    clamped = np.clip(np.where(np.isfinite(values) & (values > 0), values, lo), lo, hi)
    frac = (np.log10(clamped) - math.log10(lo)) / (math.log10(hi) - math.log10(lo))
    return bottom_px - frac * (bottom_px - top_px)


@dataclass(frozen=True)
class Gap:
    """An idle gap cut from a broken axis: from the end of one data stretch to the start of the next."""

    start_s: float
    end_s: float
    left_px: float
    right_px: float

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


@dataclass(frozen=True, eq=False)
class BrokenAxis:
    """A time axis (Unix seconds -> pixel columns) with its idle gaps cut to a fixed width.

    Piecewise linear and increasing: within a data stretch a second is px_per_s pixels, the same
    in every stretch, so runs compare by length; a gap between stretches is gap_px wide whatever
    its duration. Times before the first stretch or after the last extrapolate at px_per_s.
    Built by broken_axis(); one entry per stretch in the arrays, in time order.
    """

    start_s: NDArray[np.float64]
    end_s: NDArray[np.float64]
    start_px: NDArray[np.float64]
    end_px: NDArray[np.float64]
    px_per_s: float
    gap_px: float  # 0 when there is no gap

    def _stretch(self, time_s: NDArray[np.float64]) -> NDArray[np.int64]:
        # The stretch starting at or before each time (the first one for a time before it).
        return np.clip(np.searchsorted(self.start_s, time_s, side="right") - 1, 0, self.start_s.size - 1)

    def px(self, time_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """The pixel column of each time."""
        t = np.asarray(time_s, dtype=np.float64)
        i = self._stretch(t)
        last = self.start_s.size - 1
        in_data = (t <= self.end_s[i]) | (i == last)
        x_data = self.start_px[i] + (t - self.start_s[i]) * self.px_per_s
        following = np.minimum(i + 1, last)
        duration_s = np.where(in_data, 1.0, self.start_s[following] - self.end_s[i])  # > 0 in a gap
        x_gap = self.end_px[i] + (t - self.end_s[i]) / duration_s * self.gap_px
        return np.where(in_data, x_data, x_gap)

    def time_s(self, x_px: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """The time at each pixel column: the inverse of px."""
        x = np.asarray(x_px, dtype=np.float64)
        i = np.clip(np.searchsorted(self.start_px, x, side="right") - 1, 0, self.start_px.size - 1)
        last = self.start_px.size - 1
        in_data = (x <= self.end_px[i]) | (i == last)
        t_data = self.start_s[i] + (x - self.start_px[i]) / self.px_per_s
        following = np.minimum(i + 1, last)
        gap_px = self.gap_px if self.gap_px > 0 else 1.0  # no gap: every column is in data
        t_gap = self.end_s[i] + (x - self.end_px[i]) / gap_px * (self.start_s[following] - self.end_s[i])
        return np.where(in_data, t_data, t_gap)

    def snap(self, time_s: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Each time moved onto the data: unchanged within a stretch, a gap's start within a gap,
        the axis' ends outside it. Where a mark (an event) is drawn, so it never sits in a cut gap."""
        t = np.asarray(time_s, dtype=np.float64)
        i = self._stretch(t)
        return np.clip(t, self.start_s[i], self.end_s[i])

    @property
    def gaps(self) -> list[Gap]:
        return [
            Gap(float(a), float(b), float(x0), float(x1))
            for a, b, x0, x1 in zip(self.end_s[:-1], self.start_s[1:], self.end_px[:-1], self.start_px[1:], strict=True)
        ]


def broken_axis(
    time_s: NDArray[np.float64],
    left_px: float,
    right_px: float,
    max_idle_s: float,
    gap_px: float,
    *,
    max_gap_share: float = 1 / 3,
    min_span_s: float = 60.0,
) -> BrokenAxis:
    """The broken axis of these times (any order) from left_px to right_px: idle gaps over max_idle_s cut to gap_px.

    Many gaps share at most max_gap_share of the width (each then narrower than gap_px), so the
    data always keep most of it. Data lasting less than min_span_s in all are given that span,
    half before the first time and half after the last, so a lone window is not a zero-width axis.
    """
    t = np.sort(np.asarray(time_s, dtype=np.float64))
    t = t[np.isfinite(t)]
    if t.size == 0:
        raise ValueError("a broken axis needs at least one finite time")
    first = np.concatenate(([0], np.flatnonzero(np.diff(t) > max_idle_s) + 1))
    last = np.concatenate((first[1:] - 1, [t.size - 1]))
    start_s, end_s = t[first].copy(), t[last].copy()
    data_s = float(np.sum(end_s - start_s))
    if data_s < min_span_s:
        pad_s = (min_span_s - data_s) / 2
        start_s[0] -= pad_s
        end_s[-1] += pad_s
        data_s = min_span_s
    n_gaps = start_s.size - 1
    width_px = right_px - left_px
    gap_w = min(gap_px, max_gap_share * width_px / n_gaps) if n_gaps else 0.0
    px_per_s = (width_px - n_gaps * gap_w) / data_s
    widths_px = (end_s - start_s) * px_per_s
    start_px = left_px + np.concatenate(([0.0], np.cumsum(widths_px[:-1] + gap_w)))
    return BrokenAxis(start_s, end_s, start_px, start_px + widths_px, px_per_s, gap_w)


def _labels_apart(candidates: Sequence[tuple[float, float, str]], width_px: float, anchor: str, margin_px: float) -> list[tuple[float, float, str]]:
    # The candidates (x, time, label) in order whose labels do not overlap the one kept before.
    kept: list[tuple[float, float, str]] = []
    end_px = -math.inf
    for x, t, label in candidates:
        w = len(label) * width_px
        left = x - w / 2 if anchor == "middle" else x
        if left >= end_px + margin_px:
            kept.append((x, t, label))
            end_px = left + w
    return kept


def axis_ticks(axis: BrokenAxis, min_spacing_px: float = 72.0, char_px: float = CHAR_PX) -> list[tuple[float, str]]:
    """Ticks of a broken axis at round UTC times on its data stretches: (time, label), labels apart.

    One step for the whole axis (the stretches share a scale): the first that puts ticks at least
    min_spacing_px apart. A stretch too short for a tick of that step gets one at its first whole
    minute, so every run says when it was. A label centred on its tick is dropped where it would
    overlap the one before (two stretches either side of a narrow gap).
    """
    step_s = next((s for s in TIME_STEPS_S if s * axis.px_per_s >= min_spacing_px), TIME_STEPS_S[-1])
    form = "%H:%M:%S" if step_s < 60 else "%m-%d" if step_s >= DAY_S else "%H:%M"
    candidates: list[tuple[float, float, str]] = []
    for a, b in zip(axis.start_s.tolist(), axis.end_s.tolist(), strict=True):
        times, fmt = [float(k * step_s) for k in range(math.ceil(a / step_s), math.floor(b / step_s) + 1)], form
        if not times and step_s > 60 and math.ceil(a / 60) * 60 <= b:
            times, fmt = [math.ceil(a / 60) * 60.0], "%H:%M"
        candidates += [(float(axis.px(t)), t, datetime.fromtimestamp(t, UTC).strftime(fmt)) for t in times]
    return [(t, label) for _, t, label in _labels_apart(candidates, char_px, "middle", 6.0)]


def day_starts(axis: BrokenAxis) -> list[float]:
    """The first time on the axis' data of each UTC day that has data: a midnight within a
    stretch, or the start of a day's first stretch when the night was cut."""
    out: list[float] = []
    next_day: int | None = None  # the first day not yet started
    for a, b in zip(axis.start_s.tolist(), axis.end_s.tolist(), strict=True):
        first = math.floor(a / DAY_S) if next_day is None else max(math.floor(a / DAY_S), next_day)
        out += [max(a, float(day * DAY_S)) for day in range(first, math.floor(b / DAY_S) + 1)]
        next_day = max(first, math.floor(b / DAY_S) + 1)
    return out


def day_labels(axis: BrokenAxis, char_px: float = CHAR_PX) -> list[tuple[float, str]]:
    """The dates of the days on the axis, at each day's first data (day_starts): (time, "YYYY-MM-DD"),
    left-aligned there, a date dropped where it would overlap the one before."""
    candidates = [(float(axis.px(t)), t, datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d")) for t in day_starts(axis)]
    return [(t, label) for _, t, label in _labels_apart(candidates, char_px, "start", 8.0)]


def duration_label(duration_s: float) -> str:
    """A gap's length as the axis writes it: "45 min", "14 h", "2.5 h", "3 d"."""
    minutes = duration_s / 60
    if minutes < 90:
        return f"{minutes:.0f} min"
    hours = duration_s / 3600
    if hours < 48:
        return f"{hours:.1f} h" if hours < 10 and round(hours, 1) != round(hours) else f"{hours:.0f} h"
    days = duration_s / DAY_S
    return f"{days:.1f} d" if days < 10 and round(days, 1) != round(days) else f"{days:.0f} d"


def _tenths(v: int) -> str:
    # A coordinate in tenths of a pixel, written as short as SVG allows: 7 -> ".7", -32 -> "-3.2".
    sign, v = ("-", -v) if v < 0 else ("", v)
    whole, frac = divmod(v, 10)
    if frac == 0:
        return f"{sign}{whole}"
    return f"{sign}{whole if whole else ''}.{frac}"


def path_d(x_px: NDArray[np.float64], y_px: NDArray[np.float64], segments: NDArray[np.int64]) -> str:
    """A compact SVG path: a move at each segment's start, relative lines within it.

    The relative steps are differences of the rounded absolute positions, so no rounding error
    accumulates along a line of a thousand points. A segment of one point is drawn as a dot.
    """
    if x_px.size == 0:
        return ""
    xi = np.rint(x_px * 10).astype(np.int64)
    yi = np.rint(y_px * 10).astype(np.int64)
    parts: list[str] = []
    starts = np.flatnonzero(np.concatenate(([True], segments[1:] != segments[:-1])))
    ends = np.concatenate((starts[1:], [x_px.size]))
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        parts.append(f"M{_tenths(int(xi[s]))} {_tenths(int(yi[s]))}")
        if e - s == 1:
            parts.append("h.1")  # with a round cap, a visible dot
            continue
        dx, dy = np.diff(xi[s:e]), np.diff(yi[s:e])
        steps = []
        for a, b in zip(dx.tolist(), dy.tolist(), strict=True):
            tb = _tenths(b)
            # A negative number needs no separator before it: "l1-2" reads as 1, -2.
            steps.append(_tenths(a) + (tb if tb.startswith("-") else " " + tb))
        parts.append("l" + " ".join(steps))
    return "".join(parts)


def decade_ticks(lo: float, hi: float) -> list[tuple[float, str]]:
    """Ticks of a log axis at each whole decade from lo to hi: (value, label)."""
    out = []
    for k in range(round(math.log10(lo)), round(math.log10(hi)) + 1):
        value = 10.0**k
        label = f"{value:g}" if -3 <= k <= 4 else f"1e{k}"
        out.append((value, label))
    return out


def utc_label(time_s: float) -> str:
    """A time as the page writes it: 2026-12-02 10:00:05Z."""
    return datetime.fromtimestamp(time_s, UTC).strftime("%Y-%m-%d %H:%M:%SZ")


def num(v: float) -> str:
    """A pixel position for an attribute: one decimal, no trailing zero."""
    return _tenths(int(round(v * 10)))


def text(x: float, y: float, content: str, cls: str = "", anchor: str = "") -> str:
    """A <text> element; content is escaped."""
    attrs = f' class="{cls}"' if cls else ""
    attrs += f' text-anchor="{anchor}"' if anchor else ""
    return f'<text x="{num(x)}" y="{num(y)}"{attrs}>{escape(content)}</text>'


def line(x1: float, y1: float, x2: float, y2: float, cls: str, tooltip: str = "") -> str:
    """A <line> element, with an optional tooltip (escaped) that a browser shows on hover."""
    body = f"<title>{escape(tooltip)}</title>" if tooltip else ""
    end = f">{body}</line>" if body else "/>"
    return f'<line x1="{num(x1)}" y1="{num(y1)}" x2="{num(x2)}" y2="{num(y2)}" class="{cls}"{end}'


def rect(x: float, y: float, width: float, height: float, cls: str, tooltip: str = "") -> str:
    """A <rect> element, with an optional tooltip (escaped)."""
    body = f"<title>{escape(tooltip)}</title>" if tooltip else ""
    end = f">{body}</rect>" if body else "/>"
    return f'<rect x="{num(x)}" y="{num(y)}" width="{num(max(width, 0.0))}" height="{num(height)}" class="{cls}"{end}'
