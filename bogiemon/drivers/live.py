"""The live sources' base: the read loop, the counting and the open/lose/close cycle, written once.

A live source reads a device that can go away under it (a CAN interface unplugged, a USB serial
adapter pulled). LiveSource owns what every such source does the same way, as python-can's
`BusABC.recv` owns the receive loop around each interface's `_recv_internal`: read(timeout_s)
gathers samples until a block is ready or the time is up; a device that fails is counted, closed
and reopened with the one backoff (drivers/reconnect.py) on later reads; a device missing at
start is retried the same way; `last_error` names the device and the reason in one line.
A block already queued goes out at once, never after a wait on the device: a burst of errors
splits the stream into many short segments, and were each handed on only at a read's timeout the
source would fall behind real time and stay there. So it holds at most a block being filled and
one read's worth, and is back at real time as soon as the pipeline has taken what the device
buffered meanwhile; `behind_s()` says how far behind it is (the pipeline logs it). A
subclass writes only its hooks: `_open` (a new device), `_receive` (read what the device has for
up to the time given, into the sample queue), `_close`, `_restart` (its decoding state,
when the stream restarts) and `_unread_n` (what the device holds unread, if it can tell).
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Callable
from typing import Generic, TypeVar

from bogiemon.drivers.base import Block, HealthCounters, Source
from bogiemon.drivers.reconnect import Backoff
from bogiemon.drivers.segments import SampleQueue
from bogiemon.drivers.counters import counters

LIVE_COUNTERS = counters("disconnects", "open_failures")
# How long a read waits at the least while the device is closed and its reopening not yet due:
# a wait of 0 would spin.
MIN_WAIT_S = 1e-3

DeviceT = TypeVar("DeviceT")  # what a source opens: a python-can bus, a pyserial port


class LiveSource(Source, Generic[DeviceT]):
    """A source on a device that can fail: the loop, the counters, the reconnection; hooks below.

    `device_errors` are what the device's receive and close raise for what the hardware does
    (never a bug of ours: those propagate); `open_errors` what its opening raises for a device
    that is not there. `description` names the device in `last_error`.
    """

    description: str
    device_errors: tuple[type[BaseException], ...] = (OSError,)
    open_errors: tuple[type[BaseException], ...] = (OSError,)

    def __init__(
        self,
        fs_hz: float,
        max_block_s: float,
        backoff_min_s: float,
        backoff_max_s: float,
        clock: Callable[[], float],
        sleep: Callable[[float], None],
    ) -> None:
        """The shared state; a subclass builds its own parts, then calls `_start()`."""
        self.fs_hz = fs_hz
        self.counters = HealthCounters()
        self.max_block_n = max(1, round(max_block_s * fs_hz))
        self._queue = SampleQueue(fs_hz)
        self._backoff = Backoff(backoff_min_s, backoff_max_s, clock)
        self._clock = clock
        self._sleep = sleep
        self._device: DeviceT | None = None
        self._opened_before = False
        self._frames_at_open = 0

    # ---- the hooks ------------------------------------------------------------------------

    @abstractmethod
    def _open(self) -> DeviceT:
        """A newly opened device; raises one of `open_errors` if it is not there."""

    @abstractmethod
    def _receive(self, device: DeviceT, timeout_s: float, wanted_n: int) -> None:
        """Read what the device delivers for up to timeout_s, or until wanted_n more samples are in.

        Hands the samples to the queue (samples read before a failure too), counts frames in
        `counters.frames`, and raises one of `device_errors` when the device fails.
        """

    @abstractmethod
    def _close(self, device: DeviceT) -> None:
        """Release the device; may raise one of `device_errors` if it is already gone."""

    def _restart(self) -> None:  # noqa: B027 - a source with no decoding state has nothing to reset
        """The stream starts again (the device was opened or lost): reset the decoding state."""

    def _unread_n(self, device: DeviceT) -> int:
        """Samples the device has received and not yet given us, where it can tell (else 0)."""
        return 0

    # ---- the loop -------------------------------------------------------------------------

    @property
    def connected(self) -> bool:
        return self._device is not None

    def read(self, timeout_s: float) -> Block | None:
        deadline_s = self._clock() + timeout_s
        while not self._queue.full_block_ready(self.max_block_n):
            remaining_s = deadline_s - self._clock()
            if remaining_s <= 0:
                break
            if self._device is None and not self._try_open():
                self._sleep(min(remaining_s, max(self._backoff.due_in_s(), MIN_WAIT_S)))
                continue
            device = self._device
            assert device is not None  # open, or opened just above
            try:
                self._receive(device, remaining_s, max(1, self.max_block_n - self._queue.n_pending))
            except self.device_errors as exc:
                self._lose(exc)
                continue
            if self.counters.frames > self._frames_at_open:
                self._backoff.reset()  # data flows: a later loss retries quickly again
        block = self._queue.take(self.max_block_n)
        self.counters.gaps = self._queue.gaps
        if block is None:
            self.counters.timeouts += 1
        return block

    def behind_s(self) -> float:
        # Blocks go out as soon as one is ready (read() never waits on the device while one is
        # queued), so what is held beyond one block is what the pipeline has yet to take.
        held_n = self._queue.n_pending + (self._unread_n(self._device) if self._device is not None else 0)
        return max(0, held_n - self.max_block_n) / self.fs_hz

    def close(self) -> None:
        self._close_device()

    def pause(self) -> None:
        """Close the device on purpose (Source.pause): the samples not handed out yet are dropped,
        and the next read opens it again as the first did (no disconnect, reconnect or gap counted)."""
        self._close_device()
        self._restart()
        self._queue.discard()
        self._opened_before = False

    # ---- the open/lose/close cycle ---------------------------------------------------------

    def _start(self) -> None:
        """The first attempt to open, at construction: a missing device is retried on reads, never raised."""
        for name in LIVE_COUNTERS:  # after the subclass's own counters, so they keep their order
            self.counters.extra.setdefault(name, 0)
        self._try_open()

    def _try_open(self) -> bool:
        """Open the device if the backoff allows; False (counted, last_error set) if it is not there."""
        if self._backoff.due_in_s() > 0:
            return False
        try:
            device = self._open()
        except self.open_errors as exc:
            self.counters.add("open_failures")
            wait_s = self._backoff.failed()
            self.last_error = f"{self.description}: cannot open: {reason(exc)}; retrying in {wait_s:g} s"
            return False
        if self._opened_before:
            self.counters.reconnects += 1
        self._opened_before = True
        self._device = device
        self._frames_at_open = self.counters.frames
        self._restart_stream()
        return True

    def _lose(self, exc: BaseException) -> None:
        self.counters.add("disconnects")
        wait_s = self._backoff.failed()
        self.last_error = f"{self.description}: lost: {reason(exc)}; reopening in {wait_s:g} s"
        self._close_device()
        self._restart_stream()

    def _restart_stream(self) -> None:
        self._restart()
        self._queue.close_segment()  # whatever comes next starts a new segment

    def _close_device(self) -> None:
        device, self._device = self._device, None
        if device is not None:
            try:
                self._close(device)
            except self.device_errors:
                pass  # the device is already gone; nothing left to release


def reason(exc: BaseException) -> str:
    """Why a device failed, in one line: the OS's words where it gave them, else the message's first line."""
    if isinstance(exc, OSError) and exc.strerror:
        return str(exc.strerror)
    return next((line for line in str(exc).splitlines() if line.strip()), type(exc).__name__)
