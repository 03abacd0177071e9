"""The room the recorder leaves the event store (docs/recorder.md, "The reserve"): the free space it
never takes, an upper bound of a recording's size before it is written, and the deletion of the
recorder's own oldest files (only they: names of NAME_PATTERN, regular files) to make room."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.recording_format import RecordingFormat

MIB = 1 << 20
# The recorder's own files, and only they, count towards the cap and are ever deleted; a name is
# the UTC time of its first sample, so name order is time order.
NAME_PATTERN = re.compile(r"\d{8}T\d{6}Z_(?:suspected|confirmed|periodic)(?:-\d+)?(?:\.csv\.gz|\.parquet)")

# The free space the recorder leaves to the event store (docs/recorder.md, "The reserve"): what the
# store takes for a long time, from figures measured with the real store on a tmpfs (4 KiB pages)
# and checked by tests/daemon/test_recorder_space.py. The store is SQLite in WAL mode: the WAL grows
# until a commit takes it past SQLite's default checkpoint of 1000 pages (measured ceiling 4.17 MB,
# 1012 frames of 4 KiB + 24 B; with the 32 KiB -shm index), and is deleted at every clean stop, so
# it grows again after each start: 7 to 8 pages (30 kB) an event commit, the ceiling within about
# 135 events. store.py's LOW_SPACE_BYTES (256 KiB) is only where a refused commit is named a full disk.
STORE_WAL_BYTES = 5 * MIB  # the WAL at its ceiling and the -shm, 0.9 MB to spare (a batch of held events past it)
# An event committed with the monitor's state, in the main file: measured 1 066 B (the demo wagon's
# CONFIRMED of 864 B and its state of 1.5 kB), 860 B (the tests' short windows).
STORE_EVENT_BYTES = 1536
STORE_EVENTS = 10_000  # the events the reserve has room for: 10 a day for nearly 3 years
STORE_STATUS_BYTES = 1024  # a status message waiting in the MQTT outbox: measured 819 B for one of 795 B


def event_store_reserve_bytes(status_outbox_messages: int) -> int:
    """The free space the recorder never takes from the event store: its WAL at the ceiling,
    STORE_EVENTS events, and status_outbox_messages MQTT status messages waiting to be sent (the
    outbox bound when MQTT sends status messages, else 0)."""
    return STORE_WAL_BYTES + STORE_EVENTS * STORE_EVENT_BYTES + status_outbox_messages * STORE_STATUS_BYTES


# With MQTT's default outbox of 10 000 messages: 30 842 880 B (29.4 MiB); 20 602 880 B (19.6 MiB) without.
DEFAULT_RESERVE_BYTES = event_store_reserve_bytes(10_000)
# What a file may take beyond its bytes rounded up to the file system's blocks: an extent block, a
# directory block more for its name (generous: ext4, f2fs and tmpfs take a block or two at most).
FILE_SLACK_BYTES = 64 * 1024
_CSV_HEADER_BYTES = len("time_s,a1,a2,a3\n")
_BOUND_CHUNK_ROWS = 1 << 16


class DeletionCounters(Protocol):
    """What an eviction counts (the recorder's RecorderCounters)."""

    write_errors: int
    files_deleted: int
    bytes_deleted: int


def recording_bound_bytes(time_s: NDArray[np.float64], accel_mps2: NDArray[np.floating], form: RecordingFormat = RecordingFormat.CSV_GZ) -> int:
    """An upper bound of the size of the recording drivers/recording.py writes for these samples.

    Parquet: four float64 columns of the samples as they are (8 bytes a value when neither the
    dictionary nor zstd helps: pyarrow then writes them plain, and zstd's frame adds at most a few
    bytes a 128 KiB block), plus 64 KiB for the footer and the pages' headers. CSV:
    The text: each value "%.6f" is its sign (of -0.0 too), the digits of its whole part (at most
    those of floor(|x|) + 1, rounding included), a point and 6 decimals, then a comma or a newline
    ("nan", "inf" and "-inf" take at most 4). Deflate expands incompressible text by at most 5 bytes
    a 16 KiB block, and gzip adds 18 bytes (zlib's technical details): counted here as 8 bytes a
    16 KiB block and 64. About 2.9 times what a bogie's samples compress to (docs/recorder.md).
    """
    if form is RecordingFormat.PARQUET:
        raw_bytes = 4 * 8 * time_s.shape[0]
        return raw_bytes + raw_bytes // 4096 + 65536
    text_bytes = _CSV_HEADER_BYTES
    for start in range(0, time_s.shape[0], _BOUND_CHUNK_ROWS):  # in chunks: an hour at 500 Hz is 1.8 M rows
        rows = slice(start, start + _BOUND_CHUNK_ROWS)
        text_bytes += _text_bytes_bound(time_s[rows]) + sum(_text_bytes_bound(accel_mps2[rows, i]) for i in range(3))
    return text_bytes + text_bytes // 2048 + 64


def _text_bytes_bound(values: NDArray[np.floating]) -> int:
    values = np.asarray(values, dtype=np.float64)
    finite = np.isfinite(values)
    digits = np.floor(np.log10(np.where(finite, np.abs(values), 0.0) + 1.0)) + 1.0
    return int((np.where(finite, np.signbit(values) + digits + 7.0, 4.0) + 1.0).sum())



def evict_oldest(directory: Path, reserve_bytes: int, needed_bytes: int, counters: DeletionCounters, log: Any) -> int:
    """Delete the recorder's oldest files until needed_bytes fit above the reserve, or, when
    deleting them all would not make that room, until the reserve is free; the free bytes then."""
    free_bytes = _free_bytes(directory)
    if free_bytes - needed_bytes >= reserve_bytes:
        return free_bytes
    files = own_files(directory)
    held_bytes = sum(disk_bytes for _, _, disk_bytes in files)
    target = reserve_bytes + needed_bytes if free_bytes + held_bytes - needed_bytes >= reserve_bytes else reserve_bytes
    deleted_n = deleted_bytes = 0
    for name, size, _ in files:
        if free_bytes >= target:
            break
        try:
            (directory / name).unlink()
        except FileNotFoundError:
            pass  # an uploader took it meanwhile
        except OSError as exc:  # the disk refuses: the next files would fare no better
            counters.write_errors += 1
            log.error("cannot delete an old recording", path=str(directory / name), error=exc.strerror or str(exc))
            break
        else:
            counters.files_deleted += 1
            counters.bytes_deleted += size
            deleted_n += 1
            deleted_bytes += size
        free_bytes = _free_bytes(directory)  # measured: a file an uploader holds open frees nothing yet
    if deleted_n:
        log.info(
            "deleted the oldest recordings to keep the event store's reserve free", path=str(directory), files=deleted_n,
            bytes=deleted_bytes, free_bytes=free_bytes, reserve_bytes=reserve_bytes, needed_bytes=needed_bytes,
        )  # fmt: skip
    return free_bytes



def _free_bytes(directory: Path) -> int:
    """Free space on the folder's file system, as an unprivileged process (the event store) may use it."""
    usage = os.statvfs(directory)
    return usage.f_bavail * usage.f_frsize


def own_files(directory: Path) -> list[tuple[str, int, int]]:
    """The recorder's own files in the folder, oldest first: (name, size, bytes taken on the disk).
    Names of the pattern, regular files only: nothing else is ever counted or deleted."""
    files = []
    with os.scandir(directory) as entries:
        for entry in entries:
            if not NAME_PATTERN.fullmatch(entry.name):
                continue
            try:
                if not entry.is_file(follow_symlinks=False):
                    continue
                stat = entry.stat(follow_symlinks=False)
            except FileNotFoundError:
                continue  # an uploader took it while we looked
            files.append((entry.name, stat.st_size, stat.st_blocks * 512))
    return sorted(files)


