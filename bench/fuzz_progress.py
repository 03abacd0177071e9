"""The slot where a fuzz worker says which input it runs and since when, read by the parent's watchdog.

The worker writes and the parent reads the same shared memory without a lock (a lock held by a
worker the parent kills would stop the parent too). The slot is a sequence lock: the worker makes
the sequence odd, writes the input's index and start, and makes it even again; the parent reads the
sequence, the values and the sequence again, and keeps the values only when the sequence was even
and unchanged. So the start time the parent reads always belongs to the index beside it, never to
a half-written pair (reading the start twice, once to test it and once to use it, once measured a
"hang" of the machine's uptime: the worker had cleared the start between the two reads).
"""

from __future__ import annotations

import time
from collections.abc import MutableSequence
from dataclasses import dataclass

SEQUENCE, INDEX, STARTED = 0, 1, 2
SLOT_SIZE = 3  # doubles: the sequence, the input's index, its start (time.monotonic(); 0: no input running)
READ_TRIES = 100  # a reader retries a torn read this often, then reports nothing for this look


@dataclass(frozen=True)
class Running:
    index: int  # the input being run
    started_s: float  # when it started, time.monotonic()


class ProgressSlot:
    """One worker's slot over a shared array of SLOT_SIZE doubles (multiprocessing.RawArray("d", 3))."""

    def __init__(self, cells: MutableSequence[float]) -> None:
        if len(cells) != SLOT_SIZE:
            raise ValueError(f"a progress slot is {SLOT_SIZE} doubles, not {len(cells)}")
        self.cells = cells

    def _write(self, index: int, started_s: float) -> None:
        sequence = self.cells[SEQUENCE]
        self.cells[SEQUENCE] = sequence + 1.0  # odd: being written
        self.cells[INDEX] = float(index)
        self.cells[STARTED] = started_s
        self.cells[SEQUENCE] = sequence + 2.0  # even: whole

    def begin(self, index: int) -> None:
        """The worker starts input `index` now."""
        self._write(index, time.monotonic())

    def idle(self) -> None:
        """The worker runs no input (between inputs, or waiting for a batch)."""
        self._write(int(self.cells[INDEX]), 0.0)

    def running(self) -> Running | None:
        """The input being run and its start, read whole; None when no input runs (or every try was torn)."""
        for _ in range(READ_TRIES):
            before = self.cells[SEQUENCE]
            index, started_s = self.cells[INDEX], self.cells[STARTED]
            if before % 2.0 == 0.0 and self.cells[SEQUENCE] == before:
                return Running(int(index), started_s) if started_s > 0.0 else None
        return None  # a worker this busy is not stuck: the next look reads it whole

    def running_s(self, now_s: float) -> float:
        """How long the current input has run at now_s (time.monotonic()); 0 when none runs."""
        current = self.running()
        return max(0.0, now_s - current.started_s) if current is not None else 0.0

    def last_index(self) -> int:
        """The index of the input last begun (whether or not it still runs)."""
        for _ in range(READ_TRIES):
            before = self.cells[SEQUENCE]
            index = self.cells[INDEX]
            if before % 2.0 == 0.0 and self.cells[SEQUENCE] == before:
                return int(index)
        return int(self.cells[INDEX])
