"""MF4 files (ASAM MDF 4: CANedge, Vector, ...) through asammdf, read as columns.

Two kinds of MF4 come from loggers, and both are read here without a Python object per sample:

- bus logging: the raw CAN frames in CAN_DataFrame groups (CAN_RemoteFrame and CAN_ErrorFrame
  groups beside them), several groups per file possible: merged in time order into FrameBatches
  for the CAN decoder (Mf4File.frames), the times absolute from the file's start;
- signals: the accelerations as channels of a group with its time master (Mf4File.signal_group
  and .read_signals; drivers/recording_mf4.py reads them as a recording).

asammdf is an extra (`pip install 'bogiemon[mf4]'`): a gateway need not carry it, and a missing
one is one line saying so. The file is opened through drivers/files.py and asammdf reads the
checked descriptor's stream; a logger's unfinished file (CANedge writes them: "UnFinMF") is
finalised by asammdf in place, so it is first copied from that descriptor into an anonymous
temporary file. Before asammdf decompresses anything, every zipped data block (DZ) of the file
is checked against its compressed size and the file's allowance, and every group's declared
records against the same allowance: a file whose blocks inflate past what its size allows is
refused, never inflated.
"""

from __future__ import annotations

import io
import logging
import os
import shutil
import struct
import tempfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO, cast

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.can_frames import ERROR, REMOTE, FrameBatch
from bogiemon.drivers.candb import CAN_EFF_KEY
from bogiemon.drivers.files import UntrustedFile, one_line, size_text
from bogiemon.drivers.recording_format import RecordingError

if TYPE_CHECKING:
    from asammdf import MDF

MF4_MISSING = "reading MF4 files needs asammdf, an extra of bogiemon: pip install 'bogiemon[mf4]'"
# What an MF4's blocks may inflate to: zipped blocks of a logger's frames or signals inflate 3 to
# 20 times; a compression bomb a thousand.
MAX_INFLATE_RATIO = 100.0
MIN_INFLATED_BYTES = 64 << 20
# One zipped block inflates to at most this (asammdf writes 4 MiB blocks; CANedge smaller ones).
MAX_DZ_BLOCK_BYTES = 64 << 20
# Records read from a group per asammdf call: 64 Ki records of a bus log's 22 bytes is 1.4 MiB.
CHUNK_RECORDS = 1 << 16
_DZ_HEADER = struct.Struct("<4s4xQQ2sBxIQQ")  # id, length, links, original type, zip type, param, original size, data size
_ID_MASK = 0x1FFFFFFF
_ID_EXTENDED_BIT = 1 << 31  # some loggers mark an extended identifier in the ID itself

logging.getLogger("asammdf").addHandler(logging.NullHandler())  # its warnings are no user's lines


def _mdf_class() -> type[MDF]:
    try:
        from asammdf import MDF
    except ImportError:
        raise RecordingError(MF4_MISSING) from None
    return MDF


@dataclass(frozen=True)
class SignalGroup:
    """A group holding the three channels of a mapping, and its time master."""

    index: int
    channels: tuple[str, ...]
    records: int


class Mf4File:
    """An MF4 opened from a checked descriptor (drivers/files.py); close() releases asammdf's
    objects and the temporary copy of an unfinished file."""

    def __init__(self, f: UntrustedFile) -> None:
        self.path = f.path
        self.allowance_bytes = max(MIN_INFLATED_BYTES, int(MAX_INFLATE_RATIO * f.size_bytes))
        head = f.head(64)
        if not head.startswith((b"MDF     ", b"UnFinMF ")):
            raise RecordingError(f"{f.path}: not an MF4 file (no MDF identification block)")
        self._copy: BinaryIO | None = None
        _check_zipped_blocks(f, self.allowance_bytes)
        unfinished = head.startswith(b"UnFinMF ") or (len(head) >= 64 and struct.unpack_from("<H", head, 60)[0] != 0)
        # asammdf takes a buffered stream (BufferedIOBase) of the checked descriptor, reads bounded.
        stream: BinaryIO = io.BufferedReader(f, 1 << 16)
        if unfinished:
            # asammdf finalises an unfinished file in the stream it reads: a copy of our own.
            copy = tempfile.TemporaryFile(prefix="bogiemon-mf4-")  # noqa: SIM115 - closed in close()
            with f.reopen() as source:
                shutil.copyfileobj(source, copy, 1 << 20)
            copy.seek(0)
            self._copy = stream = copy
        MDF = _mdf_class()
        try:
            self.mdf = MDF(cast(Any, stream))  # asammdf's FileLike wants read(size=None)
        except RecordingError:
            self.close()
            raise
        except Exception as exc:  # noqa: BLE001 - asammdf raises many kinds for a damaged file
            self.close()
            raise RecordingError(f"{f.path}: not a readable MF4 file ({type(exc).__name__}: {one_line(str(exc), 200)})") from None
        self.groups: list[Any] = list(self.mdf.groups)  # asammdf's Group records (untyped there)
        start = self.mdf.start_time
        self.start_s = float(start.timestamp()) if start is not None else None
        for i, group in enumerate(self.groups):
            cg = group.channel_group
            declared = int(cg.cycles_nr) * (int(cg.samples_byte_nr) + int(getattr(cg, "invalidation_bytes_nr", 0)))
            if declared > self.allowance_bytes:
                self.close()
                raise RecordingError(
                    f"{f.path}: group {i} declares {int(cg.cycles_nr)} records, {size_text(declared)}: more than a file of "
                    f"{size_text(f.size_bytes)} can hold (damaged, or a compression bomb); copy it again"
                )

    def close(self) -> None:
        mdf = getattr(self, "mdf", None)
        if mdf is not None:
            mdf.close()
        if self._copy is not None:
            self._copy.close()
            self._copy = None

    # -- bus logging -----------------------------------------------------------------------------

    def bus_groups(self) -> dict[str, list[int]]:
        """The groups of CAN_DataFrame, CAN_RemoteFrame and CAN_ErrorFrame records that hold any."""
        out: dict[str, list[int]] = {"CAN_DataFrame": [], "CAN_RemoteFrame": [], "CAN_ErrorFrame": []}
        for i, group in enumerate(self.groups):
            names = {c.name for c in group.channels}
            for kind, indexes in out.items():
                if kind in names and int(group.channel_group.cycles_nr):
                    indexes.append(i)
        return out

    def frames(self, path: Path | None = None) -> Iterator[FrameBatch]:
        """Every CAN frame of the bus log's groups, merged in time order, in batches; times
        absolute where the file has its start (start_s), else from it."""
        groups = self.bus_groups()
        streams = [self._group_frames(kind, i) for kind, indexes in groups.items() for i in indexes]
        if not streams:
            raise RecordingError(
                f"{path or self.path}: an MF4 without CAN frames (no CAN_DataFrame group): if it holds signals, map its "
                "channels as a recording ([source.columns] or --columns)"
            )
        yield from _merged(streams)

    def _group_frames(self, kind: str, index: int) -> Iterator[FrameBatch]:
        records = int(self.groups[index].channel_group.cycles_nr)
        offset_s = self.start_s or 0.0
        for first in range(0, records, CHUNK_RECORDS):
            try:
                signal = self.mdf.get(kind, group=index, record_offset=first, record_count=CHUNK_RECORDS)
            except Exception as exc:  # noqa: BLE001 - asammdf raises many kinds for damaged data
                raise RecordingError(f"{self.path}: group {index} ({kind}) is not readable ({type(exc).__name__}: {one_line(str(exc), 200)}); copy it again") from None
            yield _frame_batch(kind, signal.samples, np.asarray(signal.timestamps, np.float64) + offset_s)

    # -- signals ---------------------------------------------------------------------------------

    def channel_names(self) -> list[str]:
        return sorted({c.name for g in self.groups for c in g.channels if c.name})

    def signal_group(self, channels: tuple[str, ...]) -> SignalGroup:
        """The one group holding every channel named (a logger writes a sensor's channels in one)."""
        for i, group in enumerate(self.groups):
            names = {c.name for c in group.channels}
            if all(name in names for name in channels):
                return SignalGroup(i, channels, int(group.channel_group.cycles_nr))
        known = ", ".join(self.channel_names()[:12]) or "none"
        missing = [c for c in channels if c not in {ch.name for g in self.groups for ch in g.channels}]
        where = f"no channel {', '.join(missing)}" if missing else f"channels {', '.join(channels)} are not in one group"
        raise RecordingError(f"{self.path}: {where} (its channels: {one_line(known, 200)})")

    def read_signals(self, group: SignalGroup, first: int, count: int) -> tuple[NDArray[np.float64], list[NDArray[Any]]]:
        """(time_s from the file's start, [values of each channel]) of records first..first+count."""
        try:
            wanted: list[Any] = [(name, group.index) for name in group.channels]
            signals = self.mdf.select(wanted, record_offset=first, record_count=count, raw=False)
        except Exception as exc:  # noqa: BLE001 - asammdf raises many kinds for damaged data
            raise RecordingError(f"{self.path}: group {group.index} is not readable ({type(exc).__name__}: {one_line(str(exc), 200)}); copy it again") from None
        return np.asarray(signals[0].timestamps, np.float64), [np.asarray(s.samples) for s in signals]


def open_mf4(f: UntrustedFile) -> Mf4File:
    return Mf4File(f)


def _frame_batch(kind: str, samples: NDArray[Any], time_s: NDArray[np.float64]) -> FrameBatch:
    """The FrameBatch of a chunk of a bus log group's records (a structured array of its fields)."""
    n = int(time_s.shape[0])
    names = samples.dtype.names or ()

    def field(name: str, default: int = 0) -> NDArray[Any]:
        full = f"{kind}.{name}"
        return samples[full] if full in names else np.full(n, default)

    raw_id = field("ID").astype(np.int64)
    extended = (field("IDE").astype(np.int64) != 0) | ((raw_id & _ID_EXTENDED_BIT) != 0)
    key = (raw_id & _ID_MASK) | np.where(extended, CAN_EFF_KEY, 0)
    if kind == "CAN_ErrorFrame":
        return FrameBatch(time_s, np.full(n, -1, np.int64), np.zeros(n, np.int64), np.zeros((n, 8), np.uint8), np.full(n, ERROR, np.uint8))
    length = field("DataLength", -1).astype(np.int64)
    if (length < 0).all():
        length = field("DLC").astype(np.int64)
    data = np.zeros((n, 8), np.uint8)
    full = f"{kind}.DataBytes"
    if kind == "CAN_DataFrame" and full in names:
        raw = samples[full]
        if raw.dtype == object:  # variable-length data (CAN FD logs): each record its own bytes
            for i, value in enumerate(raw):
                chunk = bytes(value)[:8]
                data[i, : len(chunk)] = np.frombuffer(chunk, np.uint8)
        else:
            raw = np.asarray(raw, np.uint8).reshape(n, -1)
            width = min(8, raw.shape[1])
            data[:, :width] = raw[:, :width]
            data[np.arange(8)[None, :] >= np.minimum(length, 8)[:, None]] = 0
    flags = np.full(n, REMOTE if kind == "CAN_RemoteFrame" else 0, np.uint8)
    if kind == "CAN_RemoteFrame":
        length = np.zeros(n, np.int64)
    return FrameBatch(time_s, key, length, data, flags)


def _merged(streams: list[Iterator[FrameBatch]]) -> Iterator[FrameBatch]:
    """The frames of several groups' batches in time order (each group's are already): what every
    group has read up to the earliest of their last times is sorted and given, stably."""
    pending: list[FrameBatch | None] = [None] * len(streams)
    live = list(range(len(streams)))
    while live:
        for i in list(live):
            if pending[i] is None or pending[i].n == 0:  # type: ignore[union-attr]
                batch = next(streams[i], None)
                if batch is None:
                    live.remove(i)
                    pending[i] = None
                else:
                    pending[i] = batch
        ready = [b for b in pending if b is not None and b.n]
        if not ready:
            return
        if len(ready) == 1 and len(live) <= 1:
            yield ready[0]
            pending = [None] * len(streams)
            continue
        until_s = min(float(pending[i].time_s[-1]) for i in live if pending[i] is not None and pending[i].n)  # type: ignore[union-attr]
        parts: list[FrameBatch] = []
        for i, batch in enumerate(pending):
            if batch is None or batch.n == 0:
                continue
            cut = int(np.searchsorted(batch.time_s, until_s, side="right"))
            parts.append(batch[:cut])
            pending[i] = batch[cut:]
        merged = _concatenate(parts)
        order = np.argsort(merged.time_s, kind="stable")
        yield merged[order]


def _concatenate(parts: list[FrameBatch]) -> FrameBatch:
    return FrameBatch(
        np.concatenate([p.time_s for p in parts]), np.concatenate([p.key for p in parts]), np.concatenate([p.length for p in parts]),
        np.concatenate([p.data for p in parts]), np.concatenate([p.flags for p in parts]),
    )  # fmt: skip


def _check_zipped_blocks(f: UntrustedFile, allowance_bytes: int) -> None:
    """Refuse a file whose zipped data blocks (##DZ) would inflate past what its size allows:
    each within MAX_DZ_BLOCK_BYTES and MAX_INFLATE_RATIO of its own compressed size, all of them
    within allowance_bytes. Blocks start at 8-byte boundaries; a match is a block when its
    declared lengths agree with each other and lie within the file (compressed data that happens
    to hold the four bytes at such a place does not)."""
    fd = f.fileno()
    total = 0
    chunk_bytes = 1 << 22
    for start in range(0, f.size_bytes, chunk_bytes):
        chunk = os.pread(fd, chunk_bytes + _DZ_HEADER.size, start)
        at = chunk.find(b"##DZ")
        while 0 <= at < min(len(chunk), chunk_bytes):
            if (start + at) % 8 == 0 and at + _DZ_HEADER.size <= len(chunk):
                _, length, links, _, _, _, original, packed = _DZ_HEADER.unpack_from(chunk, at)
                if links == 0 and length == _DZ_HEADER.size + packed and start + at + length <= f.size_bytes:
                    if original > MAX_DZ_BLOCK_BYTES or original > max(1 << 20, MAX_INFLATE_RATIO * packed):
                        raise RecordingError(
                            f"{f.path}: a zipped data block at byte {start + at} inflates to {size_text(original)} from "
                            f"{size_text(packed)}: no logger's data compresses that well (damaged, or a compression bomb)"
                        )
                    total += original
                    if total > allowance_bytes:
                        raise RecordingError(
                            f"{f.path}: its zipped data blocks inflate to more than {size_text(allowance_bytes)}, "
                            f"{MAX_INFLATE_RATIO:g} times its size: damaged, or a compression bomb"
                        )
            at = chunk.find(b"##DZ", at + 1)
