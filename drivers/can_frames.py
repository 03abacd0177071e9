"""CAN frames as columns: what a bus delivered, read in batches, before anything is decoded.

A FrameBatch holds n received frames as numpy arrays (receive time, identifier key, data length,
the first 8 data bytes, flags), so the decoder works on whole batches and no Python object is
made per frame past the point where the frames come in. A FrameReader takes frames off an open
bus in batches: BusFrameReader through python-can's `recv` (any python-can bus).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
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
    extended = np.fromiter((bool(m.is_extended_id) for m in messages), bool, n)
    try:
        ids = np.fromiter(map(_ARBITRATION_ID, messages), np.int64, n)
    except (TypeError, ValueError, OverflowError):
        ids = np.fromiter((_id_or_minus_one(m.arbitration_id) for m in messages), np.int64, n)
    valid = (ids >= 0) & (ids <= np.where(extended, CAN_EXT_ID_MAX, CAN_STD_ID_MAX))
    return np.where(valid, ids | np.where(extended, CAN_EFF_KEY, 0), -1)


_ARBITRATION_ID = attrgetter("arbitration_id")


def _id_or_minus_one(arbitration_id: object) -> int:
    return arbitration_id if isinstance(arbitration_id, int) and 0 <= arbitration_id <= CAN_EXT_ID_MAX else -1


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
