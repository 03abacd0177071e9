"""Reconnection with exponential backoff: the live sources (CAN, serial) and alarm delivery (MQTT, CAN alarms).

A live source that loses its device does not raise: it closes what it holds, waits, and tries
again, doubling the wait after each failed attempt up to a ceiling, so that a missing adapter
costs a few syscalls a minute and a returning one is picked up within backoff_max_s. A fleet's
clients of one broker draw each wait with jitter, so they do not reconnect in step after a
broker restart.
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable


class Backoff:
    """When the next attempt to open a device or a connection is due.

    The first retry waits min_s; each failed attempt doubles the wait up to max_s; reset() after
    data flows again so a later loss starts from min_s. With rng, each wait is drawn uniformly in
    [w/2, w] of the doubling wait w; seed the generator (the MQTT publisher: with the wagon id) so
    that the waits are reproducible.
    """

    def __init__(
        self, min_s: float, max_s: float, clock: Callable[[], float] = time.monotonic, rng: random.Random | None = None
    ) -> None:
        if not 0 < min_s <= max_s:
            raise ValueError(f"backoff needs 0 < min_s <= max_s, got {min_s} and {max_s}")
        self.min_s = min_s
        self.max_s = max_s
        self._clock = clock
        self._rng = rng
        self._wait_s = min_s
        self._due_s = clock()  # the first attempt is due at once

    @property
    def wait_s(self) -> float:
        """The wait the next failure will schedule (with jitter: its upper bound)."""
        return self._wait_s

    def due_in_s(self) -> float:
        """Seconds until the next attempt may be made (0 if due)."""
        return max(0.0, self._due_s - self._clock())

    def failed(self) -> float:
        """An attempt failed (or the device was lost): schedule the next; returns the wait in seconds."""
        wait_s = self._wait_s
        if self._rng is not None:
            wait_s *= 0.5 + 0.5 * self._rng.random()
        self._due_s = self._clock() + wait_s
        self._wait_s = min(self.max_s, self._wait_s * 2)
        return wait_s

    def reset(self) -> None:
        self._wait_s = self.min_s
