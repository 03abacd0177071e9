"""A bounded ring of sample blocks between the source thread and the core.

The ring holds the blocks the source made, as they are (no copy, no rebuild: a source hands over
a block and never touches its samples again), and bounds what it holds: at most capacity_n
samples in at most max_blocks blocks, so the memory it keeps alive never grows however long the
daemon runs. A live source must never wait for the core: when the ring is full its block is
dropped, counted, and the next block carries a gap so no window bridges the loss. A recording
may wait instead (backpressure): replay then runs as fast as the core, and loses nothing.
"""

from __future__ import annotations

import dataclasses
import threading
from collections import deque
from dataclasses import dataclass

from bogiemon.drivers.base import Block


@dataclass
class RingCounters:
    blocks_in: int = 0
    blocks_out: int = 0
    samples_dropped: int = 0  # samples of blocks dropped because the ring was full
    overflows: int = 0  # times a block was dropped


class RingClosed(Exception):
    """The producer has closed the ring and every block in it has been taken."""


class BlockRing:
    def __init__(self, capacity_n: int, max_blocks: int = 4096, backpressure: bool = False) -> None:
        if capacity_n < 1 or max_blocks < 1:
            raise ValueError("a ring needs room for at least one sample and one block")
        self.capacity_n = capacity_n
        self.max_blocks = max_blocks
        self.backpressure = backpressure
        self.counters = RingCounters()
        self._blocks: deque[Block] = deque()
        self._n_samples = 0
        self._gap_pending = False
        self._closed = False
        self._cond = threading.Condition()

    def put(self, block: Block, timeout_s: float | None = None) -> bool:
        """Hold the block and return True.

        Without backpressure a full ring drops the block (counted; the next block gets a gap)
        and returns False. With backpressure it waits up to timeout_s for room and returns
        False on timeout without dropping anything.
        """
        n = block.n_samples
        if n == 0:
            return True
        if n > self.capacity_n:
            raise ValueError(f"a block of {n} samples cannot fit a ring of {self.capacity_n}")
        with self._cond:
            if self.backpressure:
                # Wait for room; on timeout nothing is dropped and the caller may try again.
                if not self._cond.wait_for(lambda: self._fits(n) or self._closed, timeout_s) or self._closed:
                    return False
            if not self._fits(n):
                self.counters.overflows += 1
                self.counters.samples_dropped += n
                self._gap_pending = True
                return False
            if self._gap_pending and not block.gap_before:
                block = dataclasses.replace(block, gap_before=True)  # the header only: the samples are shared
            self._gap_pending = False
            self._blocks.append(block)
            self._n_samples += n
            self.counters.blocks_in += 1
            self._cond.notify_all()
            return True

    def get(self, timeout_s: float | None = None) -> Block | None:
        """The oldest block, None on timeout; RingClosed once closed and empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: bool(self._blocks) or self._closed, timeout_s):
                return None
            if not self._blocks:
                raise RingClosed
            block = self._blocks.popleft()
            self._n_samples -= block.n_samples
            self.counters.blocks_out += 1
            self._cond.notify_all()
            return block

    def close(self) -> None:
        """No more blocks will come; readers drain what is left, then get RingClosed."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    def _fits(self, n: int) -> bool:
        return self._n_samples + n <= self.capacity_n and len(self._blocks) < self.max_blocks
