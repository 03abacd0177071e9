"""A battery-fed unit's duty cycle ([duty], docs/gateway.md): measure M minutes in every N while
the wagon runs, rest while it stands, and notice it moving again with a short listen.

DutySource wraps the configured source and decides, block by block, what the daemon reads:

- Measuring: every block goes on to the monitor. With a cycle (measure_s < cycle_s) a
  measurement ends after measure_s of samples and the source rests for the rest of the cycle.
- Standing: every channel still (below [health] standstill_rms_mps2, the level the monitor gates
  a window as standstill) for standing_after_s of samples: the source rests probe_every_s, then
  listens for probe_s (nothing goes on to the monitor) and rests again while it stays still. The
  first block that moves starts a measurement.

Stillness is told by the cheapest test the samples allow: each channel's standard deviation over
one block (about a second: 1500 numbers, microseconds), no window, filter or spectrum. While a
standing wagon rests, the daemon costs a listen a minute and its idle threads' wake-ups.

A rest on a live source releases its device (Source.pause: the CAN socket or the serial port
closed, the hub's frames dropped by the kernel unread) and sleeps; on a recording (`bogiemon replay
--duty`) the samples of a rest are skipped by their times instead, so that a replay shows what
the duty-cycled daemon would have judged on the wagon. Durations are samples' time while the
source is read and the clock's while it rests, which are the same on a wagon. The first block after
a rest begins a new stream (Block.new_stream: a new segment, never a loss the dropouts check
counts), and the source says it rests (Source.resting) so the watchdog does not take a rest for a
stall.
"""

from __future__ import annotations

import enum
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from bogiemon.daemon.logs import get_logger
from bogiemon.drivers.base import Block, Source


@dataclass(frozen=True)
class DutySettings:
    """What [duty] sets, in seconds, with the stillness level of [health]."""

    measure_s: float  # of samples per measurement while the wagon runs
    cycle_s: float  # a measurement starts every cycle_s; equal to measure_s: no cycle
    standing_after_s: float  # still this long: the wagon stands
    probe_every_s: float  # while it stands, a listen every probe_every_s ...
    probe_s: float  # ... of probe_s
    standstill_rms_mps2: float

    @property
    def cycled(self) -> bool:
        return self.measure_s < self.cycle_s


class Phase(enum.Enum):
    MEASURING = "measuring"
    CYCLE_REST = "resting between measurements"
    STANDING = "resting, the wagon stands"
    PROBING = "listening for motion"


def is_still(block: Block, level_mps2: float) -> bool:
    """Whether every channel's standard deviation over the block is below level_mps2 (a block of
    fewer than two samples tells nothing: not still)."""
    accel = block.accel_mps2
    return accel.shape[0] >= 2 and bool((np.std(accel, axis=0) < level_mps2).all())


@dataclass
class DutyCounters:
    measurements: int = 0  # measurements begun (the first included)
    cycle_rests: int = 0  # rests between two measurements of the cycle
    standing_rests: int = 0  # rests of a standing wagon (each after a measurement or a probe)
    probes: int = 0  # listens that found the wagon still


class DutySource(Source):
    """The configured source, read on the duty cycle of DutySettings (module docstring)."""

    def __init__(
        self,
        inner: Source,
        settings: DutySettings,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.inner = inner
        self.settings = settings
        self.fs_hz = inner.fs_hz
        self.counters = inner.counters
        self.finite = inner.finite
        self.duty = DutyCounters(measurements=1)
        self.phase = Phase.MEASURING
        self._clock = clock
        self._sleep = sleep
        self._log = get_logger(component="duty")
        self._measuring_from_s: float | None = None  # samples' time the measurement began
        self._still_from_s: float | None = None  # samples' time the stillness began
        self._probing_from_s: float | None = None
        self._rest_until = 0.0  # the clock's time (live), the samples' (a recording)
        self._next_is_new_stream = False

    @property
    def last_error(self) -> str | None:  # type: ignore[override]  # the inner source's, as it changes
        return self.inner.last_error

    @property
    def resting(self) -> bool:  # type: ignore[override]
        return self.phase in (Phase.CYCLE_REST, Phase.STANDING)

    def close(self) -> None:
        self.inner.close()

    def read(self, timeout_s: float) -> Block | None:
        if self.resting:
            if self.finite:
                return self._skip_rest(timeout_s)
            remaining_s = self._rest_until - self._clock()
            if remaining_s > 0:
                self._sleep(min(remaining_s, timeout_s))
                return None
            self._end_rest()
        block = self.inner.read(timeout_s)
        return None if block is None else self._take(block)

    # -- the phases ------------------------------------------------------------------------------

    def _take(self, block: Block) -> Block | None:
        """What happens to a block read in the phase the source is in: passed on, or kept back."""
        s = self.settings
        if self.phase is Phase.PROBING:
            if self._probing_from_s is None:
                self._probing_from_s = block.start_s
            if is_still(block, s.standstill_rms_mps2):
                if block.end_s - self._probing_from_s >= s.probe_s:
                    self.duty.probes += 1
                    self._rest(Phase.STANDING, s.probe_every_s, block.end_s)
                return None
            self._log.info("the wagon moves again: measuring", after_probes=self.duty.probes)
            self._begin_measurement()
        if self._measuring_from_s is None:
            self._measuring_from_s = block.start_s
        if self._next_is_new_stream:
            block = replace(block, new_stream=True)
            self._next_is_new_stream = False
        if is_still(block, s.standstill_rms_mps2):
            if self._still_from_s is None:
                self._still_from_s = block.start_s
            if block.end_s - self._still_from_s >= s.standing_after_s:
                self._log.info("the wagon stands: resting", probe_every_s=s.probe_every_s, probe_s=s.probe_s)
                self._rest(Phase.STANDING, s.probe_every_s, block.end_s)
                return block
        else:
            self._still_from_s = None
        if s.cycled and block.end_s - self._measuring_from_s >= s.measure_s:
            self._log.info("measured: resting until the next measurement", rest_s=s.cycle_s - s.measure_s)
            self._rest(Phase.CYCLE_REST, s.cycle_s - s.measure_s, block.end_s)
        return block

    def _begin_measurement(self) -> None:
        self.phase = Phase.MEASURING
        self.duty.measurements += 1
        self._measuring_from_s = self._still_from_s = self._probing_from_s = None
        self._next_is_new_stream = True

    def _rest(self, phase: Phase, duration_s: float, samples_end_s: float) -> None:
        self.phase = phase
        if phase is Phase.CYCLE_REST:
            self.duty.cycle_rests += 1
        else:
            self.duty.standing_rests += 1
        if self.finite:
            self._rest_until = samples_end_s + duration_s
        else:
            self.inner.pause()  # the device closed: no frame is read, none is decoded
            self._rest_until = self._clock() + duration_s

    def _end_rest(self) -> None:
        if self.phase is Phase.CYCLE_REST:
            self._begin_measurement()
        else:
            self.phase = Phase.PROBING
            self._probing_from_s = None

    def _skip_rest(self, timeout_s: float) -> Block | None:
        """A recording's rest: its samples before the rest's end are read and left out."""
        block = self.inner.read(timeout_s)
        if block is None or block.end_s <= self._rest_until:
            return None
        first = max(0, math.ceil((self._rest_until - block.start_s) * block.fs_hz - 1e-9))
        if first:
            block = Block(block.start_s + first / block.fs_hz, block.fs_hz, block.accel_mps2[first:], status=block.status)
        self._end_rest()
        return self._take(block)
