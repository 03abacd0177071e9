"""The CAN frame decoder at its boundary, on replay and on the live bus: unusable time stamps and
impossible identifiers counted, never passed on."""

from __future__ import annotations

import math

import can
import numpy as np
import pytest
from can.interfaces.virtual import VirtualBus

from bogiemon.drivers.base import HealthCounters
from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.can_source import BusPort, CanSource
from bogiemon.drivers.candb import CanLayout, load_layout, shipped_dbc_text
from bogiemon.drivers.segments import CLOCK_STEP_AFTER, SampleQueue
from tests.drivers.frames import FS_HZ, HUB, PER_NODE, channel_name, check_blocks, layout_frames

LAYOUTS = {"hub": HUB, "per-node": PER_NODE}


def decode(layout: CanLayout, messages: list[can.Message], batch_n: int = 64) -> tuple[list, HealthCounters]:
    counters = HealthCounters()
    queue = SampleQueue(FS_HZ)
    decoder = CanFrameDecoder(layout, FS_HZ, counters, queue)
    for i in range(0, len(messages), batch_n):
        decoder.feed(messages[i : i + batch_n])
    blocks = []
    while (block := queue.take(50)) is not None:
        blocks.append(block)
    return blocks, counters


def with_time(message: can.Message, time_s: float) -> can.Message:
    message.timestamp = time_s
    return message


@pytest.mark.parametrize("name", ["hub", "per-node"])
@pytest.mark.parametrize("bad_s", [math.nan, math.inf, -math.inf, 1e300], ids=["nan", "inf", "-inf", "1e300"])
@pytest.mark.parametrize("where", ["first", "middle"])
def test_a_frame_with_an_unusable_time_stamp_is_counted_and_decoded_as_if_never_received(name: str, bad_s: float, where: str) -> None:
    layout = LAYOUTS[name]
    messages = layout_frames(layout, np.arange(200))
    i = 0 if where == "first" else len(messages) // 2 + 1
    without, _ = decode(layout, messages[:i] + messages[i + 1 :])
    with_time(messages[i], bad_s)
    blocks, counters = decode(layout, messages)
    assert counters.bad_frames == counters.extra["bad_timestamps"] == 1
    assert counters.frames == len(messages) - 1
    assert all(math.isfinite(b.start_s) and 1000.0 <= b.start_s < 1001.0 for b in blocks)
    assert [(b.start_s, b.gap_before) for b in blocks] == [(b.start_s, b.gap_before) for b in without]
    np.testing.assert_array_equal(np.concatenate(check_blocks(blocks)), np.concatenate(check_blocks(without)))


def test_a_nan_first_time_stamp_leaves_the_stream_anchored_at_the_next_frame() -> None:
    messages = layout_frames(HUB, np.arange(100))
    with_time(messages[0], math.nan)
    blocks, _ = decode(HUB, messages)
    assert blocks[0].start_s == pytest.approx(1000.0 + 1 / FS_HZ)


def test_a_frame_far_behind_its_predecessors_is_dropped_and_counted() -> None:
    messages = layout_frames(HUB, np.arange(100))
    with_time(messages[40], 5.0)  # a stamp from long before the log
    blocks, counters = decode(HUB, messages)
    assert counters.extra["bad_timestamps"] == 1
    assert [(s[0], s[-1]) for s in check_blocks(blocks)] == [(0, 39), (41, 99)]


def test_a_clock_stepped_back_is_followed_after_a_few_frames() -> None:
    messages = layout_frames(HUB, np.arange(50)) + layout_frames(HUB, np.arange(50, 100), t0_s=500.0)
    blocks, counters = decode(HUB, messages)
    assert counters.extra["clock_steps"] == 1 and counters.extra["bad_timestamps"] == CLOCK_STEP_AFTER - 1
    segments = check_blocks(blocks)
    assert [(s[0], s[-1]) for s in segments] == [(0, 49), (50 + CLOCK_STEP_AFTER - 1, 99)]


@pytest.mark.parametrize(
    ("arbitration_id", "extended"),
    [(2**70, True), (2**70, False), (2**63, True), (-1, False), (0x100 | (1 << 31), False), (0x900, False), (0x20000000, True)],
    ids=["2^70-ext", "2^70-std", "2^63", "negative", "aliases-an-extended-key", "std-beyond-11-bits", "ext-beyond-29-bits"],
)
def test_an_identifier_no_can_frame_can_carry_is_an_unknown_id(arbitration_id: int, extended: bool) -> None:
    messages = layout_frames(HUB, np.arange(20))
    odd = can.Message(timestamp=messages[10].timestamp, arbitration_id=0, is_extended_id=extended, data=bytes(8))
    odd.arbitration_id = arbitration_id  # as python-can's .asc reader leaves an id too large for a C long
    blocks, counters = decode(HUB, messages[:11] + [odd] + messages[11:])
    assert counters.extra["unknown_ids"] == counters.bad_frames == 1
    assert counters.frames == 20
    np.testing.assert_array_equal(np.concatenate(check_blocks(blocks)), np.arange(20))


class StampKeepingPort(BusPort):
    """python-can's virtual bus keeping the sender's time stamps, so a test can send bad ones."""

    def __init__(self, channel: str) -> None:
        self.channel = channel
        self.description = f"virtual CAN channel '{channel}' (time stamps kept)"

    def open(self) -> can.BusABC:
        return VirtualBus(channel=self.channel, preserve_timestamps=True, receive_own_messages=False)


@pytest.mark.parametrize("bad_s", [math.nan, math.inf, 5.0], ids=["nan", "inf", "far-behind"])
def test_the_live_can_source_counts_a_frame_with_an_unusable_time_stamp_and_never_passes_it_on(bad_s: float) -> None:
    channel = channel_name()
    source = CanSource(StampKeepingPort(channel), HUB, FS_HZ, max_block_s=0.1)
    sender = VirtualBus(channel=channel, preserve_timestamps=True)
    try:
        messages = layout_frames(HUB, np.arange(200))
        with_time(messages[100], bad_s)
        for message in messages:
            sender.send(message)
        blocks = []
        for _ in range(100):
            if (block := source.read(0.2)) is not None:
                blocks.append(block)
            if source.counters.frames + source.counters.bad_frames == 200 and block is None:
                break
    finally:
        sender.shutdown()
        source.close()
    assert source.counters.extra["bad_timestamps"] == source.counters.bad_frames == 1
    assert [(s[0], s[-1]) for s in check_blocks(blocks)] == [(0, 99), (101, 199)]
    assert all(1000.0 <= b.start_s < 1001.0 for b in blocks)


def test_per_node_frames_laid_out_differently_per_node_decode_each_with_its_own_signals(tmp_path) -> None:
    # SensorNode2 with its acceleration in bytes 1-2 and its flags in byte 3: the DBC may lay the nodes out apart.
    text = shipped_dbc_text()
    node2 = text.index("BO_ 258 SensorNode2")
    end = text.index("BO_ 259")
    moved = (
        text[node2:end]
        .replace("SG_ OverRange : 8|1@1+", "SG_ OverRange : 24|1@1+")
        .replace("SG_ SensorFault : 9|1@1+", "SG_ SensorFault : 25|1@1+")
        .replace("SG_ Accel : 16|16@1-", "SG_ Accel : 8|16@1-")
    )
    (tmp_path / "nodes.dbc").write_text(text[:node2] + moved + text[end:])
    layout = load_layout(tmp_path / "nodes.dbc", "per-node")
    assert layout.nodes[1].signals["Accel"].shift == 8
    blocks, counters = decode(layout, layout_frames(layout, np.arange(120)))
    np.testing.assert_array_equal(np.concatenate(check_blocks(blocks)), np.arange(120))
    assert counters.bad_frames == counters.extra["lost_samples"] == 0
