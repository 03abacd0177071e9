"""The CAN frame layouts, read from a DBC file with cantools and compiled for numpy.

cantools reads the DBC once; each signal is then compiled into a shift, a mask, a sign and a
scale over the frame's 8 data bytes read as one 64-bit word (little-endian for Intel signals,
big-endian for Motorola), so a batch of n frames decodes in a few numpy operations instead of
n cantools calls. The compiled codec also encodes (the player, the tests).

Two layouts (docs/drivers.md), chosen by name from the same DBC:
  hub       message SensorHub: Counter, Accel1..3, OverRange1..3, SensorFault1..3;
  per-node  messages SensorNode1..3: Counter, Accel, OverRange, SensorFault each, and
            optionally Sync (Counter), the sampling trigger sent by the gateway.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Literal

import cantools
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.quoting import quoted

SHIPPED_DBC_NAME = "bogiemon.dbc"
LayoutName = Literal["hub", "per-node"]
LAYOUTS: tuple[LayoutName, ...] = ("hub", "per-node")
CAN_EFF_KEY = 1 << 31  # frame key = identifier | this bit for 29-bit identifiers


class DbcError(ValueError):
    """A DBC file that cannot be used; the message names the file and what is missing."""


@dataclass(frozen=True)
class SignalCodec:
    """One DBC signal as bit operations on a 64-bit word of the frame's 8 data bytes.

    shift: position of the signal's least significant bit in the little-endian word
      (Intel signals) or in the big-endian word (Motorola signals).
    """

    name: str
    shift: int
    length: int
    big_endian: bool
    signed: bool
    scale: float
    offset: float

    @property
    def raw_min(self) -> int:
        return -(1 << (self.length - 1)) if self.signed else 0

    @property
    def raw_max(self) -> int:
        return (1 << (self.length - 1)) - 1 if self.signed else (1 << self.length) - 1

    def raw(self, words_le: NDArray[np.uint64], words_be: NDArray[np.uint64]) -> NDArray[np.int64]:
        """The raw integer values, sign-extended, of a batch of frames' words."""
        words = words_be if self.big_endian else words_le
        mask = np.uint64((1 << self.length) - 1)
        value = ((words >> np.uint64(self.shift)) & mask).astype(np.int64)
        if self.signed:
            sign = np.int64(1 << (self.length - 1))
            value = (value ^ sign) - sign
        return value

    def decode(self, words_le: NDArray[np.uint64], words_be: NDArray[np.uint64]) -> NDArray[np.float64]:
        return (self.raw(words_le, words_be) * self.scale + self.offset).astype(np.float64, copy=False)

    def to_raw(self, physical: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
        """Raw values rounded to the nearest step and clipped to the signal's range; and where clipped."""
        raw = np.rint((np.asarray(physical, dtype=np.float64) - self.offset) / self.scale)
        clipped = (raw < self.raw_min) | (raw > self.raw_max)
        return np.clip(raw, self.raw_min, self.raw_max).astype(np.int64), clipped

    def pack(self, raw: NDArray[np.int64]) -> NDArray[np.uint64]:
        """The signal's bits placed in its word (OR the words of all signals of a frame)."""
        mask = np.uint64((1 << self.length) - 1)
        return (raw.astype(np.uint64) & mask) << np.uint64(self.shift)


@dataclass(frozen=True)
class MessageCodec:
    """One DBC message (a classical CAN frame of at most 8 bytes) compiled for batches."""

    name: str
    frame_id: int
    is_extended: bool
    length: int
    signals: dict[str, SignalCodec]

    @property
    def key(self) -> int:
        """Identifier plus extended flag: what tells frames apart on the bus."""
        return self.frame_id | (CAN_EFF_KEY if self.is_extended else 0)

    def words(self, data: NDArray[np.uint8]) -> tuple[NDArray[np.uint64], NDArray[np.uint64]]:
        """(n, length) payload bytes -> the little- and big-endian 64-bit words, zero-padded to 8 bytes."""
        n = data.shape[0]
        padded = np.zeros((n, 8), dtype=np.uint8)
        padded[:, : data.shape[1]] = data
        return padded.view("<u8").ravel(), padded.view(">u8").ravel()

    def decode(self, data: NDArray[np.uint8]) -> dict[str, NDArray[np.float64]]:
        """Every signal of a batch of payloads (n, length), in physical units."""
        le, be = self.words(data)
        return {name: sig.decode(le, be) for name, sig in self.signals.items()}

    def encode_raw(self, raw: dict[str, NDArray[np.int64]], n: int) -> NDArray[np.uint8]:
        """Payloads (n, length) from raw integer values per signal (signals left out are 0)."""
        le = np.zeros(n, dtype=np.uint64)
        be = np.zeros(n, dtype=np.uint64)
        for name, values in raw.items():
            sig = self.signals[name]
            if sig.big_endian:
                be |= sig.pack(np.broadcast_to(np.asarray(values, dtype=np.int64), (n,)))
            else:
                le |= sig.pack(np.broadcast_to(np.asarray(values, dtype=np.int64), (n,)))
        out = le.astype("<u8").view(np.uint8).reshape(n, 8) | be.astype(">u8").view(np.uint8).reshape(n, 8)
        return np.ascontiguousarray(out[:, : self.length])


def compile_message(message: cantools.database.can.Message) -> MessageCodec:
    """Compile a cantools message; raises DbcError for what the batch codec does not support."""
    if message.length > 8 or message.is_multiplexed() or message.is_container:
        raise DbcError(f"message {message.name}: only classical CAN frames (<= 8 bytes, not multiplexed) are supported")
    signals: dict[str, SignalCodec] = {}
    for sig in message.signals:
        if sig.is_float:
            raise DbcError(f"message {message.name}, signal {sig.name}: float signals are not supported")
        if sig.byte_order == "little_endian":
            shift, big_endian = sig.start, False
        else:
            # DBC numbers Motorola signals by their most significant bit, bit j of byte i being
            # 8 i + j; in the big-endian word that bit sits at 8 (7 - i) + j.
            msb = 8 * (7 - sig.start // 8) + sig.start % 8
            shift, big_endian = msb - sig.length + 1, True
        signals[sig.name] = SignalCodec(
            name=sig.name,
            shift=shift,
            length=sig.length,
            big_endian=big_endian,
            signed=sig.is_signed,
            scale=float(sig.scale),
            offset=float(sig.offset),
        )
    return MessageCodec(
        name=message.name,
        frame_id=message.frame_id,
        is_extended=message.is_extended_frame,
        length=message.length,
        signals=signals,
    )


@dataclass(frozen=True)
class CanLayout:
    """Which frames carry the three channels, compiled from a DBC.

    hub: one message with all three channels per instant (nodes empty);
    per-node: nodes[i] carries channel a(i+1); sync (optional) is the gateway's trigger.
    """

    name: LayoutName
    source: str  # the DBC it came from, for messages
    hub: MessageCodec | None = None
    nodes: tuple[MessageCodec, ...] = ()
    sync: MessageCodec | None = None
    # Keys of the DBC's other messages (the other layout's, the daemon's own alarm and heartbeat
    # frames): expected on a shared bus, so counted apart and not as bad frames.
    other_keys: frozenset[int] = frozenset()

    @property
    def data_messages(self) -> tuple[MessageCodec, ...]:
        return (self.hub,) if self.hub is not None else self.nodes

    @property
    def messages(self) -> tuple[MessageCodec, ...]:
        return self.data_messages + ((self.sync,) if self.sync is not None else ())

    @property
    def frames_per_instant(self) -> int:
        return len(self.messages)

    @property
    def counter_modulus(self) -> int:
        return 1 << self.data_messages[0].signals["Counter"].length


_HUB_SIGNALS = ("Counter", "Accel1", "Accel2", "Accel3", "OverRange1", "OverRange2", "OverRange3",
                "SensorFault1", "SensorFault2", "SensorFault3")  # fmt: skip
_NODE_SIGNALS = ("Counter", "Accel", "OverRange", "SensorFault")


def shipped_dbc_text() -> str:
    return resources.files("bogiemon.config").joinpath(SHIPPED_DBC_NAME).read_text(encoding="utf-8")


def load_layout(dbc_path: str | Path | None, layout: str) -> CanLayout:
    """The named layout from a DBC file (None: the shipped config/bogiemon.dbc). Raises DbcError."""
    if layout not in LAYOUTS:
        raise DbcError(f"unknown CAN layout '{layout}': use 'hub' or 'per-node'")
    source = str(dbc_path) if dbc_path is not None else f"shipped {SHIPPED_DBC_NAME}"
    try:
        text = shipped_dbc_text() if dbc_path is None else Path(dbc_path).read_text(encoding="utf-8")
    except OSError as exc:
        raise DbcError(f"{source}: cannot read the DBC file: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        raise DbcError(f"{source}: not a text file: expected a DBC file") from None
    try:
        db = cantools.database.load_string(text, database_format="dbc")
    except Exception as exc:  # cantools raises parser-specific errors; all mean a bad file
        raise DbcError(f"{source}: not a valid DBC file: {quoted(str(exc).splitlines()[0], 200) if str(exc) else type(exc).__name__}") from None
    assert isinstance(db, cantools.database.can.Database)  # what a DBC always loads as
    by_name = {m.name: m for m in db.messages}
    all_keys = {m.frame_id | (CAN_EFF_KEY if m.is_extended_frame else 0) for m in db.messages}

    def need(name: str, signals: tuple[str, ...]) -> MessageCodec:
        if name not in by_name:
            raise DbcError(f"{source}: no message '{name}', which the {layout} layout needs (see docs/drivers.md)")
        codec = compile_message(by_name[name])
        missing = [s for s in signals if s not in codec.signals]
        if missing:
            raise DbcError(f"{source}: message '{name}' lacks signal(s) {', '.join(missing)} of the {layout} layout")
        return codec

    if layout == "hub":
        hub = need("SensorHub", _HUB_SIGNALS)
        return CanLayout(name="hub", source=source, hub=hub, other_keys=frozenset(all_keys - {hub.key}))
    nodes = tuple(need(f"SensorNode{i}", _NODE_SIGNALS) for i in (1, 2, 3))
    if len({n.signals["Counter"].length for n in nodes}) != 1:
        raise DbcError(f"{source}: the three SensorNode Counter signals must have the same length")
    sync = need("Sync", ("Counter",)) if "Sync" in by_name else None
    mine = {n.key for n in nodes} | ({sync.key} if sync is not None else set())
    return CanLayout(name="per-node", source=source, nodes=nodes, sync=sync, other_keys=frozenset(all_keys - mine))
