"""Windowed cross-correlation: the estimator, a direct reference, and the streaming version.

The estimator (the paper's C_xy(tau) = 1/T * integral x(t) y(t - tau) dt, sampled):

    C_xy[k] = 1/N * sum_{n} x[n] * y[n - k],   k = -K .. +K,

where the window holds N samples s .. s+N-1 (T = N / fs) and the sum runs over the N - |k|
indices n for which *both* n and n - k lie inside the window. No sample from before or after the
window is used, so a lag never reaches outside it: C(tau) is the classical biased (1/T)
estimator, tapering towards 0 as |tau| grows, with no extra latency after the window ends and no
dependence on what happened before a gap. For k > 0, x is paired with earlier samples of y.

Streaming (StreamingCrossCorrelator): windows start every hop H samples and N = M * H. For each
completed hop b the correlator forms, in the frequency domain, the lagged block products

    A_b[l] = sum_{n in hop b} x[n] y[n - l],   l = 0 .. K,

pairing the hop's x with y up to K samples back (before the segment start, y counts as 0), and
the same with x and y exchanged for the negative lags. Summing A_b over the M hops of a window
counts every in-window pair once, plus the pairs whose y lies before the window start; those are

    E[l] = sum_{n = s}^{s + l - 1} x[n] y[n - l].

A_b is kept split in two spectra, the pairs whose y lies in hop b itself and those whose y lies
in the K samples before it (by linearity, the second needs no extra FFT). When K <= H, E is
exactly the second part of the window's first hop, so C = (sum_b A_b - E) / N is summed in the
frequency domain and costs one inverse FFT per window; when K > H, E is the correlation of the
window's first K samples of x with the K samples of y before it, one more small FFT product.
Per hop that is a few FFTs of length ~H + K instead of a correlation of the whole window. Each
window is summed afresh from the stored spectra (no running sum), so rounding never accumulates.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy import fft
from numpy.typing import NDArray

from bogiemon.detection.hops import HopAssembler


def RESUM_HOPS(hops_per_window: int) -> int:  # noqa: N802 - a rule of the module, read as a constant
    """Hops between two afresh sums of the sliding one: once per window's worth of hops."""
    return max(hops_per_window, 1)


def next_fast_len(n: int) -> int:
    """The smallest 5-smooth number (2^a 3^b 5^c) >= n: a length pocketfft transforms fastest.

    scipy.fft.next_fast_len(n, real=True), written out: the core transforms with numpy.fft (the
    same pocketfft, the same values bit for bit) so that a command that only analyses never
    imports scipy.fft, whose array-API layer and scipy.special cost a third of a second of start-up.
    """
    if n < 1:
        raise ValueError(f"a transform length is at least 1, got {n}")
    best = 1 << max(n - 1, 0).bit_length()  # the next power of two
    p5 = 1
    while p5 < best:
        p35 = p5
        while p35 < best:
            # The smallest power of two taking p35 to n or beyond.
            p2 = 1 << max(-(-n // p35) - 1, 0).bit_length()
            best = min(best, p35 * p2)
            p35 *= 3
        p5 *= 5
    return best


def xcorr_direct(x: NDArray[np.float64], y: NDArray[np.float64], max_lag_n: int) -> NDArray[np.float64]:
    """Reference: C_xy[k] for k = -max_lag_n .. +max_lag_n over one window, one dot product per lag."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    n = x.shape[0]
    if y.shape[0] != n:
        raise ValueError("x and y must have the same length")
    if not 0 <= max_lag_n < n:
        raise ValueError(f"max_lag_n must lie in [0, {n - 1}], got {max_lag_n}")
    out = np.empty(2 * max_lag_n + 1)
    for k in range(-max_lag_n, max_lag_n + 1):
        if k >= 0:
            out[k + max_lag_n] = np.dot(x[k:], y[: n - k])
        else:
            out[k + max_lag_n] = np.dot(x[: n + k], y[-k:])
    return out / n


@dataclass(frozen=True)
class WindowCorrelations:
    """The correlations of one window.

    start_index: the window's first sample, counted from the start of the segment;
    lagged: (n_pairs, 2K+1) C_xy[k] for k = -K..K, one row per lagged pair;
    zero_lag: (n_zero_lag_pairs,) C_xy[0], one entry per zero-lag pair.
    """

    start_index: int
    lagged: NDArray[np.float64]
    zero_lag: NDArray[np.float64]


class StreamingCrossCorrelator:
    """Windowed cross-correlations of a multichannel stream, fed blocks of any size.

    Every hop after the first full window, push() returns that window's correlations: full lags
    -K..K for each of ``pairs``, and lag 0 only for each of ``zero_lag_pairs`` (a pair (i, i) gives
    a mean square). Pairs are (x, y) column indices of the pushed (n, n_channels) blocks.
    Requires window_n to be a whole number of hops and max_lag_n < window_n.
    """

    def __init__(
        self,
        n_channels: int,
        pairs: Sequence[tuple[int, int]],
        window_n: int,
        hop_n: int,
        max_lag_n: int,
        zero_lag_pairs: Sequence[tuple[int, int]] = (),
    ) -> None:
        if hop_n < 1 or window_n < hop_n or window_n % hop_n:
            raise ValueError(f"window ({window_n} samples) must be a whole number of hops ({hop_n} samples)")
        if not 0 <= max_lag_n < window_n:
            raise ValueError(f"max lag ({max_lag_n} samples) must be shorter than the window ({window_n})")
        for i, j in (*pairs, *zero_lag_pairs):
            if not (0 <= i < n_channels and 0 <= j < n_channels):
                raise ValueError(f"pair ({i}, {j}) names a channel outside 0..{n_channels - 1}")
        self.n_channels = n_channels
        self.window_n = window_n
        self.hop_n = hop_n
        self.max_lag_n = max_lag_n
        self._pairs = tuple(pairs)
        self._zero_lag_pairs = tuple(zero_lag_pairs)
        self._blocks_per_window = window_n // hop_n
        # Only channels of lagged pairs need history; map them to compact columns.
        self._lag_channels = sorted({c for pair in self._pairs for c in pair})
        self._lag_col = {c: i for i, c in enumerate(self._lag_channels)}
        self._nfft_block = next_fast_len(hop_n + max_lag_n)
        self._nfft_head = next_fast_len(max(2 * max_lag_n, 1))  # used when K > H
        self._pair_cols = (
            np.array([self._lag_col[i] for i, _ in self._pairs], dtype=np.intp),
            np.array([self._lag_col[j] for _, j in self._pairs], dtype=np.intp),
        )
        lag = self._lag_channels
        # The lagged channels of a hop: a view when they are adjacent columns (the core's are).
        self._lag_take: slice | list[int] = slice(lag[0], lag[-1] + 1) if lag == list(range(lag[0], lag[-1] + 1)) else lag
        n_lag_ch = len(self._lag_channels)
        # The last window_n + K samples of the lagged channels, [s - K, s + N) at emission time, are
        # rows [end - held, end) of a buffer several windows long: a hop is appended, and the held
        # rows move to its start only when it is full (copying them every hop cost a tenth of the core).
        self._held_n = window_n + max_lag_n
        self._buffer = np.zeros((self._held_n + max(self._held_n, 8 * hop_n), n_lag_ch))
        self._end = self._held_n
        self._hops = HopAssembler(hop_n, n_channels)
        # Per hop, per pair and direction (x leads, y leads): the cross-spectra of the hop against
        # itself and against the K samples before it; and the zero-lag sums.
        n_bins = self._nfft_block // 2 + 1
        self._spec_in = np.zeros((self._blocks_per_window, len(self._pairs), 2, n_bins), dtype=np.complex128)
        self._spec_pre = np.zeros_like(self._spec_in)
        # The sliding sum of both over the held hops (module docstring), and the same with sliding off:
        # the per-window path, summed afresh for every window (the reference it is checked against).
        self._sum = np.zeros((len(self._pairs), 2, n_bins), dtype=np.complex128)
        self.sliding = True
        self._block_zero_lag = np.zeros((self._blocks_per_window, len(self._zero_lag_pairs)))
        self.reset()

    def reset(self) -> None:
        """Start a new segment: nothing before this point is paired with what follows."""
        self._spec_in.fill(0.0)
        self._spec_pre.fill(0.0)
        self._sum.fill(0.0)
        self._buffer.fill(0.0)
        self._end = self._held_n
        self._hops.reset()
        self._n_hops = 0

    @property
    def _history(self) -> NDArray[np.float64]:
        """(window_n + K, lagged channels): the samples a window's correlations may pair."""
        return self._buffer[self._end - self._held_n : self._end]

    def push(self, block: NDArray[np.float64]) -> list[WindowCorrelations]:
        """Feed an (n, n_channels) block; return the windows completed by it, oldest first."""
        out = []
        for hop in self._hops.split(block):
            window = self._complete_hop(hop)
            if window is not None:
                out.append(window)
        return out

    def _complete_hop(self, hop: NDArray[np.float64]) -> WindowCorrelations | None:
        h, k_max = self.hop_n, self.max_lag_n
        buffer, keep = self._buffer, self._held_n - h
        if self._end + h > buffer.shape[0]:
            buffer[:keep] = buffer[self._end - keep : self._end]
            self._end = keep
        buffer[self._end : self._end + h] = hop[:, self._lag_take]
        self._end += h
        hist = self._history
        slot = self._n_hops % self._blocks_per_window
        self._n_hops += 1

        if self._pairs:
            # Spectra of each lagged channel's hop (after K zeros) and of the K samples before it.
            padded = np.zeros((self._nfft_block, hist.shape[1]))
            padded[k_max : k_max + h] = hist[-h:]
            spec_hop = fft.rfft(padded, axis=0)
            spec_pre = fft.rfft(hist[-(h + k_max) :], n=self._nfft_block, axis=0) - spec_hop
            if self.sliding:  # the hop leaving the window (zeros until the first window is full)
                self._sum -= self._spec_in[slot]
                self._sum -= self._spec_pre[slot]
            self._cross_spectra(spec_hop, spec_hop, out=self._spec_in[slot])
            self._cross_spectra(spec_hop, spec_pre, out=self._spec_pre[slot])
            if self.sliding:
                if self._n_hops % RESUM_HOPS(self._blocks_per_window) == RESUM_HOPS(self._blocks_per_window) - 1:
                    self._sum = self.window_sum()  # afresh: rounding never accumulates past RESUM_HOPS
                else:
                    self._sum += self._spec_in[slot]
                    self._sum += self._spec_pre[slot]
        for p, (i, j) in enumerate(self._zero_lag_pairs):
            self._block_zero_lag[slot, p] = np.dot(hop[:, i], hop[:, j])

        if self._n_hops < self._blocks_per_window:
            return None
        return self._emit(first_slot=self._n_hops % self._blocks_per_window)

    def _cross_spectra(
        self, spec_lead: NDArray[np.complex128], spec_lag: NDArray[np.complex128], out: NDArray[np.complex128] | None = None
    ) -> NDArray[np.complex128]:
        """(n_pairs, 2, bins): lead(x) * conj(lag(y)), then lead(y) * conj(lag(x)), per pair (into
        out, a hop's slot, when given: no temporary the size of the slot)."""
        i, j = self._pair_cols
        x_lead, y_lead = spec_lead[:, i].T, spec_lead[:, j].T  # (n_pairs, bins)
        x_lag, y_lag = spec_lag[:, i].T, spec_lag[:, j].T
        if out is None:
            out = np.empty((len(self._pairs), 2, spec_lead.shape[0]), dtype=np.complex128)
        np.multiply(x_lead, np.conj(y_lag), out=out[:, 0])
        np.multiply(y_lead, np.conj(x_lag), out=out[:, 1])
        return out

    def _emit(self, first_slot: int) -> WindowCorrelations:
        k_max, n, h = self.max_lag_n, self.window_n, self.hop_n
        total = np.zeros((len(self._pairs), 2, k_max + 1))
        if self._pairs:
            spec = self._sum.copy() if self.sliding else self.window_sum()
            if k_max <= h:  # the pairs reaching before the window are all in its first hop
                spec -= self._spec_pre[first_slot]
            total = fft.irfft(spec, n=self._nfft_block, axis=2)[:, :, : k_max + 1]
            if k_max > h:
                total -= self._head_correction()
        lagged = np.empty((len(self._pairs), 2 * k_max + 1))
        lagged[:, k_max:] = total[:, 0, :]  # k >= 0: x[n] y[n - k]
        lagged[:, :k_max] = total[:, 1, :0:-1]  # k < 0: y[n] x[n - |k|], |k| = K .. 1
        start_index = (self._n_hops - self._blocks_per_window) * h
        zero_lag = self._block_zero_lag.sum(axis=0) / n
        return WindowCorrelations(start_index=start_index, lagged=lagged / n, zero_lag=zero_lag)

    def window_sum(self) -> NDArray[np.complex128]:
        """Both spectra summed afresh over the held hops: the per-window path."""
        return np.asarray(self._spec_in.sum(axis=0) + self._spec_pre.sum(axis=0), dtype=np.complex128)

    def _head_correction(self) -> NDArray[np.float64]:
        """E for both directions of every pair: the window's first K samples against the K before it."""
        k_max = self.max_lag_n
        pre = self._history[:k_max]
        head = np.zeros((self._nfft_head, pre.shape[1]))
        head[k_max : 2 * k_max] = self._history[k_max : 2 * k_max]
        spec = self._cross_spectra(fft.rfft(head, axis=0), fft.rfft(pre, n=self._nfft_head, axis=0))
        return fft.irfft(spec, n=self._nfft_head, axis=2)[:, :, : k_max + 1]
