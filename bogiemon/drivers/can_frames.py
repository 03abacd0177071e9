"""CAN frames as columns: what a bus delivered, read in batches, before anything is decoded.

A FrameBatch holds n received frames as numpy arrays (receive time, identifier key, data length,
the first 8 data bytes, flags), so the decoder works on whole batches and no Python object is
made per frame past the point where the frames come in. A FrameReader takes frames off an open
bus in batches, in one of two ways:

- BusFrameReader, through python-can's `recv` (any python-can bus): python-can makes a Message per
  frame, which becomes a column here. QueueFrameReader takes what python-can's virtual bus (the
  tests', the demo's and the benches') has queued in one step instead of a `recv` per frame.
- SocketFrameReader, for a bus with a socket delivering the kernel's `struct can_frame` datagrams
  (SocketCAN's CAN_RAW socket): up to a few hundred frames per system call with recvmmsg(2) into
  preallocated buffers, parsed with numpy. python-can's SocketCAN receive path costs a select(2),
  a recvmsg(2) and a Message per frame (python-can has no batch receive, and Python's socket
  module no recvmmsg), which at 2000 frames/s (the per-node layout) is most of a daemon's CPU.
  The socket is python-can's, opened and set up by it (drivers/canbus.py); only the reading is
  ours. The tests run this reader on datagram sockets of this kernel carrying the same bytes
  (this development kernel has no AF_CAN) and check it against python-can's own parsing.
"""

from __future__ import annotations

import ctypes
import errno
import functools
import math
import os
import queue
import select
import socket
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from operator import attrgetter
from typing import Protocol

import can
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.candb import CAN_EFF_KEY

# Error classes in the identifier of a SocketCAN error frame (linux/can/error.h).
CAN_ERR_CRTL = 0x004  # controller problem, details in data[1]
CAN_ERR_BUSOFF = 0x040
CAN_ERR_CRTL_RX_OVERFLOW = 0x01  # data[1]: the controller's receive FIFO overflowed
CAN_STD_ID_MAX = 0x7FF  # the largest 11-bit identifier
CAN_EXT_ID_MAX = 0x1FFFFFFF  # the largest 29-bit identifier

# FrameBatch.flags bits.
REMOTE = 1  # a remote-request frame
ERROR = 2  # an error frame (the identifier holds the error class)
BUS_OFF = 4  # an error frame reporting bus-off
RX_OVERFLOW = 8  # an error frame reporting the controller's receive FIFO overflowed

# The kernel's struct can_frame (linux/can.h) and the flags in its can_id.
CAN_MTU = 16
CAN_EFF_FLAG = 0x80000000
CAN_RTR_FLAG = 0x40000000
CAN_ERR_FLAG = 0x20000000
CAN_FRAME = np.dtype([("can_id", "=u4"), ("len", "u1"), ("pad", "u1"), ("res0", "u1"), ("len8_dlc", "u1"), ("data", "u1", (8,))])
# SO_TIMESTAMPNS (asm-generic/socket.h, the value of x86, arm and arm64; python-can sets the same
# option on its SocketCAN socket): each frame carries its kernel receive time as a struct
# timespec of two C longs, as python-can reads it.
SO_TIMESTAMPNS = 35
TIMESPEC = np.dtype([("sec", np.dtype(ctypes.c_long)), ("nsec", np.dtype(ctypes.c_long))])
CONTROL_SPACE = socket.CMSG_SPACE(TIMESPEC.itemsize)  # control bytes per frame
CMSG_DATA_OFFSET = socket.CMSG_LEN(0)
CMSG_HEADER = np.dtype([("len", np.dtype(ctypes.c_size_t)), ("level", np.intc), ("type", np.intc)])
CMSG_NEEDED = socket.CMSG_LEN(TIMESPEC.itemsize)
# The header of the control message the kernel writes for a receive time, as bytes.
TIMESTAMP_HEADER = np.array([(CMSG_NEEDED, socket.SOL_SOCKET, SO_TIMESTAMPNS)], CMSG_HEADER).view(np.uint8)


@dataclass(frozen=True)
class FrameBatch:
    """n received CAN frames in arrival order, as columns.

    time_s: receive times in seconds (NaN where the stamp is no number: the decoder's check
      drops it); key: identifier | CAN_EFF_KEY for 29-bit ones, -1 for an identifier no CAN frame
      can carry; length: data bytes (0 for a remote frame, as python-can has it); data: (n, 8)
      the first 8 data bytes, zero beyond length; flags: REMOTE, ERROR, BUS_OFF, RX_OVERFLOW bits.
    """

    time_s: NDArray[np.float64]
    key: NDArray[np.int64]
    length: NDArray[np.int64]
    data: NDArray[np.uint8]
    flags: NDArray[np.uint8]

    @property
    def n(self) -> int:
        return int(self.key.shape[0])

    def __getitem__(self, index: slice | NDArray[np.bool_] | NDArray[np.intp]) -> FrameBatch:
        return FrameBatch(self.time_s[index], self.key[index], self.length[index], self.data[index], self.flags[index])

    @classmethod
    def empty(cls) -> FrameBatch:
        return cls(np.zeros(0), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 8), np.uint8), np.zeros(0, np.uint8))

    @classmethod
    def from_messages(cls, messages: Sequence[can.Message]) -> FrameBatch:
        """The columns of python-can Messages (a bus's, or a log's as python-can read it)."""
        n = len(messages)
        if n == 0:
            return cls.empty()
        remote = np.fromiter(map(_IS_REMOTE, messages), bool, n)
        error = np.fromiter(map(_IS_ERROR, messages), bool, n)
        datas = list(map(_DATA, messages))
        length = np.fromiter(map(len, datas), np.int64, n)
        raw = np.frombuffer(b"".join(datas), np.uint8)
        if bool((length == 8).all()):  # every frame 8 bytes long, as the hub's
            data = raw.reshape(n, 8).copy()
        else:
            data = np.zeros((n, 8), np.uint8)
            start = np.cumsum(length) - length
            inside = np.arange(8) < length[:, None]
            data[inside] = raw[(start[:, None] + np.arange(8))[inside]]
        flags = remote * np.uint8(REMOTE) | error * np.uint8(ERROR)
        for i in np.flatnonzero(error).tolist():  # rare: their class bits, read as python-can has them
            flags[i] |= _error_bits(messages[i])
        return cls(_times_of(messages), _keys_of(messages), length, data, flags)


_IS_REMOTE = attrgetter("is_remote_frame")
_IS_ERROR = attrgetter("is_error_frame")
_DATA = attrgetter("data")


def _error_bits(message: can.Message) -> int:
    error_class = message.arbitration_id
    bits = 0
    if error_class & CAN_ERR_CRTL and len(message.data) > 1 and message.data[1] & CAN_ERR_CRTL_RX_OVERFLOW:
        bits |= RX_OVERFLOW
    if error_class & CAN_ERR_BUSOFF:
        bits |= BUS_OFF
    return bits


def _times_of(messages: Sequence[can.Message]) -> NDArray[np.float64]:
    """The frames' receive times in seconds; NaN for a stamp that is not a number (the guard drops it)."""
    try:
        return np.fromiter(map(_TIMESTAMP, messages), np.float64, len(messages))
    except (TypeError, ValueError, OverflowError):
        return np.array([_as_float(m.timestamp) for m in messages], dtype=np.float64)


_TIMESTAMP = attrgetter("timestamp")


def _as_float(value: object) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return math.nan


def _keys_of(messages: Sequence[can.Message]) -> NDArray[np.int64]:
    """Frame keys (identifier | CAN_EFF_KEY for 29-bit ones); -1 for an identifier no CAN frame can carry.

    python-can's readers take identifiers as written: an .asc line may hold one too large for a
    C long, and a standard frame's beyond 11 bits would alias a 29-bit key.
    """
    n = len(messages)
    extended = np.fromiter(map(_IS_EXTENDED, messages), bool, n)  # each value's truth, as bool() has it
    try:
        ids = np.fromiter(map(_ARBITRATION_ID, messages), np.int64, n)
    except (TypeError, ValueError, OverflowError):
        ids = np.fromiter((_id_or_minus_one(m.arbitration_id) for m in messages), np.int64, n)
    valid = (ids >= 0) & (ids <= np.where(extended, CAN_EXT_ID_MAX, CAN_STD_ID_MAX))
    return np.where(valid, ids | np.where(extended, CAN_EFF_KEY, 0), -1)


_ARBITRATION_ID = attrgetter("arbitration_id")
_IS_EXTENDED = attrgetter("is_extended_id")


def _id_or_minus_one(arbitration_id: object) -> int:
    return arbitration_id if isinstance(arbitration_id, int) and 0 <= arbitration_id <= CAN_EXT_ID_MAX else -1


def frames_from_datagrams(
    frames: NDArray[np.uint8],
    received_bytes: NDArray[np.integer],
    msg_flags: NDArray[np.integer],
    control: NDArray[np.uint8],
    control_bytes: NDArray[np.integer],
) -> FrameBatch:
    """The columns of k `struct can_frame` datagrams as recvmmsg(2) left them, as python-can reads them.

    frames (k, CAN_MTU) and received_bytes (k,): each datagram and its length; msg_flags (k,):
    MSG_TRUNC where it was longer; control (k, CONTROL_SPACE) and control_bytes (k,): its control
    message, the SO_TIMESTAMPNS receive time. A datagram that is not exactly one classical frame
    has key -1 (an unknown identifier); a missing or malformed time stamp is NaN. Copies: the
    buffers are reused.
    """
    k = frames.shape[0]
    frame = np.ascontiguousarray(frames).view(CAN_FRAME).reshape(k)
    whole = (np.asarray(received_bytes) == CAN_MTU) & ((np.asarray(msg_flags) & socket.MSG_TRUNC) == 0)
    times_s = _receive_times(control, control_bytes)
    can_id = frame["can_id"].astype(np.int64)
    length = np.minimum(frame["len"], 8).astype(np.int64)  # python-can keeps at most a classical frame's 8 bytes
    if bool(whole.all()) and not bool((can_id & ~CAN_STD_ID_MAX).any()):
        # The steady state: whole data frames with 11-bit identifiers, no flag in can_id.
        data = frame["data"] if bool((length == 8).all()) else frame["data"] * (np.arange(8) < length[:, None])
        return FrameBatch(times_s, can_id, length, data.astype(np.uint8), np.zeros(k, np.uint8))
    extended = (can_id & CAN_EFF_FLAG) != 0
    remote = (can_id & CAN_RTR_FLAG) != 0
    error = (can_id & CAN_ERR_FLAG) != 0
    arbitration_id = can_id & np.where(extended, CAN_EXT_ID_MAX, CAN_STD_ID_MAX)
    length[remote | ~whole] = 0  # python-can keeps no data of a remote frame
    data = frame["data"] * (np.arange(8) < length[:, None])
    error &= whole
    flags = (remote & whole) * np.uint8(REMOTE) | error * np.uint8(ERROR)
    flags |= (error & ((arbitration_id & CAN_ERR_BUSOFF) != 0)) * np.uint8(BUS_OFF)
    overflow = error & ((arbitration_id & CAN_ERR_CRTL) != 0) & (length > 1) & ((data[:, 1] & CAN_ERR_CRTL_RX_OVERFLOW) != 0)
    flags |= overflow * np.uint8(RX_OVERFLOW)
    key = np.where(whole, arbitration_id | np.where(extended, CAN_EFF_KEY, 0), -1)
    return FrameBatch(times_s, key, length, data.astype(np.uint8), flags.astype(np.uint8))


def _receive_times(control: NDArray[np.uint8], control_bytes: NDArray[np.integer]) -> NDArray[np.float64]:
    k = control.shape[0]
    control = np.ascontiguousarray(control)
    stamp = control[:, CMSG_DATA_OFFSET : CMSG_DATA_OFFSET + TIMESPEC.itemsize].copy().view(TIMESPEC).reshape(k)
    times_s = stamp["sec"].astype(np.float64) + stamp["nsec"].astype(np.float64) * 1e-9  # as python-can adds them
    ok = (np.asarray(control_bytes) >= CMSG_NEEDED) & (stamp["nsec"] < 1_000_000_000)  # python-can refuses the latter
    if bool((control[:, : CMSG_HEADER.itemsize] == TIMESTAMP_HEADER).all()):  # what the kernel writes
        return np.where(ok, times_s, np.nan) if not bool(ok.all()) else times_s
    header = control[:, : CMSG_HEADER.itemsize].copy().view(CMSG_HEADER).reshape(k)
    ok &= (header["len"] >= CMSG_NEEDED) & (header["level"] == socket.SOL_SOCKET) & (header["type"] == SO_TIMESTAMPNS)
    return np.where(ok, times_s, np.nan)


class FrameReader(Protocol):
    """Takes an open bus's frames off it in batches."""

    def receive(self, max_n: int, timeout_s: float) -> int:
        """Wait up to timeout_s for a frame, then take what is queued, at most max_n; how many came.

        Raises what the bus raises when it fails (can.CanError, OSError).
        """

    def take(self) -> FrameBatch:
        """The frames received since the last take, in arrival order."""


class BusFrameReader:
    """Any python-can bus, through its `recv`: a Message per frame, columns once per batch."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self._messages: list[can.Message] = []

    def receive(self, max_n: int, timeout_s: float) -> int:
        message = self.bus.recv(timeout=timeout_s)
        got = 0
        while message is not None:
            self._messages.append(message)
            got += 1
            if got >= max_n:
                break
            message = self.bus.recv(timeout=0.0)
        return got

    def take(self) -> FrameBatch:
        messages, self._messages = self._messages, []
        return FrameBatch.from_messages(messages)


class QueueFrameReader:
    """python-can's virtual bus (the demo's, the tests' and the bench's), its queue drained at once.

    A VirtualBus keeps the Messages sent to it in a queue.Queue of its own (`bus.queue`); its
    `recv` takes one per call, with a lock, a condition, two clock readings and a filter check
    each: at the hub's 500 frames/s most of what the daemon spent on that bus. Here every Message
    queued is taken in one step under the queue's own lock. The first one is still waited for
    through `recv`, which raises as python-can does when the bus is closed. Only for a bus
    without filters (every bus drivers/canbus.py opens): frames are taken as they were queued.
    """

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self._queue: queue.Queue[can.Message] = bus.queue  # type: ignore[attr-defined]  # a VirtualBus's
        self._messages: list[can.Message] = []

    def receive(self, max_n: int, timeout_s: float) -> int:
        got = self._drain(max_n)
        if got == 0:
            message = self.bus.recv(timeout=timeout_s)  # waits, and raises for a closed bus
            if message is None:
                return 0
            self._messages.append(message)
            got = 1 + self._drain(max_n - 1)
        return got

    def _drain(self, max_n: int) -> int:
        q = self._queue
        with q.mutex:
            pending = q.queue
            n = min(len(pending), max_n)
            if n == len(pending):
                self._messages.extend(pending)
                pending.clear()
            else:
                self._messages.extend(pending.popleft() for _ in range(n))
            if n:
                q.not_full.notify_all()
        return n

    def take(self) -> FrameBatch:
        messages, self._messages = self._messages, []
        return FrameBatch.from_messages(messages)


class _IoVec(ctypes.Structure):
    _fields_ = [("iov_base", ctypes.c_void_p), ("iov_len", ctypes.c_size_t)]


class _MsgHdr(ctypes.Structure):  # struct msghdr, the kernel's layout on every Linux ABI
    _fields_ = [
        ("msg_name", ctypes.c_void_p),
        ("msg_namelen", ctypes.c_uint32),
        ("msg_iov", ctypes.c_void_p),
        ("msg_iovlen", ctypes.c_size_t),
        ("msg_control", ctypes.c_void_p),
        ("msg_controllen", ctypes.c_size_t),
        ("msg_flags", ctypes.c_int),
    ]


class _MMsgHdr(ctypes.Structure):
    _fields_ = [("msg_hdr", _MsgHdr), ("msg_len", ctypes.c_uint)]


_WOULD_BLOCK = frozenset({errno.EAGAIN, errno.EWOULDBLOCK, errno.EINTR})


@functools.cache
def _libc_recvmmsg() -> Callable[..., int]:
    """recvmmsg(2) from the C library (glibc and musl have it; Linux since 2.6.33), looked up on first use."""
    function = ctypes.CDLL(None, use_errno=True).recvmmsg
    function.argtypes = [ctypes.c_int, ctypes.c_void_p, ctypes.c_uint, ctypes.c_int, ctypes.c_void_p]
    function.restype = ctypes.c_int
    return function


class SocketFrameReader:
    """A socket delivering `struct can_frame` datagrams (SocketCAN's), read with recvmmsg(2).

    Up to `capacity` frames wait between two takes, in buffers allocated once: the kernel writes
    the frames and their receive times there, and `take` parses them in one pass of numpy. The
    socket is the bus's: closing the bus closes it, and the next receive raises OSError (EBADF),
    as any failure of the interface does (ENETDOWN, ENODEV).
    """

    def __init__(self, sock: socket.socket, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"a frame reader holds at least one frame, got capacity {capacity}")
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)  # python-can asks too; the stamps are needed here
        self.socket = sock
        self.capacity = capacity
        self._frames = np.zeros((capacity, CAN_MTU), np.uint8)
        self._control = np.zeros((capacity, CONTROL_SPACE), np.uint8)
        self._iov = (_IoVec * capacity)()
        self._headers = (_MMsgHdr * capacity)()
        for i in range(capacity):
            self._iov[i].iov_base = self._frames.ctypes.data + i * CAN_MTU
            self._iov[i].iov_len = CAN_MTU
            header = self._headers[i].msg_hdr
            header.msg_iov = ctypes.addressof(self._iov[i])
            header.msg_iovlen = 1
            header.msg_control = self._control.ctypes.data + i * CONTROL_SPACE
            header.msg_controllen = CONTROL_SPACE
        # What the kernel writes back into each header, as arrays over the headers themselves.
        self._received_bytes = self._field("msg_len", np.dtype(ctypes.c_uint))
        self._control_bytes = self._field("msg_controllen", np.dtype(ctypes.c_size_t))
        self._msg_flags = self._field("msg_flags", np.dtype(np.intc))
        self._recvmmsg_call = _libc_recvmmsg()
        self._n = 0

    def _field(self, name: str, dtype: np.dtype) -> NDArray[np.integer]:
        offset = getattr(_MMsgHdr, name).offset if name == "msg_len" else _MMsgHdr.msg_hdr.offset + getattr(_MsgHdr, name).offset
        # A ctypes array is a writable buffer; numpy's stubs do not list ctypes among buffers.
        return np.ndarray((self.capacity,), dtype=dtype, buffer=self._headers, offset=offset, strides=(ctypes.sizeof(_MMsgHdr),))  # type: ignore[arg-type]

    def receive(self, max_n: int, timeout_s: float) -> int:
        fd = self.socket.fileno()
        if fd < 0:
            raise OSError(errno.EBADF, "the bus's socket is closed")
        max_n = min(max_n, self.capacity - self._n)
        if max_n <= 0:
            return 0
        got = self._recvmmsg(fd, max_n)
        if got == 0 and timeout_s > 0:
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            if poller.poll(math.ceil(timeout_s * 1000)):  # readable, or an error to report
                got = self._recvmmsg(fd, max_n)
        return got

    def _recvmmsg(self, fd: int, max_n: int) -> int:
        first = ctypes.addressof(self._headers) + self._n * ctypes.sizeof(_MMsgHdr)
        got = self._recvmmsg_call(fd, first, max_n, socket.MSG_DONTWAIT, None)
        if got < 0:
            code = ctypes.get_errno()
            if code in _WOULD_BLOCK:
                return 0
            raise OSError(code, os.strerror(code))
        self._n += got
        return got

    def take(self) -> FrameBatch:
        k, self._n = self._n, 0
        if k == 0:
            return FrameBatch.empty()
        batch = frames_from_datagrams(
            self._frames[:k], self._received_bytes[:k], self._msg_flags[:k], self._control[:k], self._control_bytes[:k]
        )
        self._control_bytes[:k] = CONTROL_SPACE  # the kernel wrote the length it used: room again
        return batch
