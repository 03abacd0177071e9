"""CAN frames in, checked and aligned samples out: the part of the CAN source that sees frames.

CanFrameDecoder takes python-can Messages in batches (whatever a read() gathered), sorts them
into error frames, remote frames, unknown identifiers, wrong lengths and frames of the layout,
decodes the latter with the compiled DBC in one pass of numpy per batch, checks the sequence
counter and hands the accepted samples to a SampleQueue. It never raises for what is on the bus.

Every received frame lands in exactly one of: counters.frames (well-formed frames of the layout,
the Sync included, even those the counter check then drops as duplicates or out of order),
counters.bad_frames (an unusable time stamp, an unknown or impossible identifier, wrong length,
remote frame) or extra["error_frames"]. Receive times pass a TimestampGuard (drivers/segments.py)
first, so a frame whose time stamp is not finite, absurd or behind its predecessors never
anchors a segment; identifiers beyond 29 bits (11 for a standard frame) are unknown ones.
"""

from __future__ import annotations

from collections.abc import Sequence

import can
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import HealthCounters, SensorStatus
from bogiemon.drivers.candb import CAN_EFF_KEY, CanLayout, MessageCodec
from bogiemon.drivers.segments import RESTART_AFTER_BEHIND, SampleQueue, SequenceTracker, TimestampGuard

# Error classes in the identifier of a SocketCAN error frame (linux/can/error.h).
CAN_ERR_CRTL = 0x004  # controller problem, details in data[1]
CAN_ERR_BUSOFF = 0x040
CAN_ERR_CRTL_RX_OVERFLOW = 0x01  # data[1]: the controller's receive FIFO overflowed
CAN_STD_ID_MAX = 0x7FF  # the largest 11-bit identifier
CAN_EXT_ID_MAX = 0x1FFFFFFF  # the largest 29-bit identifier

CAN_COUNTERS = (
    "duplicates",  # a frame with the counter of the one just accepted: dropped
    "out_of_order",  # a frame whose counter is behind the last accepted one: dropped
    "lost_samples",  # sampling instants missing inside counter jumps (a lower bound)
    "unknown_ids",  # frames whose identifier is in no message of the DBC, or no CAN identifier (also bad_frames)
    "other_dbc_frames",  # frames of the DBC's other messages (alarms, heartbeats): expected, ignored
    "wrong_length",  # a layout identifier with the wrong data length (also bad_frames)
    "remote_frames",  # remote-request frames (also bad_frames)
    "error_frames",  # error frames the controller reported
    "bus_off",  # of those, bus-off: the controller stopped sending and receiving
    "rx_overflow",  # of those, the controller's own receive FIFO overflowed
    "dropped_by_kernel",  # frames the socket's receive buffer had no room for (socketcan)
    "disconnects",  # the bus or interface went away under the source
    "open_failures",  # attempts to (re)open the bus that failed
)


def max_silence_s(modulus: int, fs_hz: float) -> float:
    """The longest pause a CAN stream may have and stay one segment: just under half a counter period.

    Beyond it a counter jump is ambiguous (see SequenceTracker).
    """
    return (modulus // 2 - 1) / fs_hz


def status_bits(over_range: NDArray[np.float64], fault: NDArray[np.float64]) -> NDArray[np.uint8]:
    return (over_range != 0).astype(np.uint8) * np.uint8(SensorStatus.OVER_RANGE) | (fault != 0).astype(
        np.uint8
    ) * np.uint8(SensorStatus.SENSOR_FAULT)


class CanFrameDecoder:
    """Frames of one CAN layout -> samples in a SampleQueue; counts everything it rejects."""

    def __init__(
        self, layout: CanLayout, fs_hz: float, counters: HealthCounters, queue: SampleQueue
    ) -> None:
        self.layout = layout
        self.counters = counters
        self.queue = queue
        for name in CAN_COUNTERS:
            counters.extra.setdefault(name, 0)
        modulus = layout.counter_modulus
        silence_s = max_silence_s(modulus, fs_hz)
        self._keys = {m.key: m for m in layout.messages}
        self._other_keys = np.fromiter(layout.other_keys, np.int64, len(layout.other_keys))
        self._guard = TimestampGuard(counters)
        self._tracker = SequenceTracker(modulus, silence_s)
        self._aligner = NodeAligner(modulus, silence_s) if layout.name == "per-node" else None

    def restart(self) -> None:
        """The bus was reopened or went bus-off: whatever comes next starts a new segment."""
        self._tracker.restart()
        if self._aligner is not None:
            self._aligner.restart()
        self.queue.close_segment()

    def feed(self, messages: Sequence[can.Message]) -> None:
        """Decode a batch of frames in arrival order."""
        if not messages:
            return
        errors = [i for i, m in enumerate(messages) if m.is_error_frame]
        start = 0
        for i in errors:  # a bus-off splits the batch: nothing is bridged across it
            self._feed_frames(messages[start:i])
            if self._count_error_frame(messages[i]):
                self.restart()
            start = i + 1
        self._feed_frames(messages[start:] if start else messages)

    def _count_error_frame(self, message: can.Message) -> bool:
        """Count an error frame; True if it reports bus-off."""
        self.counters.add("error_frames")
        error_class = message.arbitration_id
        if error_class & CAN_ERR_CRTL and len(message.data) > 1 and message.data[1] & CAN_ERR_CRTL_RX_OVERFLOW:
            self.counters.add("rx_overflow")
        if error_class & CAN_ERR_BUSOFF:
            self.counters.add("bus_off")
            return True
        return False

    def _feed_frames(self, messages: Sequence[can.Message]) -> None:
        if not messages:
            return
        times_s = _times_of(messages)
        passed = self._guard.check(times_s)  # counts what it rejects
        if not passed.all():
            messages = [m for m, ok in zip(messages, passed.tolist(), strict=True) if ok]
            times_s = times_s[passed]
            if not messages:
                return
        keys = _keys_of(messages)
        remote = np.fromiter((m.is_remote_frame for m in messages), bool, len(messages))
        lengths = np.fromiter((len(m.data) for m in messages), np.int64, len(messages))
        n_remote = int(remote.sum())
        if n_remote:
            self.counters.add("remote_frames", n_remote)
            self.counters.bad_frames += n_remote
        known = np.zeros(len(messages), bool)
        good: dict[int, NDArray[np.intp]] = {}
        for key, codec in self._keys.items():
            mine = (keys == key) & ~remote
            known |= mine
            ok = mine & (lengths == codec.length)
            n_wrong = int(mine.sum() - ok.sum())
            if n_wrong:
                self.counters.add("wrong_length", n_wrong)
                self.counters.bad_frames += n_wrong
            good[key] = np.flatnonzero(ok)
            self.counters.frames += good[key].size
        other = np.isin(keys, self._other_keys) & ~remote
        n_other = int((other & ~known).sum())
        if n_other:
            self.counters.add("other_dbc_frames", n_other)
        n_unknown = int((~known & ~other & ~remote).sum())
        if n_unknown:
            self.counters.add("unknown_ids", n_unknown)
            self.counters.bad_frames += n_unknown
        if self.layout.hub is not None:
            self._feed_hub(messages, good[self.layout.hub.key], times_s)
        else:
            self._feed_nodes(messages, good, times_s)

    @staticmethod
    def _payloads(messages: Sequence[can.Message], index: NDArray[np.intp], codec: MessageCodec) -> NDArray[np.uint8]:
        raw = b"".join([messages[i].data for i in index.tolist()])
        return np.frombuffer(raw, dtype=np.uint8).reshape(index.size, codec.length)

    def _feed_hub(self, messages: Sequence[can.Message], index: NDArray[np.intp], all_times_s: NDArray[np.float64]) -> None:
        if index.size == 0:
            return
        codec = self.layout.hub
        assert codec is not None
        le, be = codec.words(self._payloads(messages, index, codec))
        sig = codec.signals
        counter = sig["Counter"].raw(le, be)
        times_s = all_times_s[index]
        verdict = self._tracker.check(counter, times_s)
        self._count_verdict(verdict.duplicates, verdict.out_of_order, verdict.lost)
        keep = verdict.accept
        if not keep.any():
            return
        le, be = le[keep], be[keep]
        accel = np.column_stack([sig[f"Accel{c}"].decode(le, be) for c in (1, 2, 3)])
        status = np.column_stack(
            [status_bits(sig[f"OverRange{c}"].raw(le, be), sig[f"SensorFault{c}"].raw(le, be)) for c in (1, 2, 3)]
        )
        self.queue.append(accel, status, verdict.new_segment[keep], times_s[keep])

    def _feed_nodes(
        self, messages: Sequence[can.Message], good: dict[int, NDArray[np.intp]], all_times_s: NDArray[np.float64]
    ) -> None:
        assert self._aligner is not None
        parts = []
        for channel, codec in enumerate(self.layout.nodes):
            index = good[codec.key]
            if index.size == 0:
                continue
            le, be = codec.words(self._payloads(messages, index, codec))
            sig = codec.signals
            parts.append(
                (
                    index,
                    np.full(index.size, channel),
                    sig["Counter"].raw(le, be),
                    sig["Accel"].decode(le, be),
                    status_bits(sig["OverRange"].raw(le, be), sig["SensorFault"].raw(le, be)),
                )
            )
        if not parts:
            return
        order = np.argsort(np.concatenate([p[0] for p in parts]), kind="stable")  # back to arrival order
        index = np.concatenate([p[0] for p in parts])[order]
        channel = np.concatenate([p[1] for p in parts])[order]
        counter = np.concatenate([p[2] for p in parts])[order]
        value = np.concatenate([p[3] for p in parts])[order]
        status = np.concatenate([p[4] for p in parts])[order]
        out = self._aligner.push(channel, counter, value, status, all_times_s[index])
        self._count_verdict(out.duplicates, out.out_of_order, out.lost)
        self.queue.append(out.accel_mps2, out.status, out.new_segment, out.times_s)

    def _count_verdict(self, duplicates: int, out_of_order: int, lost: int) -> None:
        if duplicates:
            self.counters.add("duplicates", duplicates)
        if out_of_order:
            self.counters.add("out_of_order", out_of_order)
        if lost:
            self.counters.add("lost_samples", lost)


def _times_of(messages: Sequence[can.Message]) -> NDArray[np.float64]:
    """The frames' receive times in seconds; NaN for a stamp that is not a number (the guard drops it)."""
    try:
        return np.fromiter((m.timestamp for m in messages), np.float64, len(messages))
    except (TypeError, ValueError, OverflowError):
        return np.array([_as_float(m.timestamp) for m in messages], dtype=np.float64)


def _as_float(value: object) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        return float("nan")


def _keys_of(messages: Sequence[can.Message]) -> NDArray[np.int64]:
    """Frame keys (identifier | CAN_EFF_KEY for 29-bit ones); -1 for an identifier no CAN frame can carry.

    python-can's readers take identifiers as written: an .asc line may hold one too large for a
    C long, and a standard frame's beyond 11 bits would alias a 29-bit key.
    """
    n = len(messages)
    extended = np.fromiter((bool(m.is_extended_id) for m in messages), bool, n)
    try:
        ids = np.fromiter((m.arbitration_id for m in messages), np.int64, n)
    except (TypeError, ValueError, OverflowError):
        ids = np.fromiter((_id_or_minus_one(m.arbitration_id) for m in messages), np.int64, n)
    valid = (ids >= 0) & (ids <= np.where(extended, CAN_EXT_ID_MAX, CAN_STD_ID_MAX))
    return np.where(valid, ids | np.where(extended, CAN_EFF_KEY, 0), -1)


def _id_or_minus_one(arbitration_id: object) -> int:
    return arbitration_id if isinstance(arbitration_id, int) and 0 <= arbitration_id <= CAN_EXT_ID_MAX else -1


class AlignedSamples:
    """Complete sampling instants assembled by NodeAligner.push."""

    def __init__(self, rows: list[tuple[list[float], list[int], bool, float]], duplicates: int, out_of_order: int, lost: int) -> None:
        n = len(rows)
        self.accel_mps2 = np.array([r[0] for r in rows], dtype=np.float64).reshape(n, 3)
        self.status = np.array([r[1] for r in rows], dtype=np.uint8).reshape(n, 3)
        self.new_segment = np.array([r[2] for r in rows], dtype=bool)
        self.times_s = np.array([r[3] for r in rows], dtype=np.float64)
        self.duplicates = duplicates
        self.out_of_order = out_of_order
        self.lost = lost


class NodeAligner:
    """The per-node layout: three frame streams joined into instants by their shared counter.

    Each node answers the gateway's Sync with its sample tagged with the Sync's counter; an
    instant is complete when all three answers with that counter are in. Instants are emitted
    in counter order. An instant still incomplete when any node is `window` counts past it is
    lost: the segment ends there and the next complete instant starts a new one.
    """

    def __init__(self, modulus: int, max_silence_s: float, window: int = 16) -> None:
        if not 1 <= window < modulus // 2:
            raise ValueError(f"window {window} must be below half the counter modulus {modulus}")
        self.modulus = modulus
        self.max_silence_s = max_silence_s
        self.window = window
        self._values = np.zeros((modulus, 3))
        self._status = np.zeros((modulus, 3), dtype=np.uint8)
        self._have = [0] * modulus  # bit c set: channel c's frame for this counter is in
        self._first_time_s = [0.0] * modulus
        self._next: int | None = None  # counter of the next instant to emit
        self._segment_emitted = False  # the current segment has delivered an instant
        self._new_segment = True
        self._last_time_s: float | None = None
        self._behind = [0, 0, 0]

    def restart(self) -> None:
        self._have = [0] * self.modulus
        self._next = None
        self._segment_emitted = False
        self._new_segment = True
        self._behind = [0, 0, 0]

    def push(
        self,
        channel: NDArray[np.int64],
        counter: NDArray[np.int64],
        value: NDArray[np.float64],
        status: NDArray[np.uint8],
        times_s: NDArray[np.float64],
    ) -> AlignedSamples:
        rows: list[tuple[list[float], list[int], bool, float]] = []
        duplicates = out_of_order = lost = 0
        half = self.modulus // 2
        for ch, c, v, st, t in zip(
            channel.tolist(), counter.tolist(), value.tolist(), status.tolist(), times_s.tolist(), strict=True
        ):
            if self._last_time_s is not None and t - self._last_time_s > self.max_silence_s:
                self.restart()
            self._last_time_s = t
            if self._next is None:
                self._next = c
            ahead = (c - self._next) % self.modulus
            if ahead >= half and not self._segment_emitted and (self._next - c) % self.modulus < self.window:
                # A segment's first frames may come from several instants in any order: it
                # begins at the earliest instant seen so far.
                self._next, ahead = c, 0
            if ahead >= half:
                self._behind[ch] += 1
                if self._behind[ch] < RESTART_AFTER_BEHIND:
                    out_of_order += 1
                    continue
                self.restart()  # this node (and so the sync master) restarted its counter
                self._next, ahead = c, 0
            self._behind[ch] = 0
            bit = 1 << ch
            if self._have[c] & bit:
                duplicates += 1
                continue
            if self._have[c] == 0:
                self._first_time_s[c] = t
            self._have[c] |= bit
            self._values[c, ch] = v
            self._status[c, ch] = st
            # Instants left incomplete while this node is `window` ahead will never complete.
            while ahead >= self.window:
                if self._have[self._next] != 0b111:
                    self._have[self._next] = 0
                    if self._segment_emitted:
                        lost += 1
                        self._new_segment = True
                    self._next = (self._next + 1) % self.modulus
                    ahead -= 1
                else:
                    self._emit(rows)
                    ahead -= 1
            while self._have[self._next] == 0b111:
                self._emit(rows)
        return AlignedSamples(rows, duplicates, out_of_order, lost)

    def _emit(self, rows: list[tuple[list[float], list[int], bool, float]]) -> None:
        c = self._next
        assert c is not None
        rows.append((self._values[c].tolist(), self._status[c].tolist(), self._new_segment, self._first_time_s[c]))
        self._have[c] = 0
        self._new_segment = False
        self._segment_emitted = True
        self._next = (c + 1) % self.modulus
