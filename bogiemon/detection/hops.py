"""Cutting a stream of blocks of any size into consecutive hops of a fixed size."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
from numpy.typing import NDArray


class HopAssembler:
    """Yields consecutive (hop_n, n_channels) hops from blocks of any length, keeping the remainder.

    A yielded hop is a view, valid until the generator is advanced: consume it before asking for
    the next. Whole hops inside a large block are yielded without copying.
    """

    def __init__(self, hop_n: int, n_channels: int) -> None:
        if hop_n < 1:
            raise ValueError(f"a hop holds at least one sample, got {hop_n}")
        self.hop_n = hop_n
        self.n_channels = n_channels
        self._pending = np.zeros((hop_n, n_channels))
        self._n_pending = 0

    def reset(self) -> None:
        """Drop the partial hop: the next sample starts a new hop."""
        self._n_pending = 0

    def split(self, block: NDArray[np.float64]) -> Iterator[NDArray[np.float64]]:
        data = np.asarray(block, dtype=np.float64)
        if data.ndim != 2 or data.shape[1] != self.n_channels:
            raise ValueError(f"expected an (n, {self.n_channels}) block, got shape {data.shape}")
        n, pos = data.shape[0], 0
        if self._n_pending:
            take = min(self.hop_n - self._n_pending, n)
            self._pending[self._n_pending : self._n_pending + take] = data[:take]
            self._n_pending += take
            pos = take
            if self._n_pending < self.hop_n:
                return
            self._n_pending = 0
            yield self._pending
        while n - pos >= self.hop_n:
            yield data[pos : pos + self.hop_n]
            pos += self.hop_n
        if n > pos:
            self._pending[: n - pos] = data[pos:]
            self._n_pending = n - pos
