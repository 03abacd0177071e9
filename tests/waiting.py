"""Waiting on another process the way a loaded machine allows: for as long as it works towards it.

A test that gives a process a fixed number of seconds to start or to stop fails on a busy machine
(`make test`'s workers beside other work: a daemon that starts in 3 s alone took 76 s at a load
average of 25). A process that still uses the CPU is still getting there; one whose CPU time stands
still for STALL_S is stuck (or asleep for good), and BACKSTOP_S of wall time ends any wait.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

STALL_S = 30.0
BACKSTOP_S = 600.0
_TICK_S = 1.0 / os.sysconf("SC_CLK_TCK")


def cpu_time_s(pid: int) -> float | None:
    """A process's CPU time so far (user and system, every thread) and its living children's, theirs
    included (a harness waits while its workers work); None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_bytes().decode("ascii", "replace")
    except OSError:
        return None
    fields = text[text.rindex(")") + 2 :].split()  # the name, in parentheses, may hold spaces
    own_s = (int(fields[11]) + int(fields[12]) + int(fields[13]) + int(fields[14])) * _TICK_S  # utime, stime, and the waited-for children's
    return own_s + sum(cpu_time_s(child) or 0.0 for child in _children(pid))


def _children(pid: int) -> list[int]:
    children = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            children += [int(c) for c in Path(f"/proc/{pid}/task/{task}/children").read_text().split()]
    except OSError:
        pass  # gone meanwhile
    return children


class Progress:
    """Whether the process `pid` still works: its CPU time moved within the last stall_s, and the
    wait has not reached backstop_s."""

    def __init__(self, pid: int, stall_s: float = STALL_S, backstop_s: float = BACKSTOP_S) -> None:
        self.pid, self.stall_s = pid, stall_s
        now = time.monotonic()
        self._end_s = now + backstop_s
        self._cpu_s = cpu_time_s(pid)
        self._moved_s = now

    def working(self) -> bool:
        now = time.monotonic()
        cpu_s = cpu_time_s(self.pid)
        if cpu_s is None:
            return False  # gone
        if cpu_s != self._cpu_s:
            self._cpu_s, self._moved_s = cpu_s, now
        return now - self._moved_s < self.stall_s and now < self._end_s

    def why_not(self) -> str:
        """What working() saw, for a failure's message."""
        return f"its CPU time ({self._cpu_s} s) stood still for {time.monotonic() - self._moved_s:.0f} s, or the wait passed {BACKSTOP_S:g} s"
