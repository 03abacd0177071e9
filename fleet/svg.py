"""Plain functions that draw time series as inline SVG: scales, ticks, decimation, compact paths.

No plotting library: the report must be one self-contained HTML file, small enough to mail, and
these few pieces are all a fleet page needs. Coordinates are pixels of the SVG's viewBox.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from datetime import UTC, datetime
from html import escape

import numpy as np
from numpy.typing import NDArray

# Steps of a UTC time axis, in seconds: the first that gives at most max_ticks ticks is used.
TIME_STEPS_S = (
    60, 300, 600, 1800, 3600, 2 * 3600, 3 * 3600, 6 * 3600, 12 * 3600,
    86400, 2 * 86400, 7 * 86400, 14 * 86400, 28 * 86400, 91 * 86400, 364 * 86400,
)  # fmt: skip


def gap_segments(time_s: NDArray[np.float64], max_gap_s: float) -> NDArray[np.int64]:
    """A segment number per point (time in increasing order): a new segment after each gap over max_gap_s."""
    if time_s.size == 0:
        return np.zeros(0, dtype=np.int64)
    breaks = np.diff(time_s) > max_gap_s
    return np.concatenate(([0], np.cumsum(breaks))).astype(np.int64)


def decimate_max(
    time_s: NDArray[np.float64], values: NDArray[np.float64], segments: NDArray[np.int64], t0_s: float, t1_s: float, buckets: int
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    """At most one point per time bucket and segment: the bucket's largest value, at its own time.

    The maximum, not a mean or a sample, so that a short excursion over the alarm level stays
    visible however many windows share a pixel. Points must be in time order. At most
    buckets + (number of segments) points come back (a segment may start inside a bucket).
    """
    n = time_s.size
    if n == 0 or buckets <= 0:
        return time_s[:0], values[:0], segments[:0]
    span_s = max(t1_s - t0_s, 1e-9)
    bucket = np.clip(((time_s - t0_s) / span_s * buckets).astype(np.int64), 0, buckets - 1)
    key = segments * buckets + bucket  # non-decreasing in time: segments and buckets both grow
    # Within each key, the first index in (key ascending, value descending) order is the maximum.
    order = np.lexsort((-values, key))
    first = np.ones(n, dtype=bool)
    first[1:] = key[order][1:] != key[order][:-1]
    keep = np.sort(order[first])
    return time_s[keep], values[keep], segments[keep]


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


def linear_px(values: NDArray[np.float64], lo: float, hi: float, left_px: float, right_px: float) -> NDArray[np.float64]:
    """Pixel columns of values on a linear axis from lo (at left_px) to hi (at right_px)."""
    span = hi - lo if hi > lo else 1.0
    return left_px + (values - lo) / span * (right_px - left_px)


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


def time_ticks(t0_s: float, t1_s: float, max_ticks: int = 10) -> list[tuple[float, str]]:
    """Ticks of a UTC time axis from t0_s to t1_s (Unix seconds): (time, label) at round times."""
    span_s = max(t1_s - t0_s, 1.0)
    step_s = next((s for s in TIME_STEPS_S if span_s / s <= max_ticks), TIME_STEPS_S[-1])
    first = math.ceil(t0_s / step_s) * step_s
    ticks = []
    t = float(first)
    while t <= t1_s:
        moment = datetime.fromtimestamp(t, UTC)
        if step_s >= 86400:
            label = moment.strftime("%m-%d")
        elif moment.hour == 0 and moment.minute == 0 or not ticks:
            label = moment.strftime("%m-%d %H:%M")  # the date where a day starts (and on the first tick)
        else:
            label = moment.strftime("%H:%M")
        ticks.append((t, label))
        t += step_s
    return ticks


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


def rect(x: float, y: float, width: float, height: float, cls: str) -> str:
    """A <rect> element."""
    return f'<rect x="{num(x)}" y="{num(y)}" width="{num(max(width, 0.0))}" height="{num(height)}" class="{cls}"/>'
