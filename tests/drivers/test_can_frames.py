"""Frames as columns (drivers/can_frames.py): from python-can Messages, and from struct can_frame
datagrams read in batches, checked against python-can's own SocketCAN parsing on the same bytes."""

from __future__ import annotations

import errno
import socket
import struct
import threading
import time

import can
import numpy as np
import pytest
from can.interfaces.socketcan.socketcan import build_can_frame, capture_message
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.can_frames import (
    BUS_OFF,
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_MTU,
    CMSG_DATA_OFFSET,
    CONTROL_SPACE,
    ERROR,
    REMOTE,
    RX_OVERFLOW,
    SO_TIMESTAMPNS,
    BusFrameReader,
    FrameBatch,
    QueueFrameReader,
    SocketFrameReader,
    frames_from_datagrams,
)
from bogiemon.drivers.canbus import BusRole, open_bus
from bogiemon.drivers.candb import CAN_EFF_KEY
from tests.drivers.frames import HUB, DatagramCanBus, layout_frames, send_frames


STAMP_BYTES = socket.CMSG_LEN(struct.calcsize("@ll"))  # an SO_TIMESTAMPNS control message's length


def assert_same_batch(got: FrameBatch, expected: FrameBatch, times: bool = True) -> None:
    np.testing.assert_array_equal(got.key, expected.key)
    np.testing.assert_array_equal(got.length, expected.length)
    np.testing.assert_array_equal(got.data, expected.data)
    np.testing.assert_array_equal(got.flags, expected.flags)
    if times:
        np.testing.assert_array_equal(got.time_s, expected.time_s)  # NaN where both are NaN


def reference_columns(message: can.Message) -> tuple[float, int, int, bytes, int]:
    """One Message's columns, spelt out: (time, key, length, 8 data bytes, flags)."""
    arbitration_id = message.arbitration_id
    extended = bool(message.is_extended_id)
    valid = isinstance(arbitration_id, int) and 0 <= arbitration_id <= (0x1FFFFFFF if extended else 0x7FF)
    key = arbitration_id | (CAN_EFF_KEY if extended else 0) if valid else -1
    flags = (REMOTE if message.is_remote_frame else 0) | (ERROR if message.is_error_frame else 0)
    if message.is_error_frame:
        if arbitration_id & CAN_ERR_BUSOFF:
            flags |= BUS_OFF
        if arbitration_id & CAN_ERR_CRTL and len(message.data) > 1 and message.data[1] & 0x01:
            flags |= RX_OVERFLOW
    try:
        time_s = float(message.timestamp)
    except (TypeError, ValueError, OverflowError):
        time_s = float("nan")
    return time_s, key, len(message.data), bytes(message.data[:8]).ljust(8, b"\0"), flags


@st.composite
def messages(draw: st.DrawFn) -> can.Message:
    kind = draw(st.sampled_from(["data", "data", "remote", "error"]))
    extended = draw(st.booleans())
    arbitration_id = draw(st.one_of(st.integers(0, 0x7FF), st.integers(0, 0x1FFFFFFF), st.integers(-5, 2**64)))
    data = draw(st.binary(max_size=64 if kind == "data" else 8))
    message = can.Message(
        timestamp=draw(st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.just(1000.25))),
        arbitration_id=0,
        is_extended_id=extended,
        is_remote_frame=kind == "remote",
        is_error_frame=kind == "error",
        data=data,
    )
    message.arbitration_id = arbitration_id  # as a log reader may leave one no frame can carry
    return message


@settings(max_examples=200, deadline=None)
@given(batch=st.lists(messages(), max_size=20))
def test_messages_become_columns_field_by_field(batch: list[can.Message]) -> None:
    frames = FrameBatch.from_messages(batch)
    assert frames.n == len(batch) and frames.data.shape == (len(batch), 8)
    for i, message in enumerate(batch):
        time_s, key, length, data, flags = reference_columns(message)
        assert (frames.key[i], frames.length[i], bytes(frames.data[i]), frames.flags[i]) == (key, length, data, flags)
        assert frames.time_s[i] == time_s or (np.isnan(frames.time_s[i]) and np.isnan(time_s))


def test_hub_frames_all_eight_bytes_long_become_columns_in_one_piece() -> None:
    batch = layout_frames(HUB, np.arange(5))
    frames = FrameBatch.from_messages(batch)
    assert frames.data.tolist() == [list(m.data) for m in batch]
    assert frames.key.tolist() == [0x100] * 5 and frames.length.tolist() == [8] * 5


# ---- struct can_frame datagrams, parsed as python-can parses them ------------------------------


class OneDatagram:
    """A socket whose recvmsg returns one given datagram: python-can's capture_message reads it."""

    def __init__(self, frame: bytes, control: list[tuple[int, int, bytes]], flags: int = 0) -> None:
        self.reply = (frame, control, flags, ("", 0))

    def recvmsg(self, size: int, control_size: int) -> tuple[bytes, list[tuple[int, int, bytes]], int, tuple[str, int]]:
        return self.reply


def control_message(sec: int, nsec: int, kind: int = SO_TIMESTAMPNS) -> bytes:
    """The control bytes the kernel writes for an SO_TIMESTAMPNS receive time (or a message of another kind)."""
    data = struct.pack("@ll", sec, nsec)
    header = struct.pack("@NiI", socket.CMSG_LEN(len(data)), socket.SOL_SOCKET, kind)
    return (header.ljust(CMSG_DATA_OFFSET, b"\0") + data).ljust(CONTROL_SPACE, b"\0")


@st.composite
def datagrams(draw: st.DrawFn, plain: bool) -> tuple[bytes, int, int]:
    """A struct can_frame and its receive time; plain: an 11-bit identifier and no flag, as a bus mostly carries."""
    can_id = draw(st.integers(0, 0x7FF) if plain else st.integers(0, 2**32 - 1))
    header = struct.pack("=IBBBB", can_id, draw(st.integers(0, 15)), draw(st.integers(0, 255)), draw(st.integers(0, 255)), draw(st.integers(0, 15)))
    return header + draw(st.binary(min_size=8, max_size=8)), draw(st.integers(0, 2**31 - 1)), draw(st.integers(0, 999_999_999))


@settings(max_examples=300, deadline=None)
@given(batch=st.booleans().flatmap(lambda plain: st.lists(datagrams(plain), min_size=1, max_size=16)))
def test_datagrams_parse_exactly_as_python_cans_socketcan_receive_path(batch: list[tuple[bytes, int, int]]) -> None:
    k = len(batch)
    frames = np.frombuffer(b"".join(f for f, _, _ in batch), np.uint8).reshape(k, CAN_MTU)
    control = np.frombuffer(b"".join(control_message(s, ns) for _, s, ns in batch), np.uint8).reshape(k, CONTROL_SPACE)
    got = frames_from_datagrams(frames, np.full(k, CAN_MTU), np.zeros(k, np.intc), control, np.full(k, STAMP_BYTES))
    reference = []
    for frame, sec, nsec in batch:
        sock = OneDatagram(frame, [(socket.SOL_SOCKET, SO_TIMESTAMPNS, struct.pack("@ll", sec, nsec))])
        message = capture_message(sock)  # type: ignore[arg-type]  # recvmsg is all it uses
        assert message is not None
        reference.append(message)
    assert_same_batch(got, FrameBatch.from_messages(reference))


def test_a_datagram_that_is_not_one_frame_is_an_unknown_identifier_and_a_missing_stamp_nan() -> None:
    frame = np.frombuffer(build_can_frame(can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes(8))), np.uint8)
    frames = np.stack([frame] * 5)
    control = np.frombuffer(control_message(1000, 5) * 4 + control_message(1000, 5, kind=SO_TIMESTAMPNS + 1), np.uint8)
    got = frames_from_datagrams(
        frames,
        received_bytes=np.array([CAN_MTU, 10, CAN_MTU, CAN_MTU, CAN_MTU]),  # a short one
        msg_flags=np.array([0, 0, socket.MSG_TRUNC, 0, 0]),  # a longer one, cut
        control=control.reshape(5, CONTROL_SPACE),
        control_bytes=np.array([STAMP_BYTES] * 3 + [0, STAMP_BYTES]),  # no stamp; another message
    )
    assert got.key.tolist() == [0x100, -1, -1, 0x100, 0x100]
    assert got.time_s[:3].tolist() == [1000 + 5e-9] * 3 and np.isnan(got.time_s[3:]).all()


def test_a_batch_of_whole_data_frames_keeps_its_stamps_unless_one_is_missing() -> None:
    frame = np.frombuffer(build_can_frame(can.Message(arbitration_id=0x101, is_extended_id=False, data=b"\x01\x02")), np.uint8)
    control = np.frombuffer(control_message(1000, 5) * 3, np.uint8).reshape(3, CONTROL_SPACE)
    received = np.full(3, CAN_MTU)
    got = frames_from_datagrams(np.stack([frame] * 3), received, np.zeros(3, np.intc), control, np.array([STAMP_BYTES, 0, STAMP_BYTES]))
    assert got.key.tolist() == [0x101] * 3 and got.length.tolist() == [2] * 3 and got.data[:, :3].tolist() == [[1, 2, 0]] * 3
    assert got.time_s[[0, 2]].tolist() == [1000 + 5e-9] * 2 and np.isnan(got.time_s[1])


# ---- the socket reader on a real datagram socket -----------------------------------------------


@pytest.fixture
def bus():
    bus = DatagramCanBus("can7")
    yield bus
    bus.shutdown()


def test_a_socket_reader_takes_every_queued_frame_in_order_with_its_receive_time(bus: DatagramCanBus) -> None:
    sent = layout_frames(HUB, np.arange(100))
    sent[10:10] = [
        can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, data=b"\x01\x02\x03"),
        can.Message(arbitration_id=0x100, is_extended_id=False, is_remote_frame=True, dlc=8),
        can.Message(arbitration_id=CAN_ERR_BUSOFF | CAN_ERR_CRTL, is_extended_id=False, is_error_frame=True, data=bytes([0, 1, 0, 0, 0, 0, 0, 0])),
    ]
    reader = SocketFrameReader(bus.socket, capacity=200)
    before_s = time.time()
    send_frames(bus.address, sent)
    assert reader.receive(200, 1.0) == len(sent)  # one call: all that was queued
    frames = reader.take()
    after_s = time.time()
    assert_same_batch(frames, FrameBatch.from_messages(sent), times=False)
    assert frames.flags[12] == ERROR | BUS_OFF | RX_OVERFLOW
    assert before_s - 1 <= frames.time_s[0] and frames.time_s[-1] <= after_s + 1  # the kernel's clock, Unix time
    assert (np.diff(frames.time_s) >= 0).all()


def test_the_socket_reader_reads_what_python_can_reads_from_the_same_datagrams() -> None:
    ours, theirs = DatagramCanBus("can7"), DatagramCanBus("can7")
    try:
        sent = layout_frames(HUB, np.arange(50)) + [
            can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b"\xff"),
            can.Message(arbitration_id=0x80, is_extended_id=True, data=b""),
        ]
        send_frames(ours.address, sent)
        send_frames(theirs.address, sent)
        reader = SocketFrameReader(ours.socket, capacity=64)
        reader.receive(64, 1.0)
        python_can = [m for m in (theirs.recv(timeout=1.0) for _ in sent) if m is not None]
        assert len(python_can) == len(sent)
        assert_same_batch(reader.take(), FrameBatch.from_messages(python_can), times=False)
    finally:
        ours.shutdown()
        theirs.shutdown()


def test_a_socket_reader_takes_at_most_what_is_asked_and_what_it_holds(bus: DatagramCanBus) -> None:
    sent = layout_frames(HUB, np.arange(10))
    send_frames(bus.address, sent)
    reader = SocketFrameReader(bus.socket, capacity=7)
    assert reader.receive(4, 0.0) == 4
    assert reader.receive(100, 0.0) == 3  # full: 7 held
    assert reader.receive(100, 0.0) == 0
    first = reader.take()
    assert reader.receive(100, 0.0) == 3
    second = reader.take()
    assert [m.data[0] for m in sent] == first.data[:, 0].tolist() + second.data[:, 0].tolist()
    assert reader.take().n == 0


def test_a_socket_reader_waits_for_the_first_frame_and_returns_none_at_its_timeout(bus: DatagramCanBus) -> None:
    reader = SocketFrameReader(bus.socket, capacity=8)
    assert reader.receive(8, 0.02) == 0
    later = threading.Timer(0.05, send_frames, (bus.address, layout_frames(HUB, np.arange(1))))
    later.start()
    try:
        assert reader.receive(8, 30.0) == 1  # woken by the frame, long before the timeout
    finally:
        later.join()


def test_a_closed_socket_is_reported_as_an_os_error(bus: DatagramCanBus) -> None:
    reader = SocketFrameReader(bus.socket, capacity=8)
    bus.socket.close()
    with pytest.raises(OSError) as raised:
        reader.receive(8, 0.0)
    assert raised.value.errno == errno.EBADF


def test_the_bus_reader_takes_python_can_messages_through_recv() -> None:
    bus = DatagramCanBus("can7")
    try:
        send_frames(bus.address, layout_frames(HUB, np.arange(5)))
        reader = BusFrameReader(bus)
        assert reader.receive(3, 1.0) == 3
        assert reader.receive(10, 1.0) == 2
        frames = reader.take()
        assert frames.data[:, 0].tolist() == [0, 1, 2, 3, 4] and np.isfinite(frames.time_s).all()
        assert reader.receive(10, 0.0) == 0 and reader.take().n == 0
    finally:
        bus.shutdown()


# ---- python-can's virtual bus, its queue taken whole ------------------------------------------


def virtual_pair() -> tuple[can.BusABC, can.BusABC, can.BusABC]:
    """Two receivers and a sender on one new virtual channel."""
    channel = f"queue-reader-{time.monotonic_ns()}"
    return open_bus("virtual", channel, BusRole.RECEIVER), open_bus("virtual", channel, BusRole.RECEIVER), open_bus("virtual", channel, BusRole.SENDER)


def test_the_queue_reader_takes_what_recv_takes_in_one_step() -> None:
    ours, theirs, sender = virtual_pair()
    try:
        sent = layout_frames(HUB, np.arange(50)) + [
            can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, data=b"\x01"),
            can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=2),
        ]
        for message in sent:
            sender.send(message)
        queue_reader, bus_reader = QueueFrameReader(ours), BusFrameReader(theirs)
        assert queue_reader.receive(100, 1.0) == len(sent) == bus_reader.receive(100, 1.0)
        assert_same_batch(queue_reader.take(), bus_reader.take())  # the receive times too: stamped at sending
        assert queue_reader.take().n == 0
    finally:
        for bus in (ours, theirs, sender):
            bus.shutdown()


def test_the_queue_reader_takes_at_most_what_is_asked_and_waits_for_the_first_frame() -> None:
    ours, theirs, sender = virtual_pair()
    theirs.shutdown()
    try:
        reader = QueueFrameReader(ours)
        assert reader.receive(8, 0.02) == 0
        for message in layout_frames(HUB, np.arange(10)):
            sender.send(message)
        assert reader.receive(4, 0.0) == 4 and reader.receive(100, 0.0) == 6 and reader.receive(100, 0.0) == 0
        assert reader.take().data[:, 0].tolist() == list(range(10))
        later = threading.Timer(0.05, sender.send, (layout_frames(HUB, np.arange(1))[0],))
        later.start()
        try:
            assert reader.receive(8, 30.0) == 1  # woken by the frame, long before the timeout
        finally:
            later.join()
    finally:
        ours.shutdown()
        sender.shutdown()


def test_the_queue_reader_of_a_closed_bus_raises_as_python_can_does() -> None:
    ours, theirs, sender = virtual_pair()
    for bus in (theirs, sender, ours):
        bus.shutdown()
    with pytest.raises(can.CanOperationError):
        QueueFrameReader(ours).receive(8, 0.0)
