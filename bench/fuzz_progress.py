"""The fuzz harness's hang clock: the slot where a worker says which input it runs and since when,
read by the parent's watchdog, and the limits both sides apply.

Since when on two clocks: the wall clock (time.monotonic()) and the worker's own CPU time
(time.process_time(), every thread of it). The watchdog judges a hang by the CPU time an input took
(cpu_time_s() reads a process's from /proc): a machine busy with other work slows an input's wall
time, never its CPU time; the wall clock only catches an input blocked without using the CPU.

The worker writes and the parent reads the same shared memory without a lock (a lock held by a
worker the parent kills would stop the parent too). The slot is a sequence lock: the worker makes
the sequence odd, writes the input's index and start, and makes it even again; the parent reads the
sequence, the values and the sequence again, and keeps the values only when the sequence was even
and unchanged. So the start time the parent reads always belongs to the index beside it, never to
a half-written pair (reading the start twice, once to test it and once to use it, once measured a
"hang" of the machine's uptime: the worker had cleared the start between the two reads).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import MutableSequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import fuzz_core

SEQUENCE, INDEX, STARTED, STARTED_CPU = 0, 1, 2, 3
# Doubles: the sequence, the input's index, its start (time.monotonic(); 0: no input running) and
# the worker's CPU time then (time.process_time()).
SLOT_SIZE = 4
READ_TRIES = 100  # a reader retries a torn read this often, then reports nothing for this look
# An input's time limit is CPU time (ITIMER_PROF: the worker's threads together, as the watchdog
# reads it): a machine busy with other work slows an input's wall time, never its CPU time, and a
# wall-clock limit made "hangs" of ordinary inputs under load (a 2 s serial-parser input of the
# quick run, with `make test`'s workers beside it). An input blocked without using the CPU (a
# deadlock) is caught by the wall clock instead, at this many times the limit.
WALL_FACTOR = 10.0


@dataclass(frozen=True)
class Running:
    index: int  # the input being run
    started_s: float  # when it started, time.monotonic()
    started_cpu_s: float  # the worker's CPU time then, time.process_time()


class ProgressSlot:
    """One worker's slot over a shared array of SLOT_SIZE doubles (multiprocessing.RawArray("d", 3))."""

    def __init__(self, cells: MutableSequence[float]) -> None:
        if len(cells) != SLOT_SIZE:
            raise ValueError(f"a progress slot is {SLOT_SIZE} doubles, not {len(cells)}")
        self.cells = cells

    def _write(self, index: int, started_s: float, started_cpu_s: float) -> None:
        sequence = self.cells[SEQUENCE]
        self.cells[SEQUENCE] = sequence + 1.0  # odd: being written
        self.cells[INDEX] = float(index)
        self.cells[STARTED] = started_s
        self.cells[STARTED_CPU] = started_cpu_s
        self.cells[SEQUENCE] = sequence + 2.0  # even: whole

    def begin(self, index: int) -> None:
        """The worker starts input `index` now."""
        self._write(index, time.monotonic(), time.process_time())

    def idle(self) -> None:
        """The worker runs no input (between inputs, or waiting for a batch)."""
        self._write(int(self.cells[INDEX]), 0.0, 0.0)

    def running(self) -> Running | None:
        """The input being run and its start, read whole; None when no input runs (or every try was torn)."""
        for _ in range(READ_TRIES):
            before = self.cells[SEQUENCE]
            index, started_s, started_cpu_s = self.cells[INDEX], self.cells[STARTED], self.cells[STARTED_CPU]
            if before % 2.0 == 0.0 and self.cells[SEQUENCE] == before:
                return Running(int(index), started_s, started_cpu_s) if started_s > 0.0 else None
        return None  # a worker this busy is not stuck: the next look reads it whole

    def running_s(self, now_s: float) -> float:
        """How long the current input has run at now_s (time.monotonic()); 0 when none runs."""
        current = self.running()
        return max(0.0, now_s - current.started_s) if current is not None else 0.0

    def took(self, now_s: float, cpu_now_s: float | None) -> tuple[float, float | None]:
        """The current input's wall and CPU seconds so far, read whole (0 and 0 when none runs;
        CPU None where the worker's CPU time cannot be read): now_s is time.monotonic(), cpu_now_s
        the worker's CPU time now (cpu_time_s)."""
        current = self.running()
        if current is None:
            return 0.0, 0.0
        cpu_s = None if cpu_now_s is None else max(0.0, cpu_now_s - current.started_cpu_s)
        return max(0.0, now_s - current.started_s), cpu_s

    def last_index(self) -> int:
        """The index of the input last begun (whether or not it still runs)."""
        for _ in range(READ_TRIES):
            before = self.cells[SEQUENCE]
            index = self.cells[INDEX]
            if before % 2.0 == 0.0 and self.cells[SEQUENCE] == before:
                return int(index)
        return int(self.cells[INDEX])


_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 0.01


def cpu_time_s(pid: int) -> float | None:
    """A process's CPU time so far (user and system, every thread), as its time.process_time()
    reads it to the kernel's tick; None where /proc cannot tell (another OS, a process gone)."""
    try:
        text = Path(f"/proc/{pid}/stat").read_bytes().decode("ascii", "replace")
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the name, in parentheses, may hold spaces
    try:
        return (int(fields[11]) + int(fields[12])) * _TICK_S  # utime, stime: fields 14 and 15 of proc(5)
    except (IndexError, ValueError):
        return None


def _on_alarm(signum: int, _frame: Any) -> None:
    raise fuzz_core.InputTimeout("cpu" if signum == signal.SIGPROF else "wall")


def install_alarms() -> None:
    """The handlers of the two soft limits an input runs under (bench/fuzz.py run_input: ITIMER_PROF
    for its CPU time, ITIMER_REAL for WALL_FACTOR times it); a worker's main thread, once."""
    signal.signal(signal.SIGALRM, _on_alarm)
    signal.signal(signal.SIGPROF, _on_alarm)


def stuck(running_s: float, cpu_s: float | None, hard_limit_s: float) -> str | None:
    """Why a worker whose input has run running_s of wall time and cpu_s of CPU time (None: not
    known) is stuck past hard_limit_s, or None: the CPU it took decides, so that a worker slowed by
    a busy machine is never killed; the wall clock only for one that waits, at WALL_FACTOR times."""
    if cpu_s is not None and cpu_s > hard_limit_s:
        return f"killed after {cpu_s:.0f} s of CPU in one input"
    if running_s > WALL_FACTOR * hard_limit_s or (cpu_s is None and running_s > hard_limit_s):
        return f"killed after {running_s:.0f} s in one input, {'?' if cpu_s is None else f'{cpu_s:.0f} s'} of CPU"
    return None
