"""The serial ADC source: a pyserial port in, Blocks out; survives garbage and unplugging.

The ADC board streams the packets of drivers/serial_protocol.py. read(timeout_s) reads what
the port delivers for up to timeout_s (or until max_block_s of samples are in), parses it in
one batch, checks the sequence counter and returns the samples since the last call. Bytes
between packets and packets with a bad CRC are skipped and counted; the parser resynchronises
on the next sync word whose CRC holds. When the port fails (a USB adapter unplugged: EIO, the
device node gone) the source closes it and reopens the same path with exponential backoff, so
a stable name such as /dev/serial/by-id/... is picked up again when the adapter returns.

Time stamps: the serial line carries none, so a segment is anchored to the wall clock when its
first packet is parsed, less the time the packets parsed with it took to arrive at fs_hz.
"""

from __future__ import annotations

import math
import termios
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import serial

from bogiemon.drivers.live import LiveSource
from bogiemon.drivers.segments import SequenceTracker, TimestampGuard
from bogiemon.drivers.serial_protocol import PACKET_SIZE, SEQUENCE_MODULUS, PacketParser
from bogiemon.drivers.counters import counters

SERIAL_COUNTERS = counters("crc_errors", "garbage_bytes", "duplicates", "out_of_order", "lost_samples", "disconnects", "open_failures")
# The sequence counter wraps after 131 s at 500 Hz; half of that is far beyond any pause the
# line can have without the port failing, so silence only matters for a stalled board.
MAX_SILENCE_S = 5.0


def open_serial_port(port: str, baudrate: int) -> serial.Serial:
    """The port in raw 8N1 without flow control, locked against a second reader."""
    return serial.Serial(
        port=port,
        baudrate=baudrate,
        bytesize=serial.EIGHTBITS,
        parity=serial.PARITY_NONE,
        stopbits=serial.STOPBITS_ONE,
        timeout=0,
        xonxoff=False,
        rtscts=False,
        dsrdtr=False,
        exclusive=True,
    )


class SerialSource(LiveSource[Any]):  # a pyserial port, or a test's double of one
    """Blocks from the serial ADC board (docs/drivers.md, serial protocol).

    The read loop, the counting and the reconnection are LiveSource's; this class opens and
    closes the port and turns its bytes into samples.
    """

    device_errors = (serial.SerialException, OSError, termios.error)
    open_errors = (*device_errors, ValueError)  # pyserial refuses some paths and settings with ValueError

    def __init__(
        self,
        port: str,
        baudrate: int,
        fs_hz: float,
        max_block_s: float = 1.0,
        backoff_min_s: float = 0.5,
        backoff_max_s: float = 30.0,
        opener: Callable[[str, int], Any] = open_serial_port,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        wall_clock: Callable[[], float] = time.time,
    ) -> None:
        super().__init__(fs_hz, max_block_s, backoff_min_s, backoff_max_s, clock, sleep)
        self.port = port
        self.baudrate = baudrate
        self.description = f"serial port {port}"
        for name in SERIAL_COUNTERS:
            self.counters.extra[name] = 0
        self._opener = opener
        self._wall_clock = wall_clock
        self._parser = PacketParser()
        self._tracker = SequenceTracker(SEQUENCE_MODULUS, MAX_SILENCE_S)
        # Receive times come from the wall clock at each read, so a backlog read in two parts
        # overlaps by design: only non-finite and implausible stamps are refused, not late ones.
        self._guard = TimestampGuard(self.counters, tolerance_s=math.inf)
        self._start()

    def _open(self) -> Any:
        port = self._opener(self.port, self.baudrate)
        port.reset_input_buffer()  # bytes queued while nobody listened are stale
        return port

    def _receive(self, device: Any, timeout_s: float, wanted_n: int) -> None:
        device.timeout = timeout_s
        # pyserial returns when wanted_n packets' bytes are in or the timeout expires: one
        # wake-up per block rather than per packet.
        data = device.read(wanted_n * PACKET_SIZE)
        if data:
            self._parse(data, self._wall_clock())

    def _close(self, device: Any) -> None:
        device.close()

    def _unread_n(self, device: Any) -> int:
        try:
            return int(device.in_waiting) // PACKET_SIZE  # the kernel's count (a tty's 4 KiB at most)
        except self.device_errors:
            return 0  # gone: the next read says so

    def _restart(self) -> None:
        self._parser.reset()
        self._tracker.restart()

    def _parse(self, data: bytes, received_s: float) -> None:
        packets = self._parser.feed(data)
        self.counters.add("crc_errors", packets.crc_errors)
        self.counters.add("garbage_bytes", packets.garbage_bytes)
        self.counters.bad_frames += packets.crc_errors
        k = packets.sequence.shape[0]
        if k == 0:
            return
        # Packet i was complete (k - 1 - i) sample periods before the last one, which was
        # complete at most one read ago: receive times spaced at fs_hz, ending now.
        times_s = received_s - (k - 1 - np.arange(k)) / self.fs_hz
        passed = self._guard.check(times_s)
        self.counters.frames += int(passed.sum())
        if not passed.all():
            sequence, accel_mps2, status, times_s = packets.sequence[passed], packets.accel_mps2[passed], packets.status[passed], times_s[passed]
        else:
            sequence, accel_mps2, status = packets.sequence, packets.accel_mps2, packets.status
        verdict = self._tracker.check(sequence, times_s)
        if verdict.duplicates:
            self.counters.add("duplicates", verdict.duplicates)
        if verdict.out_of_order:
            self.counters.add("out_of_order", verdict.out_of_order)
        if verdict.lost:
            self.counters.add("lost_samples", verdict.lost)
        keep = verdict.accept
        self._queue.append(accel_mps2[keep], status[keep], verdict.new_segment[keep], times_s[keep])
