"""The live sources' base (drivers/live.py) on a fake device and a fake clock: missing at start,
lost in the middle of a read, back again; counted, reported in one line, never raised, never bridged."""

from __future__ import annotations

import errno
from collections import deque

import can
import numpy as np
import pytest

from bogiemon.drivers.live import LiveSource, reason
from tests.drivers.frames import FS_HZ, check_blocks, coded_accel
from tests.drivers.test_replay import FakeClock  # time that moves only when the source sleeps

LOST = OSError(errno.EIO, "Input/output error")
GONE = OSError(errno.ENODEV, "No such device")


class FakeDevice:
    """One opening of the device: what each receive delivers, in turn (a count of instants, or an error)."""

    def __init__(self, script: deque[int | BaseException]) -> None:
        self.script = script
        self.closed = False


class FakeSource(LiveSource[FakeDevice]):
    """A live source over FakeDevice: the hooks only, as CanSource and SerialSource write them."""

    description = "fake device 'dev0'"

    def __init__(self, clock: FakeClock, missing: int = 0, close_raises: bool = False) -> None:
        super().__init__(FS_HZ, max_block_s=0.1, backoff_min_s=0.1, backoff_max_s=0.4, clock=clock, sleep=clock.sleep)
        self.clock = clock
        self.missing = missing  # openings that fail before the device is there
        self.close_raises = close_raises
        self.script: deque[int | BaseException] = deque()  # shared by every opening, as a stream is
        self.devices: list[FakeDevice] = []
        self.restarts = 0
        self.next_instant = 0
        self._start()

    def _open(self) -> FakeDevice:
        if self.missing:
            self.missing -= 1
            raise GONE
        self.devices.append(FakeDevice(self.script))
        return self.devices[-1]

    def _receive(self, device: FakeDevice, timeout_s: float, wanted_n: int) -> None:
        assert not device.closed
        if not device.script:
            self.clock.now_s += timeout_s  # the device had nothing: the read waited it out
            return
        item = device.script.popleft()
        if isinstance(item, BaseException):
            raise item
        k = np.arange(self.next_instant, self.next_instant + item)
        self.next_instant += item
        self.counters.frames += item
        self._queue.append(coded_accel(k), np.zeros((item, 3), np.uint8), np.zeros(item, bool), self.clock.now_s + k / FS_HZ)

    def _close(self, device: FakeDevice) -> None:
        device.closed = True
        if self.close_raises:
            raise OSError(errno.ENODEV, "No such device")

    def _restart(self) -> None:
        self.restarts += 1


def read_until(source: FakeSource, n: int, max_reads: int = 50) -> list:
    blocks, got = [], 0
    for _ in range(max_reads):
        if got >= n:
            break
        block = source.read(0.05)
        if block is not None:
            blocks.append(block)
            got += block.n_samples
    return blocks


class BurstSource(FakeSource):
    """A FakeSource whose device, after bit errors, delivers its instants in segments of three (each
    receive brings what it was asked for, or waits its timeout out when the script is done)."""

    def _receive(self, device: FakeDevice, timeout_s: float, wanted_n: int) -> None:
        if not device.script:
            self.clock.now_s += timeout_s
            return
        left = device.script[0]
        assert isinstance(left, int)
        n = min(left, wanted_n)
        device.script[0] = left - n
        if device.script[0] == 0:
            device.script.popleft()
        k = np.arange(self.next_instant, self.next_instant + n)
        self.next_instant += n
        self.counters.frames += n
        self._queue.append(coded_accel(k), np.zeros((n, 3), np.uint8), k % 3 == 0, self.clock.now_s + k / FS_HZ)


def test_after_a_burst_of_errors_every_queued_segment_goes_on_without_a_wait_on_the_device() -> None:
    clock = FakeClock()
    source = BurstSource(clock)  # blocks of 50 samples at most
    source.script.append(300)
    blocks = read_until(source, 300, max_reads=500)
    segments = check_blocks(blocks)
    assert len(segments) == 100 and np.concatenate(segments).tolist() == list(range(300))
    # One read waited on the device, the last: for the samples the open segment lacked, which never came.
    assert clock.now_s == pytest.approx(0.05)
    assert source.behind_s() == 0.0


def test_a_live_source_is_behind_by_what_it_holds_beyond_one_block() -> None:
    clock = FakeClock()
    source = BurstSource(clock)
    source.script.append(60)
    source._receive(source.devices[0], 1.0, 200)  # a read's worth more than a block (50), taken at once
    assert source.behind_s() == pytest.approx(10 / FS_HZ)
    read_until(source, 60, max_reads=100)
    assert source.behind_s() == 0.0


def test_a_device_missing_at_start_is_retried_with_backoff_and_never_raised() -> None:
    clock = FakeClock()
    source = FakeSource(clock, missing=3)
    assert not source.connected
    assert source.counters.extra["open_failures"] == 1
    assert source.last_error == "fake device 'dev0': cannot open: No such device; retrying in 0.1 s"
    assert source.read(0.05) is None and source.counters.timeouts == 1  # not yet due: waited, not retried
    while not source.connected:
        source.read(0.05)
    assert source.counters.extra["open_failures"] == 3
    assert source.last_error.endswith("retrying in 0.4 s")  # 0.1, 0.2, 0.4: doubled up to the ceiling
    assert source.counters.reconnects == 0  # the first open is not a reconnect
    assert clock.now_s == pytest.approx(0.1 + 0.2 + 0.4, abs=0.05 + 1e-9)


def test_a_closed_device_is_waited_for_without_spinning() -> None:
    clock = FakeClock()
    source = FakeSource(clock, missing=100)
    assert source.read(1.0) is None
    # One sleep per due attempt: until 0.1 s, then 0.2 s later, then 0.4 s later (the read ends at 1 s).
    assert len(clock.sleeps) <= 5 and sum(clock.sleeps) == pytest.approx(1.0)


def test_a_device_lost_in_the_middle_of_a_read_keeps_what_came_before_and_is_reopened() -> None:
    clock = FakeClock()
    source = FakeSource(clock)
    source.script.extend([30, 20, LOST])
    first = read_until(source, 50)
    assert source.read(0.05) is None  # the loss: no exception, nothing more delivered
    assert not source.connected and source.devices[0].closed
    assert source.counters.extra["disconnects"] == 1
    assert source.last_error == "fake device 'dev0': lost: Input/output error; reopening in 0.1 s"
    source.script.extend([40])
    second = read_until(source, 40)
    assert source.connected and len(source.devices) == 2 and source.counters.reconnects == 1
    # Before and after the outage are two segments, the second starting with gap_before.
    assert [(s[0], s[-1]) for s in check_blocks(first + second)] == [(0, 49), (50, 89)]
    assert source.counters.gaps == 1
    assert source.restarts == 3  # at the first open, at the loss, at the reopening


def test_samples_received_before_a_failure_in_the_same_read_are_delivered() -> None:
    clock = FakeClock()
    source = FakeSource(clock)
    source.script.extend([10, LOST])
    block = source.read(0.05)  # 10 samples, then the loss in the same read
    assert block is not None and block.n_samples == 10
    assert source.counters.extra["disconnects"] == 1


def test_the_backoff_starts_again_from_its_minimum_once_frames_flow() -> None:
    clock = FakeClock()
    source = FakeSource(clock, missing=2)
    while not source.connected:
        source.read(0.05)
    assert source.last_error.endswith("retrying in 0.2 s")
    source.script.extend([5, LOST])
    read_until(source, 5)
    source.read(0.01)
    assert source.last_error.endswith("reopening in 0.1 s")  # not 0.4: data flowed since the reopening


def test_a_loss_before_any_frame_keeps_doubling_the_wait() -> None:
    clock = FakeClock()
    source = FakeSource(clock)
    source.script.extend([LOST, LOST])
    source.read(0.01)
    assert source.last_error.endswith("reopening in 0.1 s")
    while len(source.devices) < 2:
        source.read(0.05)
    source.read(0.01)
    assert source.counters.extra["disconnects"] == 2
    assert source.last_error.endswith("reopening in 0.2 s")  # no frame came in between


def test_a_device_already_gone_when_closed_is_released_quietly() -> None:
    clock = FakeClock()
    source = FakeSource(clock, close_raises=True)
    source.script.extend([LOST])
    source.read(0.01)
    assert not source.connected and source.devices[0].closed
    source.script.extend([3])
    read_until(source, 3)
    source.close()
    assert not source.connected and source.devices[1].closed


def test_an_error_the_device_does_not_cause_is_a_bug_and_propagates() -> None:
    clock = FakeClock()
    source = FakeSource(clock)
    source.script.extend([ValueError("a bug in a decoder")])
    with pytest.raises(ValueError, match="a bug in a decoder"):
        source.read(0.01)


def test_the_live_counters_are_listed_at_zero_from_the_start() -> None:
    source = FakeSource(FakeClock())
    assert list(source.counters.extra)[-2:] == ["disconnects", "open_failures"]
    assert source.counters.extra == {"disconnects": 0, "open_failures": 0}


@pytest.mark.parametrize(
    ("exc", "expected"),
    [
        (OSError(errno.ENETDOWN, "Network is down"), "Network is down"),
        (can.CanOperationError("Failed to receive: Network is down", 100), "Failed to receive: Network is down [Error Code 100]"),
        (OSError("could not open port /dev/ttyX:\n[Errno 2] No such file"), "could not open port /dev/ttyX:"),
        (can.CanError(""), "CanError"),
        (RuntimeError("\nsecond line only"), "second line only"),
    ],
    ids=["strerror", "python-can", "first-line", "empty", "leading-newline"],
)
def test_a_reason_is_one_line_naming_the_cause(exc: BaseException, expected: str) -> None:
    assert reason(exc) == expected
