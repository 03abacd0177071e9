"""Per-window statistics of the raw channels, for judging the sensors rather than the suspension.

A dead, stuck, clipping or inverted sensor shows in the raw samples before the indicators: the
mean (a vertical accelerometer at rest reads about +9.81 m/s^2 when mounted the right way up),
the peak, the share of samples equal to their predecessor (a frozen converter repeats its last
value), the longest run of equal consecutive samples (a converter that froze a moment ago: the
share is still small, the run already long), the share at or beyond the converter's clip
level, and the smallest and largest RMS of one hop (after removing the hop's own mean) over the
window's hops: a wagon that stops, stands or starts within the window shows as hops far quieter
than the others, while the window's RMS still looks like running. Computed per hop and combined
per window, on the same hops and windows as the indicators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Triple = tuple[float, float, float]
# A statistic a record does not carry (a record built by hand, without the core's hops).
NOT_MEASURED: Triple = (float("nan"), float("nan"), float("nan"))


def _triple(values: NDArray[np.float64]) -> Triple:
    return (float(values[0]), float(values[1]), float(values[2]))


@dataclass(frozen=True)
class ChannelStats:
    """Raw statistics of a1, a2, a3 over one window (before any filtering)."""

    mean_mps2: Triple
    peak_abs_mps2: Triple
    repeat_fraction: Triple  # share of samples equal to the previous one
    longest_run_s: Triple  # the longest run of equal consecutive samples, seconds (1 / fs: none)
    clipped_fraction: Triple  # share of samples with |a| >= the clip level
    # The smallest and the largest RMS of one hop about the hop's own mean, over the window's hops.
    hop_rms_min_mps2: Triple = NOT_MEASURED
    hop_rms_max_mps2: Triple = NOT_MEASURED


class WindowedChannelStats:
    """Feed whole hops; after the first full window, each hop returns that window's ChannelStats."""

    def __init__(self, hops_per_window: int, hop_n: int, fs_hz: float, clip_level_mps2: float = np.inf) -> None:
        self.hops_per_window = hops_per_window
        self.hop_n = hop_n
        self.fs_hz = fs_hz
        self.clip_level_mps2 = clip_level_mps2
        # Per hop and channel: sum, peak |a|, repeats inside the hop, repeat across the boundary
        # with the previous hop, samples at the clip level.
        self._sum = np.zeros((hops_per_window, 3))
        self._peak = np.zeros((hops_per_window, 3))
        self._repeats = np.zeros((hops_per_window, 3))
        self._boundary = np.zeros((hops_per_window, 3))
        self._clipped = np.zeros((hops_per_window, 3))
        self._hop_rms = np.zeros((hops_per_window, 3))
        # Per hop and channel, in samples: the run that starts the hop, the run that ends it and
        # the longest inside it; a run crossing hops is joined where the boundary repeats.
        self._lead = np.zeros((hops_per_window, 3), dtype=np.int64)
        self._trail = np.zeros((hops_per_window, 3), dtype=np.int64)
        self._longest = np.zeros((hops_per_window, 3), dtype=np.int64)
        self._last = np.full(3, np.nan)
        self._n_hops = 0

    def reset(self) -> None:
        self._last.fill(np.nan)
        self._n_hops = 0

    def push_hop(self, hop: NDArray[np.float64]) -> ChannelStats | None:
        slot = self._n_hops % self.hops_per_window
        self._n_hops += 1
        # Channel-major: reductions along a contiguous axis run 10 to 30 times faster than down
        # the columns of an (n, 3) hop.
        cols = np.ascontiguousarray(hop.T)
        total = _sequential_sum(cols)
        self._sum[slot] = total
        self._peak[slot] = np.abs(cols).max(axis=1)
        self._repeats[slot] = np.count_nonzero(cols[:, 1:] == cols[:, :-1], axis=1)
        self._boundary[slot] = hop[0] == self._last  # False after a reset: NaN equals nothing
        self._clipped[slot] = np.count_nonzero(np.abs(cols) >= self.clip_level_mps2, axis=1)
        # The population RMS about the hop's mean (gravity and bias out), as hop.std(axis=0).
        deviation = cols - (total / hop.shape[0])[:, None]
        self._hop_rms[slot] = np.sqrt(_sequential_sum(deviation * deviation) / hop.shape[0])
        self._lead[slot], self._trail[slot], self._longest[slot] = _runs(cols)
        self._last = hop[-1].copy()
        if self._n_hops < self.hops_per_window:
            return None
        n = self.hops_per_window * self.hop_n
        first = self._n_hops % self.hops_per_window  # the window's first hop: its boundary is outside
        repeats = self._repeats.sum(axis=0) + self._boundary.sum(axis=0) - self._boundary[first]
        return ChannelStats(
            mean_mps2=_triple(self._sum.sum(axis=0) / n),
            peak_abs_mps2=_triple(self._peak.max(axis=0)),
            repeat_fraction=_triple(repeats / max(n - 1, 1)),
            longest_run_s=_triple(self._window_longest_run(first) / self.fs_hz),
            clipped_fraction=_triple(self._clipped.sum(axis=0) / n),
            hop_rms_min_mps2=_triple(self._hop_rms.min(axis=0)),
            hop_rms_max_mps2=_triple(self._hop_rms.max(axis=0)),
        )

    def _window_longest_run(self, first: int) -> NDArray[np.float64]:
        """Per channel, the longest run of the window whose first hop is in slot `first`.

        Plain Python over the window's few hops: numpy's per-call cost dominates at this size.
        """
        order = [(first + k) % self.hops_per_window for k in range(self.hops_per_window)]
        lead, trail, longest = self._lead.tolist(), self._trail.tolist(), self._longest.tolist()
        joined_at = self._boundary.tolist()
        out = []
        for c in range(3):
            best = longest[order[0]][c]
            current = trail[order[0]][c]  # the run reaching the end of the hops so far
            for slot in order[1:]:
                if joined_at[slot][c]:  # the hop's first sample repeats the previous hop's last
                    best = max(best, current + lead[slot][c])
                    current = current + self.hop_n if lead[slot][c] == self.hop_n else trail[slot][c]
                else:
                    current = trail[slot][c]
                best = max(best, longest[slot][c], current)
            out.append(best)
        return np.array(out, dtype=np.float64)


def _sequential_sum(cols: NDArray[np.float64]) -> NDArray[np.float64]:
    """Per row of a (3, n) array, its sum added left to right: the order, and so the bits, of
    numpy's sum down the columns of the (n, 3) hop (a contiguous sum adds pairwise)."""
    return np.cumsum(cols, axis=1)[:, -1]


def _runs(cols: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """Per channel of a (3, n) hop: the lengths of its first run, its last run and its longest."""
    n = cols.shape[1]
    lead, trail, longest = (np.empty(3, dtype=np.int64) for _ in range(3))
    for c in range(3):
        changes = np.flatnonzero(cols[c, 1:] != cols[c, :-1])  # a run ends at each of these samples
        edges = np.concatenate(([-1], changes, [n - 1]))
        lengths = np.diff(edges)
        lead[c], trail[c], longest[c] = lengths[0], lengths[-1], lengths.max()
    return lead, trail, longest


def longest_run_reference(column: NDArray[np.float64]) -> int:
    """The longest run of equal consecutive values, by walking the samples one by one."""
    best = run = 0
    for i, value in enumerate(column):
        run = run + 1 if i > 0 and value == column[i - 1] else 1
        best = max(best, run)
    return best


def hop_rms_reference(window: NDArray[np.float64], hop_n: int) -> NDArray[np.float64]:
    """(n_hops, 3): each hop's RMS about its own mean, hop by hop."""
    rows = []
    for start in range(0, window.shape[0], hop_n):
        hop = window[start : start + hop_n]
        rows.append(np.sqrt(np.mean((hop - hop.mean(axis=0)) ** 2, axis=0)))
    return np.array(rows)


def channel_stats_reference(
    window: NDArray[np.float64], fs_hz: float, clip_level_mps2: float = np.inf, hop_n: int | None = None
) -> ChannelStats:
    """The same statistics of one (n, 3) window, computed directly; hops of hop_n samples (None:
    the window is one hop)."""
    n = window.shape[0]
    hop_rms = hop_rms_reference(window, hop_n or n)
    return ChannelStats(
        mean_mps2=_triple(window.mean(axis=0)),
        peak_abs_mps2=_triple(np.abs(window).max(axis=0)),
        repeat_fraction=_triple(np.count_nonzero(np.diff(window, axis=0) == 0, axis=0) / max(n - 1, 1)),
        longest_run_s=_triple(np.array([longest_run_reference(window[:, c]) for c in range(3)]) / fs_hz),
        clipped_fraction=_triple(np.count_nonzero(np.abs(window) >= clip_level_mps2, axis=0) / n),
        hop_rms_min_mps2=_triple(hop_rms.min(axis=0)),
        hop_rms_max_mps2=_triple(hop_rms.max(axis=0)),
    )
