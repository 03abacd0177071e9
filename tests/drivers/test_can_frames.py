"""Frames as columns (drivers/can_frames.py): from python-can Messages, read through python-can's recv."""

from __future__ import annotations

import can
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.can_frames import (
    BUS_OFF,
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    ERROR,
    REMOTE,
    RX_OVERFLOW,
    BusFrameReader,
    FrameBatch,
)
from bogiemon.drivers.candb import CAN_EFF_KEY
from tests.drivers.frames import HUB, channel_name, layout_frames


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


def test_the_bus_reader_takes_python_can_messages_through_recv() -> None:
    channel = channel_name()
    bus, sender = VirtualBus(channel=channel), VirtualBus(channel=channel)
    try:
        for message in layout_frames(HUB, np.arange(5)):
            sender.send(message)
        reader = BusFrameReader(bus)
        assert reader.receive(3, 1.0) == 3
        assert reader.receive(10, 1.0) == 2
        frames = reader.take()
        assert frames.data[:, 0].tolist() == [0, 1, 2, 3, 4] and np.isfinite(frames.time_s).all()
        assert reader.receive(10, 0.0) == 0 and reader.take().n == 0
    finally:
        bus.shutdown()
        sender.shutdown()
