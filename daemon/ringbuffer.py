"""A preallocated, bounded ring of sample blocks between the source thread and the core.

The samples live in one (capacity, 3) array allocated at start and the block headers in a
fixed-size table, so memory never grows however long the daemon runs. A live source must never
wait for the core: when the ring is full its block is dropped, counted, and the next block
carries a gap so no window bridges the loss. A recording may wait instead (backpressure): replay
then runs as fast as the core, and loses nothing.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from bogiemon.drivers.base import Block, SensorStatus


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
        self.backpressure = backpressure
        self.counters = RingCounters()
        self._samples = np.zeros((capacity_n, 3))
        # Header table: sample offset, length, start time, rate, gap flag, status bits.
        self._offset = np.zeros(max_blocks, dtype=np.int64)
        self._length = np.zeros(max_blocks, dtype=np.int64)
        self._start_s = np.zeros(max_blocks)
        self._fs_hz = np.zeros(max_blocks)
        self._gap = np.zeros(max_blocks, dtype=bool)
        self._status = np.zeros((max_blocks, 3), dtype=np.int64)
        self._head = 0  # next header slot to read
        self._n_blocks = 0
        self._write_pos = 0  # next sample slot to write
        self._n_samples = 0
        self._gap_pending = False
        self._closed = False
        self._cond = threading.Condition()

    def put(self, block: Block, timeout_s: float | None = None) -> bool:
        """Store a copy of the block and return True.

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
            slot = (self._head + self._n_blocks) % self._offset.shape[0]
            self._offset[slot], self._length[slot] = self._write_pos, n
            self._start_s[slot], self._fs_hz[slot] = block.start_s, block.fs_hz
            self._gap[slot] = block.gap_before or self._gap_pending
            self._status[slot] = [int(s) for s in block.status]
            self._gap_pending = False
            first = min(n, self.capacity_n - self._write_pos)  # the copy may wrap around the end
            self._samples[self._write_pos : self._write_pos + first] = block.accel_mps2[:first]
            self._samples[: n - first] = block.accel_mps2[first:]
            self._write_pos = (self._write_pos + n) % self.capacity_n
            self._n_samples += n
            self._n_blocks += 1
            self.counters.blocks_in += 1
            self._cond.notify_all()
            return True

    def get(self, timeout_s: float | None = None) -> Block | None:
        """The oldest block (a copy), None on timeout; RingClosed once closed and empty."""
        with self._cond:
            if not self._cond.wait_for(lambda: self._n_blocks > 0 or self._closed, timeout_s):
                return None
            if self._n_blocks == 0:
                raise RingClosed
            slot = self._head
            offset, n = int(self._offset[slot]), int(self._length[slot])
            first = min(n, self.capacity_n - offset)
            samples = np.concatenate([self._samples[offset : offset + first], self._samples[: n - first]])
            block = Block(
                start_s=float(self._start_s[slot]),
                fs_hz=float(self._fs_hz[slot]),
                accel_mps2=samples,
                gap_before=bool(self._gap[slot]),
                status=(SensorStatus(int(self._status[slot, 0])), SensorStatus(int(self._status[slot, 1])), SensorStatus(int(self._status[slot, 2]))),
            )
            self._head = (self._head + 1) % self._offset.shape[0]
            self._n_blocks -= 1
            self._n_samples -= n
            self.counters.blocks_out += 1
            self._cond.notify_all()
            return block

    def close(self) -> None:
        """No more blocks will come; readers drain what is left, then get RingClosed."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()

    @property
    def fill_n(self) -> int:
        with self._cond:
            return self._n_samples

    def _fits(self, n: int) -> bool:
        return self._n_samples + n <= self.capacity_n and self._n_blocks < self._offset.shape[0]
