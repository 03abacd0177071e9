"""CAN frames in, checked and aligned samples out: the part of the CAN source that sees frames.

CanFrameDecoder takes frames in batches (whatever a read() gathered) as the columns of a
FrameBatch (drivers/can_frames.py), or as python-can Messages (replay), sorts them into error
frames, remote frames, unknown identifiers, wrong lengths and frames of the layout, decodes the
latter with the compiled DBC in one pass of numpy per batch, checks the sequence counter and
hands the accepted samples to a SampleQueue. It never raises for what is on the bus.

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
from bogiemon.drivers.can_frames import (  # noqa: F401 - the error classes, also named here for callers
    BUS_OFF,
    CAN_ERR_BUSOFF,
    CAN_ERR_CRTL,
    CAN_ERR_CRTL_RX_OVERFLOW,
    CAN_EXT_ID_MAX,
    CAN_STD_ID_MAX,
    ERROR,
    REMOTE,
    RX_OVERFLOW,
    FrameBatch,
)
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.segments import RESTART_AFTER_BEHIND, SampleQueue, SequenceTracker, TimestampGuard

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
        # Each frame's class: the index of its message in layout.messages (for the per-node
        # layout the channel of a node, then the Sync), OTHER for the DBC's other messages,
        # UNKNOWN for the rest; looked up by key in one searchsorted per batch.
        self._messages = layout.messages
        self._other = len(self._messages)
        self._unknown = self._other + 1
        by_key = {**dict.fromkeys(layout.other_keys, self._other), **{m.key: i for i, m in enumerate(self._messages)}}
        self._sorted_keys = np.array(sorted(by_key), dtype=np.int64)
        self._class_of_key = np.array([by_key[k] for k in self._sorted_keys.tolist()] + [self._unknown], dtype=np.int64)
        self._length_of_class = np.array([m.length for m in self._messages] + [-1, -1], dtype=np.int64)
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
        """Decode a batch of python-can Messages in arrival order (replay, tests)."""
        if messages:
            self.feed_frames(FrameBatch.from_messages(messages))

    def feed_frames(self, frames: FrameBatch) -> None:
        """Decode a batch of frames in arrival order."""
        if frames.n == 0:
            return
        errors = np.flatnonzero(frames.flags & ERROR)
        if errors.size == 0:
            self._feed_frames(frames)
            return
        start = 0
        for i in errors.tolist():  # a bus-off splits the batch: nothing is bridged across it
            self._feed_frames(frames[start:i])
            if self._count_error_frame(int(frames.flags[i])):
                self.restart()
            start = i + 1
        self._feed_frames(frames[start:])

    def _count_error_frame(self, flags: int) -> bool:
        """Count an error frame; True if it reports bus-off."""
        self.counters.add("error_frames")
        if flags & RX_OVERFLOW:
            self.counters.add("rx_overflow")
        if flags & BUS_OFF:
            self.counters.add("bus_off")
            return True
        return False

    def _feed_frames(self, frames: FrameBatch) -> None:
        if frames.n == 0:
            return
        passed = self._guard.check(frames.time_s)  # counts what it rejects
        if not passed.all():
            frames = frames[passed]
            if frames.n == 0:
                return
        position = np.minimum(np.searchsorted(self._sorted_keys, frames.key), self._sorted_keys.size - 1)
        known = self._sorted_keys[position] == frames.key
        frame_class = np.where(known, self._class_of_key[position], self._unknown)
        remote = (frames.flags & REMOTE) != 0
        layout_frame = (frame_class < self._other) & ~remote
        good = layout_frame & (frames.length == self._length_of_class[frame_class])
        n_good = int(good.sum())
        self.counters.frames += n_good
        if n_good < frames.n:  # something else than well-formed frames of the layout: count it
            n_remote = int(remote.sum())
            n_wrong = int(layout_frame.sum()) - n_good
            n_other = int(((frame_class == self._other) & ~remote).sum())
            n_unknown = frames.n - n_remote - int(layout_frame.sum()) - n_other
            for name, count in (("remote_frames", n_remote), ("wrong_length", n_wrong), ("unknown_ids", n_unknown)):
                if count:
                    self.counters.add(name, count)
                    self.counters.bad_frames += count
            if n_other:
                self.counters.add("other_dbc_frames", n_other)
        if self.layout.hub is not None:
            index = np.flatnonzero(good) if n_good < frames.n else None
            self._feed_hub(frames, index)
        else:
            self._feed_nodes(frames, np.flatnonzero(good & (frame_class < len(self.layout.nodes))), frame_class)

    def _feed_hub(self, frames: FrameBatch, index: NDArray[np.intp] | None) -> None:
        """The hub's frames (index: which of the batch; None: all of them)."""
        codec = self.layout.hub
        assert codec is not None
        data, times_s = (frames.data, frames.time_s) if index is None else (frames.data[index], frames.time_s[index])
        if data.shape[0] == 0:
            return
        le, be = codec.words(data[:, : codec.length])
        sig = codec.signals
        counter = sig["Counter"].raw(le, be)
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

    def _feed_nodes(self, frames: FrameBatch, index: NDArray[np.intp], frame_class: NDArray[np.int64]) -> None:
        """The nodes' frames (index: which of the batch, in arrival order), joined into instants."""
        assert self._aligner is not None
        if index.size == 0:
            return
        channel = frame_class[index]
        counter = np.empty(index.size, np.int64)
        value = np.empty(index.size, np.float64)
        status = np.empty(index.size, np.uint8)
        for c, codec in enumerate(self.layout.nodes):
            mine = channel == c
            if not mine.any():
                continue
            le, be = codec.words(frames.data[index[mine], : codec.length])
            sig = codec.signals
            counter[mine] = sig["Counter"].raw(le, be)
            value[mine] = sig["Accel"].decode(le, be)
            status[mine] = status_bits(sig["OverRange"].raw(le, be), sig["SensorFault"].raw(le, be))
        out = self._aligner.push(channel, counter, value, status, frames.time_s[index])
        self._count_verdict(out.duplicates, out.out_of_order, out.lost)
        self.queue.append(out.accel_mps2, out.status, out.new_segment, out.times_s)

    def _count_verdict(self, duplicates: int, out_of_order: int, lost: int) -> None:
        if duplicates:
            self.counters.add("duplicates", duplicates)
        if out_of_order:
            self.counters.add("out_of_order", out_of_order)
        if lost:
            self.counters.add("lost_samples", lost)


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
