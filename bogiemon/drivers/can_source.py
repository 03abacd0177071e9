"""The CAN source: a python-can bus in, Blocks out; survives what a real bus does.

The bus comes from a BusPort, the one extension point. CanBusPort opens a python-can bus through
drivers/canbus.py: kind 'socketcan' on a gateway (can0, vcan0), 'virtual' for tests and
in-process benches. canbus.py instantiates the interface class directly with every setting
spelled out, never `can.Bus(...)`, so no ~/.canrc, can.ini or CAN_* environment variable is read.

The port also says how the frames come off the bus (drivers/can_frames.py), and that is the one
other place where the kinds differ: a bus with a socket (SocketCAN) is read in batches, every
frame queued on the socket in one recvmmsg(2) parsed with numpy, because python-can's SocketCAN
receive costs a select, a recvmsg and a Message per frame (it has no batch receive; Python's
socket module has no recvmmsg) and that was most of the reader's CPU; the virtual bus, an
in-process queue of Messages, has its queue taken whole (can_frames.QueueFrameReader), and any
other python-can bus is read through its recv. Past the reader, frames are
the columns of a FrameBatch and everything is the same code. The socket reader is tested on this
kernel's datagram sockets carrying the same struct can_frame bytes, against python-can's own
parsing (tests/drivers/test_can_frames.py), as AF_CAN cannot be created here.

read(timeout_s) gathers frames for up to timeout_s, decodes them in one batch and returns the
samples received since the last call: a Block as soon as max_block_s of samples are in or a
segment ends, else at timeout_s whatever arrived (None if nothing did). While a block fills, the
reader does not wake for every frame: once the bus's queue is drained it sleeps coalesce_s (by
default the time 100 frames take, at most 0.2 s: 0.2 s for the hub, 50 ms per node at 500 Hz)
and then takes everything that arrived meanwhile, the frames keeping their receive times. At
500 Hz that is 5 or 20 wake-ups a second instead of 500 or 2000 (`make bench-drivers`); a
block's last sample waits at most coalesce_s longer.

The read loop, the counting and the reconnection are drivers/live.py's: when the bus fails (an
interface unplugged or deleted, a closed channel) the source counts it, closes the bus, and
reopens it with exponential backoff on later calls; the next samples start a new segment.
"""

from __future__ import annotations

import queue
import socket
import struct
import time
from abc import ABC, abstractmethod
from collections.abc import Callable

import can

from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.can_frames import BusFrameReader, FrameReader, QueueFrameReader, SocketFrameReader
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.canbus import BusRole, bus_kind, open_bus
from bogiemon.drivers.live import LiveSource

# Linux socket options Python's socket module does not name (asm-generic/socket.h values,
# those of x86, arm and arm64).
SO_RCVBUFFORCE = 33
SO_MEMINFO = 55
SK_MEMINFO_DROPS = 8  # index in the u32 array SO_MEMINFO returns (Linux >= 4.6)
# How long the reader lets frames accumulate once the bus queue is drained, by default: the
# time COALESCE_FRAMES take to arrive, at most MAX_COALESCE_S (0.2 s for the hub at 500 Hz, 50 ms
# per node). Each wake-up costs a sleep, a system call and a hand-over of the interpreter lock
# whatever it brings: per node, 12.5 ms (25 frames) cost a third more CPU than 50 ms
# (bench/bench_drivers.py), and the hub's 20 wake-ups a second at the earlier cap of 50 ms were
# a tenth of the daemon's CPU. The socket's receive buffer must hold them meanwhile: the few
# hundred frames it holds even where net.core.rmem_max is left at its default (docs/drivers.md)
# are several times 100. A window's verdict waits for its last block: 0.2 s on a 10 s hop.
COALESCE_FRAMES = 100
MAX_COALESCE_S = 0.2
# The most frames gathered before they are decoded: a block's worth up to this many (recvmmsg
# takes at most 1024 messages a call, UIO_MAXIOV), so that a reader's buffers stay small (128
# bytes a frame) whatever max_block_s and fs_hz are; a larger block is gathered in several.
MAX_BATCH_FRAMES = 1024


class BusPort(ABC):
    """How a CanSource gets (and gets again) its bus, and takes its frames off it."""

    description: str

    @abstractmethod
    def open(self) -> can.BusABC:
        """A new bus; raises OSError or can.CanError if the interface is not there."""

    def frame_reader(self, bus: can.BusABC, capacity: int) -> FrameReader:
        """What takes bus's frames off it, up to capacity between two takes: python-can's recv here."""
        return BusFrameReader(bus)

    def dropped_frames(self, bus: can.BusABC) -> int | None:
        """Frames the bus's receive queue had to drop so far, if the interface can tell."""
        return None


class CanBusPort(BusPort):
    """A python-can bus of a kind of drivers/canbus.py ('socketcan', 'virtual') on one channel.

    Where the bus has a socket (SocketCAN), its frames are read off that socket in batches
    (drivers/can_frames.py: SocketFrameReader, one recvmmsg(2) for all the frames queued), and
    its receive buffer holds the frames that arrive while the daemon is busy; each frame costs
    the kernel a whole socket buffer (several hundred bytes), not 16. SO_RCVBUFFORCE (needs
    CAP_NET_ADMIN) sets it past net.core.rmem_max; without the capability SO_RCVBUF is capped
    there. effective_receive_buffer_bytes is what the kernel granted (None: no socket, or
    receive_buffer_bytes None leaves the kernel's default). The kernel's drop count is read from
    the same socket. A virtual bus has none of these: its queue of Messages is taken whole.
    """

    def __init__(self, kind: str, channel: str, receive_buffer_bytes: int | None = None) -> None:
        self.kind = kind
        self.channel = channel
        self.receive_buffer_bytes = receive_buffer_bytes
        self.description = bus_kind(kind).description.format(channel=channel)  # an unknown kind fails here
        self.effective_receive_buffer_bytes: int | None = None

    def open(self) -> can.BusABC:
        bus = open_bus(self.kind, self.channel, BusRole.RECEIVER)
        sock = getattr(bus, "socket", None)
        if self.receive_buffer_bytes is not None and isinstance(sock, socket.socket):
            self.effective_receive_buffer_bytes = set_receive_buffer(sock, self.receive_buffer_bytes)
        return bus

    def frame_reader(self, bus: can.BusABC, capacity: int) -> FrameReader:
        sock = getattr(bus, "socket", None)
        if isinstance(sock, socket.socket):
            return SocketFrameReader(sock, capacity)
        if isinstance(getattr(bus, "queue", None), queue.Queue) and bus.filters is None:
            return QueueFrameReader(bus)  # python-can's virtual bus: its queue taken whole
        return BusFrameReader(bus)

    def dropped_frames(self, bus: can.BusABC) -> int | None:
        sock = getattr(bus, "socket", None)
        return socket_drops(sock) if isinstance(sock, socket.socket) else None


def set_receive_buffer(sock: socket.socket, size_bytes: int) -> int:
    """Ask for size_bytes of receive buffer (forced if permitted); returns what the kernel granted."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, size_bytes)
    except OSError:  # EPERM without CAP_NET_ADMIN: fall back to the capped option
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, size_bytes)
    return sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)


def socket_drops(sock: socket.socket) -> int | None:
    """The kernel's count of packets this socket dropped for want of receive buffer (sk_drops).

    The same number SO_RXQ_OVFL would attach to each received frame, read with SO_MEMINFO
    instead, because python-can's SocketCAN receive path reserves room for exactly one control
    message (the timestamp) and would truncate a second. None where the kernel cannot say.
    """
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * (SK_MEMINFO_DROPS + 1))
    except OSError:
        return None
    if len(raw) < 4 * (SK_MEMINFO_DROPS + 1):
        return None
    return int(struct.unpack_from("=I", raw, 4 * SK_MEMINFO_DROPS)[0])


class CanSource(LiveSource[can.BusABC]):
    """Blocks from a CAN bus carrying one of the DBC's layouts (docs/drivers.md).

    The read loop, the counting and the reconnection are LiveSource's; this class opens and
    closes the bus through its port and gathers and decodes its frames.
    """

    device_errors = (can.CanError, OSError)
    open_errors = device_errors

    def __init__(
        self,
        port: BusPort,
        layout: CanLayout,
        fs_hz: float,
        max_block_s: float = 1.0,
        coalesce_s: float | None = None,
        backoff_min_s: float = 0.5,
        backoff_max_s: float = 30.0,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        super().__init__(fs_hz, max_block_s, backoff_min_s, backoff_max_s, clock, sleep)
        self.port = port
        self.layout = layout
        self.description = port.description
        if coalesce_s is None:
            coalesce_s = min(MAX_COALESCE_S, COALESCE_FRAMES / (fs_hz * layout.frames_per_instant))
        if coalesce_s < 0:
            raise ValueError(f"coalesce_s must be >= 0 (0: wake for every frame), got {coalesce_s}")
        self.coalesce_s = coalesce_s
        self._decoder = CanFrameDecoder(layout, fs_hz, self.counters, self._queue)
        self._frames_per_instant = layout.frames_per_instant
        self._batch_frames = min(self.max_block_n * self._frames_per_instant, MAX_BATCH_FRAMES)
        self._reader: FrameReader | None = None
        self._drops_seen = 0  # the current bus's kernel drop count already counted
        self._start()

    def _open(self) -> can.BusABC:
        bus = self.port.open()
        try:
            self._reader = self.port.frame_reader(bus, self._batch_frames)
        except BaseException:
            bus.shutdown()
            raise
        self._drops_seen = self.port.dropped_frames(bus) or 0
        return bus

    def _close(self, device: can.BusABC) -> None:
        self._reader = None
        device.shutdown()

    def _restart(self) -> None:
        self._decoder.restart()

    def _receive(self, device: can.BusABC, timeout_s: float, wanted_n: int) -> None:
        """Gather frames until wanted_n instants' worth (or a batch) are in or timeout_s is over, then decode them."""
        reader = self._reader
        assert reader is not None
        wanted = min(wanted_n * self._frames_per_instant, self._batch_frames)
        end_s = self._clock() + timeout_s
        try:
            got = reader.receive(wanted, timeout_s)  # an idle bus: block until a frame comes
            while 0 < got < wanted:
                more = self._more_frames(reader, wanted - got, end_s)
                if more == 0:
                    break
                got += more
        finally:
            self._decoder.feed_frames(reader.take())  # the frames received before a failure too
        self._count_kernel_drops(device)

    def _more_frames(self, reader: FrameReader, max_n: int, end_s: float) -> int:
        """More frames for a batch being gathered (the queue was drained): 0 once none comes before end_s.

        Past the deadline it still takes what is already queued (timeout 0). With coalesce_s > 0
        the drained queue is left to refill for coalesce_s instead of waking for every frame.
        """
        if self.coalesce_s == 0:
            return reader.receive(max_n, max(0.0, end_s - self._clock()))
        pause_s = min(self.coalesce_s, end_s - self._clock())
        if pause_s > 0:
            self._sleep(pause_s)
        return reader.receive(max_n, 0.0)

    def _count_kernel_drops(self, bus: can.BusABC) -> None:
        drops = self.port.dropped_frames(bus)
        if drops is not None and drops > self._drops_seen:
            self.counters.add("dropped_by_kernel", drops - self._drops_seen)
            # No restart here: the loss shows in the counters and, for long losses, in the
            # receive times (kernel time stamps), exactly where it happened in the stream.
            self._drops_seen = drops
