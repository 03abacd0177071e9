"""The DBC layouts: compiled batch codec against cantools frame by frame, and clear DBC errors."""

from pathlib import Path
from typing import Any

import cantools
import numpy as np
import pytest
from cantools.database.can import Message, Signal
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.drivers.candb import DbcError, compile_message, load_layout, shipped_dbc_text

SHIPPED = cantools.database.load_string(shipped_dbc_text(), database_format="dbc")


def cantools_rows(message: Message, data: np.ndarray) -> list[dict[str, Any]]:
    rows = []
    for row in data:
        decoded = message.decode(bytes(row), decode_choices=False)
        assert isinstance(decoded, dict)  # a plain message, never a container's parts
        rows.append(decoded)
    return rows


@pytest.mark.parametrize("name", ["SensorHub", "SensorNode1", "SensorNode3", "Sync"])
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 60))
def test_batch_decoder_matches_cantools_on_the_shipped_messages(name: str, seed: int, n: int) -> None:
    message = SHIPPED.get_message_by_name(name)
    codec = compile_message(message)
    data = np.random.default_rng(seed).integers(0, 256, (n, message.length), dtype=np.uint8)
    batch = codec.decode(data)
    for i, expected in enumerate(cantools_rows(message, data)):
        assert {k: batch[k][i] for k in expected} == pytest.approx(expected, rel=1e-12, abs=1e-12)


@st.composite
def signal_layouts(draw: st.DrawFn) -> Message:
    """A message of 1..4 non-overlapping signals, Intel or Motorola, signed or not, scaled."""
    bits = list(range(64))
    signals = []
    free = set(bits)
    for i in range(draw(st.integers(1, 4))):
        length = draw(st.integers(1, 16))
        big_endian = draw(st.booleans())
        # Place by the signal's bit positions in cantools' own terms, rejecting overlaps.
        start = draw(st.integers(0, 63))
        if big_endian:
            # Motorola: start is the MSB; following bits run down the byte, then to the next byte's bit 7.
            positions, pos = [], start
            for _ in range(length):
                positions.append(pos)
                pos = pos - 1 if pos % 8 else pos + 15
            if not all(0 <= p < 64 for p in positions):
                continue
        else:
            positions = list(range(start, start + length))
            if positions[-1] > 63:
                continue
        if not free.issuperset(positions):
            continue
        free -= set(positions)
        scale = draw(st.sampled_from([1.0, 0.5, 0.0047884033203125, 3.0]))
        offset = draw(st.sampled_from([0.0, -10.0, 2.5]))
        signals.append(
            Signal(
                f"S{i}",
                start,
                length,
                byte_order="big_endian" if big_endian else "little_endian",
                is_signed=draw(st.booleans()) and length > 1,
                conversion=cantools.database.conversion.LinearConversion(scale, offset, False),
            )
        )
    if not signals:
        signals.append(Signal("S0", 0, 8))
    return Message(0x123, "T", 8, signals, strict=True)


@settings(max_examples=60, deadline=None)
@given(message=signal_layouts(), seed=st.integers(0, 2**32 - 1))
def test_batch_decoder_matches_cantools_for_any_intel_or_motorola_signal(message: Message, seed: int) -> None:
    codec = compile_message(message)
    data = np.random.default_rng(seed).integers(0, 256, (20, 8), dtype=np.uint8)
    batch = codec.decode(data)
    for i, expected in enumerate(cantools_rows(message, data)):
        assert {k: batch[k][i] for k in expected} == pytest.approx(expected, rel=1e-12, abs=1e-12)


@settings(max_examples=40, deadline=None)
@given(message=signal_layouts(), seed=st.integers(0, 2**32 - 1))
def test_batch_encoder_writes_what_cantools_reads(message: Message, seed: int) -> None:
    codec = compile_message(message)
    rng = np.random.default_rng(seed)
    raw = {name: rng.integers(sig.raw_min, sig.raw_max + 1, 10) for name, sig in codec.signals.items()}
    data = codec.encode_raw(raw, 10)
    for i, decoded in enumerate(cantools_rows(message, data)):
        for name, sig in codec.signals.items():
            assert decoded[name] == pytest.approx(raw[name][i] * sig.scale + sig.offset, rel=1e-12, abs=1e-12)


def test_hub_samples_are_int16_covering_16_g() -> None:
    accel = load_layout(None, "hub").hub.signals["Accel1"]
    assert (accel.length, accel.signed) == (16, True)
    assert accel.raw_min * accel.scale == pytest.approx(-16 * 9.80665)
    assert (accel.raw_max + 1) * accel.scale == pytest.approx(16 * 9.80665)


def test_per_node_layout_has_three_nodes_and_the_sync() -> None:
    layout = load_layout(None, "per-node")
    assert [m.name for m in layout.messages] == ["SensorNode1", "SensorNode2", "SensorNode3", "Sync"]
    assert layout.counter_modulus == 256


@pytest.mark.parametrize(
    ("text", "layout", "message"),
    [
        (None, "hub", r"nope.dbc: cannot read the DBC file"),
        ('VERSION ""\nBO_ 256 SensorHub: 8 N\n SG_ Accel1 : x|16@1- (1,0) [0|1] "" N\n', "hub",
         r"bad.dbc: not a valid DBC file: .*Invalid syntax at line 3"),
        ('VERSION ""\n\nBS_:\n\nBU_: N\n\nBO_ 256 Other: 8 N\n SG_ Counter : 0|8@1+ (1,0) [0|255] "" N\n', "hub",
         r"bad.dbc: no message 'SensorHub', which the hub layout needs"),
        ('VERSION ""\n\nBS_:\n\nBU_: N\n\nBO_ 256 SensorHub: 8 N\n SG_ Counter : 0|8@1+ (1,0) [0|255] "" N\n', "hub",
         r"bad.dbc: message 'SensorHub' lacks signal\(s\) Accel1, Accel2"),
        (None, "per-axle", r"unknown CAN layout 'per-axle': use 'hub' or 'per-node'"),
    ],
)  # fmt: skip
def test_an_unusable_dbc_is_named_in_one_line(tmp_path: Path, text: str | None, layout: str, message: str) -> None:
    path = tmp_path / ("nope.dbc" if text is None else "bad.dbc")
    if text is not None:
        path.write_text(text)
    with pytest.raises(DbcError, match=message) as info:
        load_layout(path, layout)
    assert "\n" not in str(info.value)
