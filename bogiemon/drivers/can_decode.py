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
from dataclasses import dataclass
from typing import NamedTuple

import can
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import HealthCounters, SensorStatus
from bogiemon.drivers.can_frames import BUS_OFF, ERROR, REMOTE, RX_OVERFLOW, FrameBatch
from bogiemon.drivers.candb import CanLayout, MessageCodec
from bogiemon.drivers.segments import RESTART_AFTER_BEHIND, SampleQueue, SequenceTracker, TimestampGuard
from bogiemon.drivers.counters import counters

CAN_COUNTERS = counters(
    "duplicates", "out_of_order", "lost_samples", "unknown_ids", "other_dbc_frames", "wrong_length", "remote_frames",
    "error_frames", "bus_off", "rx_overflow", "dropped_by_kernel", "disconnects", "open_failures",
)


def max_silence_s(modulus: int, fs_hz: float) -> float:
    """The longest pause a CAN stream may have and stay one segment: just under half a counter period.

    Beyond it a counter jump is ambiguous (see SequenceTracker).
    """
    return (modulus // 2 - 1) / fs_hz


def status_bits(over_range: NDArray[np.number], fault: NDArray[np.number]) -> NDArray[np.uint8]:
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
        # The nodes' frames decode in one pass where the DBC lays their signals out alike (the
        # shipped one does), else node by node.
        nodes = layout.nodes
        self._node_codecs = nodes[:1] if nodes and all((n.length, n.signals) == (nodes[0].length, nodes[0].signals) for n in nodes) else nodes
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
        if len(self._node_codecs) == 1:
            counter, value, status = self._decode_node(self._node_codecs[0], frames.data[index])
        else:
            counter = np.empty(index.size, np.int64)
            value = np.empty(index.size, np.float64)
            status = np.empty(index.size, np.uint8)
            for c, codec in enumerate(self._node_codecs):
                mine = channel == c
                if mine.any():
                    counter[mine], value[mine], status[mine] = self._decode_node(codec, frames.data[index[mine]])
        out = self._aligner.push(channel, counter, value, status, frames.time_s[index])
        self._count_verdict(out.duplicates, out.out_of_order, out.lost)
        self.queue.append(out.accel_mps2, out.status, out.new_segment, out.times_s)

    @staticmethod
    def _decode_node(codec: MessageCodec, data: NDArray[np.uint8]) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.uint8]]:
        """Counter, acceleration and status bits of node frames' data (n, 8)."""
        le, be = codec.words(data[:, : codec.length])
        sig = codec.signals
        return sig["Counter"].raw(le, be), sig["Accel"].decode(le, be), status_bits(sig["OverRange"].raw(le, be), sig["SensorFault"].raw(le, be))

    def _count_verdict(self, duplicates: int, out_of_order: int, lost: int) -> None:
        if duplicates:
            self.counters.add("duplicates", duplicates)
        if out_of_order:
            self.counters.add("out_of_order", out_of_order)
        if lost:
            self.counters.add("lost_samples", lost)


class NodeFrames(NamedTuple):
    """A batch of node frames in arrival order, (n,) each: channel 0..2, counter, value, status bits, receive time."""

    channel: NDArray[np.int64]
    counter: NDArray[np.int64]
    value: NDArray[np.float64]
    status: NDArray[np.uint8]
    times_s: NDArray[np.float64]


@dataclass(frozen=True)
class AlignedSamples:
    """Complete sampling instants assembled by NodeAligner.push, in counter order.

    accel_mps2 (m, 3), status (m, 3) per channel, new_segment (m,): the instant starts a segment
    (instants were lost before it), times_s (m,): the receive time of each instant's first frame;
    and the frames dropped (duplicates, out_of_order) and instants lost in this push.
    """

    accel_mps2: NDArray[np.float64]
    status: NDArray[np.uint8]
    new_segment: NDArray[np.bool_]
    times_s: NDArray[np.float64]
    duplicates: int = 0
    out_of_order: int = 0
    lost: int = 0

    @classmethod
    def from_rows(cls, rows: list[tuple[list[float], list[int], bool, float]], duplicates: int, out_of_order: int, lost: int) -> AlignedSamples:
        n = len(rows)
        return cls(
            np.array([r[0] for r in rows], dtype=np.float64).reshape(n, 3),
            np.array([r[1] for r in rows], dtype=np.uint8).reshape(n, 3),
            np.array([r[2] for r in rows], dtype=bool),
            np.array([r[3] for r in rows], dtype=np.float64),
            duplicates,
            out_of_order,
            lost,
        )


class NodeAligner:
    """The per-node layout: three frame streams joined into instants by their shared counter.

    Each node answers the gateway's Sync with its sample tagged with the Sync's counter; an
    instant is complete when all three answers with that counter are in. Instants are emitted
    in counter order. An instant still incomplete when any node is `window` counts past it is
    lost: the segment ends there and the next complete instant starts a new one.

    The rules are those of `_push_frame_by_frame`, one frame at a time: the definition, and what
    runs for a batch that is not regular. A regular batch (the steady state: no pause beyond
    max_silence_s, no frame repeated or behind the instant being assembled, within a segment that
    has delivered, lost instants allowed) is joined in numpy by `_push_regular`, with the same
    result to the bit (tests/drivers/test_node_aligner.py checks it against the frame-by-frame
    rules with hypothesis).
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
        """Join a batch of node frames in arrival order: channel (0..2), counter, value, status bits, receive time (n,)."""
        frames = NodeFrames(channel, counter, value, status, times_s)
        joined = self._push_regular(frames)
        if joined is not None:
            return joined
        return self._push_frame_by_frame(frames)

    def _push_regular(self, frames: NodeFrames) -> AlignedSamples | None:
        """A regular batch joined in numpy; None (and nothing changed) if the batch is not regular.

        In instants counted from the next one to emit (u: each frame's, unwrapped along the
        batch), the rules come down to this when every frame is accepted: instant v is passed
        (emitted if complete, else lost) at the frame where it completes or where a frame
        `window` instants ahead arrives, whichever comes first, and never before instant v - 1.
        The batch is regular when each frame then lies ahead of the instant being assembled at
        its arrival by less than half the counter period, and is no repeat.
        """
        channel, counter, value, status, times_s = frames
        n = channel.shape[0]
        if n == 0:
            return AlignedSamples.from_rows([], 0, 0, 0)
        if self._next is None or not self._segment_emitted or self._last_time_s is None:
            return None  # a segment's start has rules of its own
        modulus, window, half = self.modulus, self.window, self.modulus // 2
        if times_s[0] - self._last_time_s > self.max_silence_s or bool((times_s[1:] - times_s[:-1] > self.max_silence_s).any()):
            return None
        first = self._next
        u = np.empty(n, np.int64)
        u[0] = (int(counter[0]) - first) % modulus
        u[1:] = u[0] + np.cumsum((counter[1:] - counter[:-1] + half) % modulus - half)
        have = np.array(self._have, dtype=np.int64)
        slots = np.flatnonzero(have)
        pending_at = (slots - first) % modulus  # instants waiting for frames, counted from next
        if pending_at.size and int(pending_at.max()) >= half:
            return None
        size = int(max(u.max(), pending_at.max(initial=-1))) + 1
        if int(u.min()) < 0 or size > 2 * n + modulus:
            return None  # frames from before the instant being assembled, or counters far apart
        bit = np.left_shift(1, channel)
        pending = np.zeros(size, np.int64)
        pending[pending_at] = have[slots]
        frame = np.arange(n)
        answers = np.zeros((size, 3), np.int64)  # frames per instant and node
        np.add.at(answers, (u, channel), 1)
        if bool((pending[u] & bit).any()) or int(answers.max()) > 1:
            return None  # a frame repeated
        bits = pending | (answers[:, 0] | answers[:, 1] << 1 | answers[:, 2] << 2)
        last = np.full(size, -1)
        np.maximum.at(last, u, frame)
        done = np.where(bits == 0b111, last, n)  # the frame completing each instant (-1: before the batch, n: none)
        floor = np.maximum.accumulate(u - window + 1)  # next is at least this after each frame
        pushed_past = np.searchsorted(floor, np.arange(size), side="right")  # first frame with floor > v
        passed_at = np.maximum.accumulate(np.minimum(done, pushed_past))
        next_before = np.searchsorted(passed_at, frame, side="left")  # instants passed before each frame
        ahead = u - next_before
        if bool((ahead < 0).any()) or bool((ahead >= half).any()):
            return None  # behind the instant being assembled: out of order, or a restart
        # Regular: every frame is accepted. Commit the state and emit.
        passed = passed_at < n
        n_passed = int(passed.sum())
        emitted = passed & (done <= passed_at)
        lost_mask = passed & ~emitted
        rows = np.flatnonzero(emitted)
        values = np.zeros((size, 3))
        bits_status = np.zeros((size, 3), np.uint8)
        first_time_s = np.zeros(size)
        values[pending_at] = self._values[slots]
        bits_status[pending_at] = self._status[slots]
        first_time_s[pending_at] = [self._first_time_s[s] for s in slots.tolist()]
        values[u, channel] = value
        bits_status[u, channel] = status
        first_frame = np.full(size, n)
        np.minimum.at(first_frame, u, frame)
        first_time_s = np.where(pending != 0, first_time_s, times_s[np.minimum(first_frame, n - 1)])
        lost_before = np.cumsum(lost_mask)[rows]  # instants lost up to each emitted one
        new_segment = lost_before > np.concatenate([[0], lost_before[:-1]])
        n_lost = int(lost_mask.sum())
        if rows.size:
            new_segment[0] |= self._new_segment
            self._new_segment = n_lost > int(lost_before[-1])
        else:
            self._new_segment = self._new_segment or n_lost > 0
        waiting = np.arange(n_passed, size)
        waiting = waiting[bits[waiting] != 0]
        waiting_slots = (first + waiting) % modulus
        have[(first + np.arange(min(n_passed, modulus))) % modulus] = 0
        have[waiting_slots] = bits[waiting]
        self._values[waiting_slots] = values[waiting]
        self._status[waiting_slots] = bits_status[waiting]
        for slot, time_s in zip(waiting_slots.tolist(), first_time_s[waiting].tolist(), strict=True):
            self._first_time_s[slot] = time_s
        self._have = have.tolist()
        self._next = (first + n_passed) % modulus
        self._last_time_s = float(times_s[-1])
        for c in np.flatnonzero(answers.any(axis=0)).tolist():
            self._behind[c] = 0
        return AlignedSamples(values[rows], bits_status[rows], new_segment, first_time_s[rows], lost=n_lost)

    def _push_frame_by_frame(self, frames: NodeFrames) -> AlignedSamples:
        """The rules, one frame at a time: the definition of push, and what runs for an irregular batch."""
        channel, counter, value, status, times_s = frames
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
        return AlignedSamples.from_rows(rows, duplicates, out_of_order, lost)

    def _emit(self, rows: list[tuple[list[float], list[int], bool, float]]) -> None:
        c = self._next
        assert c is not None
        rows.append((self._values[c].tolist(), self._status[c].tolist(), self._new_segment, self._first_time_s[c]))
        self._have[c] = 0
        self._new_segment = False
        self._segment_emitted = True
        self._next = (c + 1) % self.modulus
