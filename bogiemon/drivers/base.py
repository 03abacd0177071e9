"""The source interface: what every driver delivers downstream, and the counters it keeps.

A source turns bytes or frames into Blocks: time-aligned (n, 3) samples of a1, a2, a3 in m/s^2
with the sample rate, the time of the first sample, whether samples were lost before it, and the
sensors' status bits. Nothing downstream ever sees a byte or a frame.
"""

from __future__ import annotations

import enum
import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field, fields
from typing import Self

import numpy as np
from numpy.typing import NDArray


class SensorStatus(enum.IntFlag):
    """Status bits a sensor reports with its samples (OR-ed over a block)."""

    OK = 0
    OVER_RANGE = 1  # a sample hit the converter's full scale: the value is clipped
    SENSOR_FAULT = 2  # the sensor's own self-test or supply monitor reports a fault


ALL_OK: tuple[SensorStatus, SensorStatus, SensorStatus] = (SensorStatus.OK,) * 3

# Time stamps a source accepts, in seconds from any origin: Unix time (candump -L, .blf, the
# kernel's receive stamps), or from a log's or a clock's start (.asc, an uptime, a CSV's own
# origin). What is not finite or lies beyond the year 2100 as Unix time either way is no clock's
# reading: the frame or row carrying it is counted and skipped (or the file refused), so nothing
# downstream, and no event in the store, ever has such a time.
MAX_TIME_S = 4_102_444_800.0  # 2100-01-01T00:00:00Z


def plausible_time(time_s: float) -> bool:
    """Whether time_s is a time stamp a source may pass on (finite, within +/-MAX_TIME_S)."""
    return -MAX_TIME_S <= time_s <= MAX_TIME_S  # False for NaN too


@dataclass(frozen=True)
class Block:
    """Consecutive, uniformly sampled accelerations of the three sensors.

    start_s: time of the first sample, seconds on the source's clock;
    accel_mps2: (n, 3) float64, columns a1, a2, a3 (specific force, gravity included or not);
    gap_before: samples were lost, or the stream (re)started, before this block: anything
      computed across this boundary must be discarded, never bridged;
    status: per sensor, the status bits seen in this block;
    new_stream: the block begins another stream on purpose (a duty cycle's measurement after a
      rest, daemon/duty.py): a new segment, as after gap_before, but no loss that the dropouts
      check counts.
    """

    start_s: float
    fs_hz: float
    accel_mps2: NDArray[np.float64]
    gap_before: bool = False
    status: tuple[SensorStatus, SensorStatus, SensorStatus] = ALL_OK
    new_stream: bool = False

    def __post_init__(self) -> None:
        if self.accel_mps2.ndim != 2 or self.accel_mps2.shape[1] != 3:
            raise ValueError(f"a block holds (n, 3) samples, got shape {self.accel_mps2.shape}")
        # The sources validate time stamps where they read them (a segment's samples may then run
        # past MAX_TIME_S by its length); a block past that with a time or rate that is not
        # finite is a bug in a driver, and must not reach windows and events.
        if not math.isfinite(self.start_s):
            raise ValueError(f"a block starts at {self.start_s!r} s: a time must be finite")
        if not (math.isfinite(self.fs_hz) and self.fs_hz > 0):
            raise ValueError(f"a block is sampled at {self.fs_hz!r} Hz: the rate must be finite and positive")

    @property
    def n_samples(self) -> int:
        return int(self.accel_mps2.shape[0])

    @property
    def end_s(self) -> float:
        """Time just after the last sample (where the next contiguous block starts)."""
        return self.start_s + self.n_samples / self.fs_hz


@dataclass
class HealthCounters:
    """Monotonic counters a source keeps about its input; read them, never reset them."""

    frames: int = 0  # frames, packets or rows accepted
    bad_frames: int = 0  # rejected: wrong length, bad CRC, undecodable, unknown id, unusable time stamp
    gaps: int = 0  # discontinuities passed downstream as gap_before
    timeouts: int = 0  # read() calls that returned nothing in time
    reconnects: int = 0  # times the device or bus was reopened
    extra: dict[str, int] = field(default_factory=dict)  # driver-specific counters

    def as_dict(self) -> dict[str, int]:
        out = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "extra"}
        out.update(self.extra)
        return out

    def add(self, name: str, n: int = 1) -> None:
        """Increase the driver-specific counter `name` by n (drivers list theirs at 0 up front)."""
        self.extra[name] = self.extra.get(name, 0) + n


class EndOfStream(Exception):
    """A finite source (a recording) has delivered its last block."""


class Source(ABC):
    """Where blocks come from. Implementations: CAN, serial, replay, in-memory (for tests)."""

    fs_hz: float
    counters: HealthCounters
    # The latest problem with the device, bus or file, in one line naming it (None: none yet);
    # for the daemon's log, next to the counters. A live source keeps it after recovering.
    last_error: str | None = None
    # A recording (ends with EndOfStream; the reader may wait for downstream rather than drop)
    # or a live stream (never waits: samples not taken in time are lost on the bus).
    finite: bool = False
    # At rest on purpose (a duty cycle, daemon/duty.py): it delivers nothing and is not stalled.
    resting: bool = False

    @abstractmethod
    def read(self, timeout_s: float) -> Block | None:
        """The next block, or None if nothing arrived within timeout_s.

        Raises EndOfStream after the last block of a finite source. A live source never raises
        for what the bus or the cable does: it counts it, reconnects, and reports a gap.
        """

    def behind_s(self) -> float:
        """How far a live source is behind real time: the seconds of samples it has received and
        not handed on, beyond the block it is filling (0 for a recording: it has no real time)."""
        return 0.0

    def close(self) -> None:  # noqa: B027 - optional for sources that hold nothing
        """Release the device or file."""

    def pause(self) -> None:  # noqa: B027 - a source that holds no device has nothing to release
        """Release the device for a while (a duty cycle's rest, daemon/duty.py); the next read takes
        it up again, as at the start: a new segment, and no loss or reconnection counted."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class MemorySource(Source):
    """A finite source over blocks held in memory: the test double of every driver."""

    def __init__(self, blocks: list[Block]) -> None:
        if not blocks:
            raise ValueError("a MemorySource needs at least one block")
        self.fs_hz = blocks[0].fs_hz
        self.counters = HealthCounters()
        self._blocks = list(blocks)
        self._next = 0

    def read(self, timeout_s: float) -> Block | None:
        if self._next >= len(self._blocks):
            raise EndOfStream
        block = self._blocks[self._next]
        self._next += 1
        self.counters.frames += block.n_samples
        if block.gap_before and self._next > 1:
            self.counters.gaps += 1
        return block
