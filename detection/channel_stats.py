"""Per-window statistics of the raw channels, for judging the sensors rather than the suspension.

A dead, stuck, clipping or inverted sensor shows in the raw samples before the indicators: the
mean (a vertical accelerometer at rest reads about +9.81 m/s^2 when mounted the right way up),
the peak, the share of samples equal to their predecessor (a frozen converter repeats its last
value) and the share at or beyond the converter's clip level. Computed per hop and summed per
window, on the same hops and windows as the indicators.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

Triple = tuple[float, float, float]


def _triple(values: NDArray[np.float64]) -> Triple:
    return (float(values[0]), float(values[1]), float(values[2]))


@dataclass(frozen=True)
class ChannelStats:
    """Raw statistics of a1, a2, a3 over one window (before any filtering)."""

    mean_mps2: Triple
    peak_abs_mps2: Triple
    repeat_fraction: Triple  # share of samples equal to the previous one
    clipped_fraction: Triple  # share of samples with |a| >= the clip level


class WindowedChannelStats:
    """Feed whole hops; after the first full window, each hop returns that window's ChannelStats."""

    def __init__(self, hops_per_window: int, hop_n: int, clip_level_mps2: float = np.inf) -> None:
        self.hops_per_window = hops_per_window
        self.hop_n = hop_n
        self.clip_level_mps2 = clip_level_mps2
        # Per hop and channel: sum, peak |a|, repeats inside the hop, repeat across the boundary
        # with the previous hop, samples at the clip level.
        self._sum = np.zeros((hops_per_window, 3))
        self._peak = np.zeros((hops_per_window, 3))
        self._repeats = np.zeros((hops_per_window, 3))
        self._boundary = np.zeros((hops_per_window, 3))
        self._clipped = np.zeros((hops_per_window, 3))
        self._last = np.full(3, np.nan)
        self._n_hops = 0

    def reset(self) -> None:
        self._last.fill(np.nan)
        self._n_hops = 0

    def push_hop(self, hop: NDArray[np.float64]) -> ChannelStats | None:
        slot = self._n_hops % self.hops_per_window
        self._n_hops += 1
        self._sum[slot] = hop.sum(axis=0)
        self._peak[slot] = np.abs(hop).max(axis=0)
        self._repeats[slot] = (hop[1:] == hop[:-1]).sum(axis=0)
        self._boundary[slot] = hop[0] == self._last  # False after a reset: NaN equals nothing
        self._clipped[slot] = (np.abs(hop) >= self.clip_level_mps2).sum(axis=0)
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
            clipped_fraction=_triple(self._clipped.sum(axis=0) / n),
        )


def channel_stats_reference(window: NDArray[np.float64], clip_level_mps2: float = np.inf) -> ChannelStats:
    """The same statistics of one (n, 3) window, computed directly."""
    n = window.shape[0]
    return ChannelStats(
        mean_mps2=_triple(window.mean(axis=0)),
        peak_abs_mps2=_triple(np.abs(window).max(axis=0)),
        repeat_fraction=_triple(np.count_nonzero(np.diff(window, axis=0) == 0, axis=0) / max(n - 1, 1)),
        clipped_fraction=_triple(np.count_nonzero(np.abs(window) >= clip_level_mps2, axis=0) / n),
    )
