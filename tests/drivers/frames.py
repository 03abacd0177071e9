"""Frames, packets and recordings for the driver tests, with samples that say which instant they are.

Instant k carries a1 = k, a2 = -k, a3 = 7 k mod 20000 - 10000 in LSB, so a delivered sample names
its instant exactly and any reordering, bridging or corruption shows.
"""

from __future__ import annotations

import socket
import uuid
from pathlib import Path
from typing import Any, ClassVar

import can
import can.interfaces.virtual
import numpy as np
from can.interfaces.socketcan.socketcan import SocketcanBus, build_can_frame
from numpy.typing import NDArray

from bogiemon.drivers.base import Block
from bogiemon.drivers.can_decode import max_silence_s
from bogiemon.drivers.can_frames import SO_TIMESTAMPNS
from bogiemon.drivers.candb import CanLayout, load_layout
from bogiemon.drivers.player import encode_instants
from bogiemon.drivers.recording import write_csv_recording
from bogiemon.drivers.serial_protocol import ACCEL_LSB_MPS2

FS_HZ = 500.0
LSB_MPS2 = ACCEL_LSB_MPS2
HUB = load_layout(None, "hub")
PER_NODE = load_layout(None, "per-node")


def channel_name() -> str:
    """A virtual CAN channel no other test uses."""
    return f"test-{uuid.uuid4().hex[:12]}"


def stamped_sender(channel: str) -> can.BusABC:
    """A virtual bus that sends frames with their own time stamps, not the wall clock at send time.

    The receive times are then the recording's, whatever the machine does: on a shared one the
    sending thread can stall for longer than a quarter of a second, which the source rightly reads
    as a silence and so as a new segment.
    """
    return can.interfaces.virtual.VirtualBus(channel=channel, preserve_timestamps=True)


class DatagramCanBus(can.BusABC):
    """A SocketCAN bus on a UDP socket of this kernel, which has no AF_CAN; the test double of SocketcanBus.

    Its socket delivers the kernel's `struct can_frame` datagrams with SO_TIMESTAMPNS receive
    times, as a CAN_RAW socket does, and python-can's own SocketcanBus receive code reads it
    (`_recv_internal`: select, then capture_message), so the same bytes can be read both ways.
    Frames reach it from send_frames. Every bus made is kept in `made`, newest last.
    """

    made: ClassVar[list[DatagramCanBus]] = []
    _recv_internal = SocketcanBus._recv_internal

    def __init__(self, channel: str = "", **settings: Any) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.bind(("127.0.0.1", 0))
        self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.address = self.socket.getsockname()
        self.channel = channel
        self._is_filtered = False
        super().__init__(channel=channel)
        DatagramCanBus.made.append(self)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:  # pragma: no cover - a receiver
        raise NotImplementedError("send to a DatagramCanBus with send_frames")

    def shutdown(self) -> None:
        self.socket.close()
        super().shutdown()


class DatagramSender(can.BusABC):
    """A sending end for a DatagramCanBus: each message goes to its address as one struct can_frame datagram."""

    def __init__(self, address: tuple[str, int]) -> None:
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.address = address
        self.channel_info = f"datagrams to {address[0]}:{address[1]}"
        super().__init__(channel="")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.socket.sendto(build_can_frame(msg), self.address)

    def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:  # pragma: no cover - a sender
        return None, False

    def shutdown(self) -> None:
        self.socket.close()
        super().shutdown()


def send_frames(address: tuple[str, int], messages: list[can.Message]) -> None:
    """The messages as struct can_frame datagrams to a DatagramCanBus's address, in order."""
    sender = DatagramSender(address)
    try:
        for message in messages:
            sender.send(message)
    finally:
        sender.shutdown()


def silences_heard(listener: can.BusABC, layout: CanLayout) -> int:
    """How often the frames queued on listener pause longer than a CAN source bridges.

    For the tests whose sender stamps frames with the wall clock: a source may start a new segment
    at each such pause, and at no other place.
    """
    times_s = []
    while (message := listener.recv(timeout=0.0)) is not None:
        times_s.append(message.timestamp)
    return int((np.diff(times_s) > max_silence_s(layout.counter_modulus, FS_HZ)).sum())


def coded_accel(k: NDArray[np.int64]) -> NDArray[np.float64]:
    """(n, 3) m/s^2 that encode instant numbers k exactly (|k| < 10000)."""
    k = np.asarray(k, dtype=np.int64)
    return np.column_stack([k, -k, (7 * k) % 20000 - 10000]).astype(np.float64) * LSB_MPS2


def instants_of(accel_mps2: NDArray[np.float64]) -> NDArray[np.int64]:
    """The instant numbers coded samples carry; asserts all three channels agree."""
    raw = np.rint(accel_mps2 / LSB_MPS2).astype(np.int64)
    k = raw[:, 0]
    np.testing.assert_array_equal(raw[:, 1], -k)
    np.testing.assert_array_equal(raw[:, 2], (7 * k) % 20000 - 10000)
    return k


def layout_frames(layout: CanLayout, k: NDArray[np.int64], t0_s: float = 1000.0) -> list[can.Message]:
    """The frames of instants k (their counters are k mod 256), time-stamped k / FS_HZ after t0_s."""
    out = []
    for ki in np.asarray(k).tolist():
        (frames,) = encode_instants(layout, coded_accel(np.array([ki])), first_counter=ki)
        for frame_id, extended, payload in frames:
            out.append(
                can.Message(timestamp=t0_s + ki / FS_HZ, arbitration_id=frame_id, is_extended_id=extended, data=payload)
            )
    return out


def check_blocks(blocks: list[Block]) -> list[NDArray[np.int64]]:
    """Assert blocks are well formed (uniform times, no bridged gap); return the instants per segment."""
    segments: list[list[NDArray[np.int64]]] = []
    previous: Block | None = None
    for block in blocks:
        k = instants_of(block.accel_mps2)
        assert block.n_samples > 0
        np.testing.assert_array_equal(np.diff(k), 1)  # consecutive inside a block
        if block.gap_before or previous is None:
            assert block.gap_before, "the first block of a stream starts a segment"
            segments.append([k])
        else:
            assert k[0] == segments[-1][-1][-1] + 1, "a block without gap_before continues its segment"
            # Uniform within a segment, to the float resolution of Unix times (~2e-7 s).
            assert abs(block.start_s - previous.end_s) < 1e-6, "times are uniform within a segment"
            segments[-1].append(k)
        previous = block
    return [np.concatenate(s) for s in segments]


def write_recording(path: Path, n: int, seed: int = 0, start_s: float = 100.0) -> NDArray[np.float64]:
    """A CSV recording of n samples at FS_HZ; returns its accelerations as written (6 decimals)."""
    rng = np.random.default_rng(seed)
    accel = np.round(rng.standard_normal((n, 3)) * 2.0 + np.array([9.81, 9.7, 9.9]), 6)
    write_csv_recording(path, start_s + np.arange(n) / FS_HZ, accel)
    return accel
