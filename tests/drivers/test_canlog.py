"""CAN logs in every format python-can writes (and their gzip forms), read through the one bounded
open: the same samples from each; candump's human format and CANedge's .MFC refused with their
remedy; the file read is the one that was checked, whatever happens to its name afterwards."""

from __future__ import annotations

import gzip
import os
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from bogiemon.drivers.base import EndOfStream, Source
from bogiemon.drivers.canlog import MAX_BLF_CONTAINER_BYTES, LogFrames
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import RecordingError
from bogiemon.drivers.replay import open_replay
from bogiemon.drivers.replay_can import CanLogReplaySource
from tests.drivers.frames import FS_HZ, HUB, coded_accel

START_S = 1.7645e9  # 2025-12-01


def samples(source: Source) -> np.ndarray:
    out = []
    with pytest.raises(EndOfStream):
        for _ in range(10_000):
            block = source.read(1.0)
            if block is not None:
                out.append(block.accel_mps2)
    source.close()
    return np.concatenate(out)


def write_log(path: Path, accel: np.ndarray) -> None:
    """A CAN log of the hub's frames; a .db in python-can's SQLite schema written here (python-can
    4.6's SqliteWriter, a thread that writes in batches of 500, had written 501 of 600 frames
    when its stop() returned)."""
    if path.suffix != ".db":
        write_can_log(path, HUB, accel, FS_HZ, start_s=START_S)
        return
    from bogiemon.drivers.player import iter_messages

    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE messages (ts REAL, arbitration_id INTEGER, extended INTEGER, remote INTEGER, error INTEGER, dlc INTEGER, data BLOB)")
        db.executemany(
            "INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)",
            [(m.timestamp, m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_error_frame, m.dlc, bytes(m.data))
             for _, m in iter_messages(HUB, accel, FS_HZ, start_s=START_S)],
        )  # fmt: skip
    db.close()


def gzipped(path: Path) -> Path:
    packed = path.with_name(path.name + ".gz")
    packed.write_bytes(gzip.compress(path.read_bytes(), mtime=0))
    return packed


@pytest.mark.parametrize(
    ("suffix", "compressed"),
    [(s, c) for s in (".log", ".asc", ".blf", ".trc", ".csv", ".db") for c in (False, True) if not (c and s == ".db")],
)
def test_every_python_can_format_gives_the_samples_it_was_written_with(tmp_path: Path, suffix: str, compressed: bool) -> None:
    accel = coded_accel(np.arange(600))
    path = tmp_path / f"run{suffix}"
    write_log(path, accel)
    if compressed:
        path = gzipped(path)
    source = open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)
    np.testing.assert_array_equal(samples(source), accel)
    assert source.counters.bad_frames == 0


def test_a_compressed_sqlite_log_is_refused_with_its_remedy(tmp_path: Path) -> None:
    path = tmp_path / "run.db"
    write_log(path, coded_accel(np.arange(100)))
    with pytest.raises(RecordingError, match=r"run.db.gz: a python-can SQLite log cannot be read compressed: decompress it first"):
        open_replay(gzipped(path), rate=0, layout=HUB, fs_hz=FS_HZ)


def test_a_python_can_csv_log_is_told_from_a_recording_by_its_header_not_its_name(tmp_path: Path) -> None:
    accel = coded_accel(np.arange(300))
    path = tmp_path / "frames.csv"
    write_can_log(path, HUB, accel, FS_HZ, start_s=START_S)
    source = open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)
    assert isinstance(source, CanLogReplaySource)
    np.testing.assert_array_equal(samples(source), accel)


def test_candump_human_output_is_refused_saying_to_record_with_candump_l(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    path.write_text(" (2025-12-03 10:00:00.000213)  can0  100   [8]  00 11 22 33 44 55 66 77\n" * 3)
    with pytest.raises(RecordingError, match=r"candump's human output \(candump -ta.*Record with `candump -L can0 > run.log`"):
        open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)


def test_an_asc_replays_at_the_date_its_header_gives_not_in_1970(tmp_path: Path) -> None:
    path = tmp_path / "run.asc"
    write_can_log(path, HUB, coded_accel(np.arange(300)), FS_HZ, start_s=START_S)
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    first = source.read(1.0)
    assert source.start_s is not None and abs(source.start_s - START_S) < 86400
    assert abs(first.start_s - START_S) < 86400  # the header's day (python-can writes its local time)
    source.close()


def test_the_log_read_is_the_one_checked_whatever_its_name_becomes(tmp_path: Path) -> None:
    accel = coded_accel(np.arange(400))
    path = tmp_path / "run.log"
    write_can_log(path, HUB, accel, FS_HZ, start_s=START_S)
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    other = tmp_path / "other.log"
    write_can_log(other, HUB, coded_accel(np.arange(400)) * 0, FS_HZ, start_s=START_S)
    os.replace(other, path)  # another file takes the name after the check
    np.testing.assert_array_equal(samples(source), accel)


def test_a_sqlite_log_is_read_through_its_descriptor_without_writing_anything(tmp_path: Path) -> None:
    accel = coded_accel(np.arange(300))
    path = tmp_path / "run.db"
    write_log(path, accel)
    os.chmod(path, 0o444)
    before = sorted(p.name for p in tmp_path.iterdir())
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    path.unlink()  # the name is gone; the descriptor still holds the file
    np.testing.assert_array_equal(samples(source), accel)
    assert sorted(p.name for p in tmp_path.iterdir()) == [n for n in before if n != "run.db"]


def test_sqlite_rows_that_hold_no_frame_are_counted_not_loaded(tmp_path: Path) -> None:
    accel = coded_accel(np.arange(300))
    path = tmp_path / "run.db"
    write_log(path, accel)
    with sqlite3.connect(path) as db:
        db.execute("INSERT INTO messages VALUES (?, ?, 0, 0, 0, 8, ?)", (START_S + 100, 0x100, b"\0" * (1 << 20)))
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    np.testing.assert_array_equal(samples(source), accel)
    assert source.counters.extra["unreadable_entries"] == 1


def test_a_blf_container_inflating_past_its_bound_ends_the_log_counted(tmp_path: Path) -> None:
    import struct
    import zlib

    import can

    path = tmp_path / "bomb.blf"
    write_can_log(path, HUB, coded_accel(np.arange(50)), FS_HZ, start_s=START_S)
    data = path.read_bytes()
    header_size = struct.unpack_from("<I", data, 4)[0]
    packed = zlib.compress(b"\0" * (MAX_BLF_CONTAINER_BYTES + 4096), 9)
    body = can.io.blf.LOG_CONTAINER_STRUCT.pack(can.io.blf.ZLIB_DEFLATE, MAX_BLF_CONTAINER_BYTES + 4096) + packed
    obj = can.io.blf.OBJ_HEADER_BASE_STRUCT.pack(b"LOBJ", 16, 1, 16 + len(body), can.io.blf.LOG_CONTAINER) + body
    path.write_bytes(data[:header_size] + obj + b"\0" * (len(obj) % 4))
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    with pytest.raises(EndOfStream):
        source.read(1.0)
    assert source.counters.extra["unreadable_entries"] == 1
    assert "inflates to more than 16 MiB" in (source.last_error or "")


def test_a_log_gz_of_one_endless_line_is_read_within_its_bounds(tmp_path: Path) -> None:
    """The 1 MB .log.gz that took 2.1 GB: its inflation stops at 50 times its size, its line is
    never held whole."""
    path = tmp_path / "bomb.log.gz"
    with gzip.open(path, "wb", compresslevel=9) as f:
        f.write(b"(1764500000.000000) can0 100#")
        for _ in range(1024):
            f.write(b"0" * (1 << 20))
    assert path.stat().st_size < 3 << 20
    with pytest.raises(RecordingError, match=r"decompresses to more than .* \(a compression bomb\?\)"):
        samples(CanLogReplaySource(path, HUB, FS_HZ, rate=0))


def test_canedge_mfc_is_refused_saying_how_to_decompress_it(shared_mf4: Path) -> None:
    mfc = next(shared_mf4.glob("*.MFC"))
    with pytest.raises(RecordingError, match=r"a CANedge-compressed MF4 \(.MFC\).*decompress it"):
        LogFrames(mfc, print)


def test_the_canedge_mf4_frames_are_python_cans_own_frame_by_frame(shared_mf4: Path) -> None:
    """Every CAN_DataFrame of the real CANedge files, as our columnar reader gives them, against
    python-can's per-message MF4 reader (asammdf underneath): time, identifier, length, data."""
    import io

    import can

    for path in sorted(shared_mf4.glob("*.MF4")):
        log = LogFrames(path, pytest.fail)
        ours = [batch for batch in log]
        log.close()
        time_s = np.concatenate([b.time_s for b in ours])
        key = np.concatenate([b.key for b in ours])
        data = np.concatenate([b.data for b in ours])
        length = np.concatenate([b.length for b in ours])
        theirs = list(can.io.MF4Reader(io.BytesIO(path.read_bytes())))
        assert len(theirs) == time_s.shape[0] and len(theirs) > 1000, path.name
        np.testing.assert_allclose(time_s, [m.timestamp for m in theirs], rtol=0, atol=1e-6)
        np.testing.assert_array_equal(key & 0x1FFFFFFF, [m.arbitration_id for m in theirs])
        np.testing.assert_array_equal(length, [m.dlc for m in theirs])
        for i, message in enumerate(theirs):
            assert bytes(data[i, : length[i]]) == bytes(message.data)[:8], (path.name, i)


def test_the_canedge_mf4_frames_are_asammdfs_decoding_with_their_start_time(shared_mf4: Path) -> None:
    from asammdf import MDF

    import io

    path = next(shared_mf4.glob("*2F6913DB*.MF4"))  # several groups: one of data frames among them
    log = LogFrames(path, pytest.fail)
    batches = list(log)
    log.close()
    mdf = MDF(io.BytesIO(path.read_bytes()))
    signal = mdf.get("CAN_DataFrame", group=0)
    start_s = mdf.start_time.timestamp()
    mdf.close()
    time_s = np.concatenate([b.time_s for b in batches])
    assert log.start_s == start_s == 1641469561.0  # 2022-01-06 11:46:01 UTC, as the README of the fixtures says
    np.testing.assert_array_equal(time_s, signal.timestamps + start_s)
    np.testing.assert_array_equal(np.concatenate([b.key for b in batches]), signal.samples["CAN_DataFrame.ID"])


def test_an_mf4_bus_log_written_by_python_can_replays_the_samples_it_was_written_with(tmp_path: Path) -> None:
    accel = coded_accel(np.arange(600))
    path = tmp_path / "run.mf4"
    write_can_log(path, HUB, accel, FS_HZ, start_s=START_S)
    source = open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)
    np.testing.assert_array_equal(samples(source), accel)


def test_an_mf4_without_asammdf_says_which_extra_to_install(tmp_path: Path, shared_mf4: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "asammdf", None)
    path = next(shared_mf4.glob("*.MF4"))
    with pytest.raises(RecordingError, match=r"^reading MF4 files needs asammdf, an extra of bogiemon: pip install 'bogiemon\[mf4\]'$"):
        open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)


def test_an_mf4_whose_zipped_blocks_inflate_past_its_size_is_refused_before_inflating(tmp_path: Path) -> None:
    import struct

    path = tmp_path / "bomb.mf4"
    body = bytearray(b"MDF     4.10    bogiemon" + b"\0" * 40)
    dz = struct.pack("<4s4xQQ2sBxIQQ", b"##DZ", 48 + 16, 0, b"DT", 0, 0, 1 << 30, 16) + b"\0" * 16
    path.write_bytes(bytes(body) + dz)
    with pytest.raises(RecordingError, match=r"bomb.mf4: a zipped data block at byte 64 inflates to 1 GiB from 16 bytes"):
        open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)


def test_a_trc_whose_columns_header_lacks_the_type_counts_every_line_and_ends(tmp_path: Path) -> None:
    # Found by make fuzz (canlog-trc): each line failed with KeyError 'T', and at the end of the
    # file the resumed reader failed on no line at all, again and again.
    path = tmp_path / "run.trc"
    write_log(path, coded_accel(np.arange(20)))
    path.write_text(path.read_text().replace(";$COLUMNS=N,O,T,B,I,d,R,L,D", ";$COLUMNS=N,O,TlB,I,d,R,L,D"))
    unreadable: list[str] = []
    frames = LogFrames(path, unreadable.append)
    try:
        assert sum(batch.n for batch in frames) == 0
    finally:
        frames.close()
    assert len(unreadable) == 20
    assert unreadable[0] == f"{path}: unreadable CAN log line after 0 frames, skipped: KeyError: 'T'"


@pytest.mark.parametrize(
    ("schema", "what"),
    [
        ("CREATE VIEW messages AS WITH RECURSIVE r(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM r) SELECT i * 0.002 AS ts, 256 AS "
         "arbitration_id, 0 AS extended, 0 AS remote, 0 AS error, 8 AS dlc, zeroblob(8) AS data FROM r", "its messages a view"),
        ("CREATE TABLE messages (ts REAL, arbitration_id INTEGER, extended INTEGER, remote INTEGER, error INTEGER, dlc INTEGER, "
         "data BLOB GENERATED ALWAYS AS (zeroblob(999000000)) VIRTUAL)", "its column\\(s\\) data computed when read"),
    ],
)  # fmt: skip
def test_a_sqlite_log_whose_messages_are_computed_when_read_is_refused(tmp_path: Path, schema: str, what: str) -> None:
    # Found by make fuzz (canlog-sqlite): an endless recursive view kept the reader in SQLite forever.
    path = tmp_path / "run.db"
    with sqlite3.connect(path) as db:
        db.execute(schema)
    db.close()
    with pytest.raises(RecordingError, match=rf"run.db: not a python-can SQLite log \({what}\): expected its table 'messages' of stored rows"):
        open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)
