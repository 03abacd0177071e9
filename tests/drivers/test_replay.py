"""Replay: recordings (CSV, Parquet) and CAN logs (.log, .asc, .blf) as sources, paced or not, ending with
EndOfStream; recordings read as they are replayed; bad lines, identifiers and time stamps in a log counted
and skipped."""

from __future__ import annotations

import csv
import io
import os
import threading
from pathlib import Path

import can
import numpy as np
import pytest

from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.drivers.columns import nominal_rate_hz
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import MAX_ACCEL_MPS2, RecordingError, read_recording, write_csv_recording, write_parquet_recording
from bogiemon.drivers.replay import CsvReplaySource, open_replay
from bogiemon.drivers.replay_can import MAX_PACED_PAUSE_S, CanLogReplaySource
from tests.drivers.frames import FS_HZ, HUB, LSB_MPS2, PER_NODE, check_blocks, coded_accel, layout_frames, write_recording


def drain(source: Source) -> list:
    blocks = []
    with pytest.raises(EndOfStream):
        for _ in range(10_000):
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    return blocks


class FakeClock:
    """Time that moves only when the source sleeps: pacing checked exactly, without waiting."""

    def __init__(self) -> None:
        self.now_s = 0.0
        self.sleeps: list[float] = []

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.sleeps.append(seconds)
        self.now_s += seconds


def test_csv_replay_as_fast_as_possible_returns_the_recording(tmp_path: Path) -> None:
    accel = write_recording(tmp_path / "run.csv", 1234)
    source = open_replay(tmp_path / "run.csv", rate=0, layout=None, fs_hz=FS_HZ, max_block_s=1.0)
    blocks = drain(source)
    assert [b.n_samples for b in blocks] == [500, 500, 234]
    assert [b.gap_before for b in blocks] == [True, False, False]
    assert blocks[1].start_s == pytest.approx(101.0)
    np.testing.assert_allclose(np.concatenate([b.accel_mps2 for b in blocks]), accel, atol=1e-9)
    assert source.finite and source.counters.frames == 1234


def test_csv_replay_in_real_time_delivers_samples_only_once_their_time_has_come(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 1000)
    clock = FakeClock()
    source = CsvReplaySource(tmp_path / "run.csv", rate=1.0, max_block_s=1.0, clock=clock, sleep=clock.sleep)
    assert source.read(0.25).n_samples == 126  # samples 0..125 are due at t = 0.25 s (sample 0 at once)
    block = source.read(5.0)  # waits for a full block, no longer
    assert block.n_samples == 500 and clock.now_s == pytest.approx((126 + 499) / FS_HZ)
    assert source.read(0.0) is None and source.counters.timeouts == 1


def test_csv_replay_at_rate_n_is_n_times_faster(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 1000)
    clock = FakeClock()
    source = CsvReplaySource(tmp_path / "run.csv", rate=10.0, max_block_s=1.0, clock=clock, sleep=clock.sleep)
    drain(source)
    assert clock.now_s == pytest.approx(999 / FS_HZ / 10)


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
@pytest.mark.parametrize("layout", [HUB, PER_NODE], ids=["hub", "per-node"])
def test_can_logs_replay_the_recording_within_quantisation(tmp_path: Path, suffix: str, layout) -> None:
    accel = write_recording(tmp_path / "run.csv", 700)
    frames = write_can_log(tmp_path / f"run{suffix}", layout, accel, FS_HZ, start_s=1.7e9)
    assert frames == 700 * layout.frames_per_instant
    source = open_replay(tmp_path / f"run{suffix}", rate=0, layout=layout, fs_hz=FS_HZ)
    blocks = drain(source)
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    assert [b.gap_before for b in blocks] == [True] + [False] * (len(blocks) - 1)
    if suffix != ".asc":  # python-can reads .asc times from the measurement start
        assert blocks[0].start_s == pytest.approx(1.7e9, abs=1e-5)


def test_a_candump_log_with_lost_frames_replays_as_two_segments(tmp_path: Path) -> None:
    path = tmp_path / "lost.log"
    k = np.concatenate([np.arange(0, 120), np.arange(125, 300)])
    with can.Logger(str(path)) as writer:
        for message in layout_frames(HUB, k):
            message.channel = "vcan0"
            writer.on_message_received(message)
    # candump -L's own format, as can-utils writes it: "(time) interface id#data".
    assert path.read_text().splitlines()[0].startswith("(1000.000000) vcan0 100#")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    segments = check_blocks(drain(source))
    assert [(s[0], s[-1]) for s in segments] == [(0, 119), (125, 299)]
    assert source.counters.gaps == 1 and source.counters.extra["lost_samples"] == 5


def test_a_can_log_replays_at_the_pace_of_its_time_stamps(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    write_can_log(path, HUB, np.zeros((1000, 3)), FS_HZ, start_s=5000.0)
    clock = FakeClock()
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=2.0, max_block_s=0.5, clock=clock, sleep=clock.sleep)
    first = source.read(10.0)
    assert first.n_samples == 250 and clock.now_s == pytest.approx(249 / FS_HZ / 2)
    drain(source)
    assert clock.now_s == pytest.approx(999 / FS_HZ / 2)


def test_a_truncated_log_line_ends_the_replay_counted_not_raised(tmp_path: Path) -> None:
    path = tmp_path / "torn.log"
    write_can_log(path, HUB, np.zeros((100, 3)), FS_HZ, start_s=0.0)
    path.write_text(path.read_text() + "(1.000000) vcan0 10")  # the logger was killed mid-line
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    assert sum(b.n_samples for b in drain(source)) == 100
    assert source.counters.bad_frames == 1 and "torn.log" in (source.last_error or "")


@pytest.mark.parametrize(
    ("name", "message"),
    [("run.mp3", r"run.mp3: not a recording bogiemon replays"), ("missing.log", r"missing.log: cannot read the recording: No such file")],
)
def test_an_unusable_replay_file_is_named_in_one_line(tmp_path: Path, name: str, message: str) -> None:
    if name.endswith(".mp3"):
        (tmp_path / name).write_bytes(b"ID3")
    with pytest.raises(RecordingError, match=message):
        open_replay(tmp_path / name, rate=0, layout=HUB, fs_hz=FS_HZ)


def log_lines(path: Path, layout, n: int, start_s: float = 1000.0) -> list[str]:
    """The lines of a candump -L log of n coded instants (tests/drivers/frames.py)."""
    write_can_log(path, layout, coded_accel(np.arange(n)), FS_HZ, start_s=start_s)
    return path.read_text().splitlines()


def with_stamp(line: str, stamp: str) -> str:
    """A candump -L line, "(time) interface id#data", with another time field."""
    return f"({stamp})" + line[line.index(")") + 1 :]


def test_an_asc_frame_id_too_large_for_a_c_long_is_counted_as_unknown_and_skipped(tmp_path: Path) -> None:
    path = tmp_path / "run.asc"
    write_can_log(path, HUB, coded_accel(np.arange(200)), FS_HZ, start_s=0.0)
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if " Tx " in line)
    lines[first + 50] = lines[first + 50].replace(" 100 ", " FFFFFFFFFFFFFFFFFFFF ", 1)
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    segments = check_blocks(drain(source))
    assert [(s[0], s[-1]) for s in segments] == [(0, 49), (51, 199)]
    assert source.counters.extra["unknown_ids"] == source.counters.bad_frames == 1


@pytest.mark.parametrize("stamp", ["nan", "inf", "-inf", "1e300"])
@pytest.mark.parametrize("where", [0, 120], ids=["first", "middle"])
def test_a_log_frame_with_an_unusable_time_stamp_is_counted_and_skipped(tmp_path: Path, stamp: str, where: int) -> None:
    path = tmp_path / "run.log"
    lines = log_lines(path, HUB, 300)
    lines[where] = with_stamp(lines[where], stamp)
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    blocks = drain(source)
    assert source.counters.extra["bad_timestamps"] == source.counters.bad_frames == 1
    assert all(1000.0 <= b.start_s < 1001.0 for b in blocks)
    kept = np.concatenate(check_blocks(blocks))
    np.testing.assert_array_equal(kept, np.delete(np.arange(300), where))


def test_an_unparseable_line_in_the_middle_of_a_log_is_counted_and_the_rest_replayed(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    lines = log_lines(path, HUB, 300)
    lines[150] = "(1000.300000) can0 this is no frame"
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    segments = check_blocks(drain(source))
    assert [(s[0], s[-1]) for s in segments] == [(0, 149), (151, 299)]
    assert source.counters.extra["unreadable_entries"] == source.counters.bad_frames == 1
    assert source.last_error.startswith(f"{path}: unreadable CAN log line after 150 frames, skipped: ValueError")


def test_unparseable_lines_in_an_asc_log_are_counted_and_the_rest_replayed_with_its_header(tmp_path: Path) -> None:
    path = tmp_path / "run.asc"
    write_can_log(path, HUB, coded_accel(np.arange(300)), FS_HZ, start_s=0.0)
    lines = path.read_text().splitlines()
    first = next(i for i, line in enumerate(lines) if " Tx " in line)
    for k in (100, 200):
        lines[first + k] = lines[first + k][:-2] + "ZZ"  # a data byte that is no hex number
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    blocks = drain(source)
    assert [(s[0], s[-1]) for s in check_blocks(blocks)] == [(0, 99), (101, 199), (201, 299)]
    assert source.counters.extra["unreadable_entries"] == 2
    assert blocks[-1].start_s == pytest.approx(201 / FS_HZ)  # times still relative to the header's start


def test_an_asc_log_with_a_damaged_base_header_counts_it_and_replays_past_a_bad_line(tmp_path: Path) -> None:
    # Found by make fuzz (canlog-asc): python-can reads "base heX" from the header, then refuses
    # it; the header counts as an unreadable entry and the frames are read as hex, the default.
    path = tmp_path / "run.asc"
    write_can_log(path, HUB, coded_accel(np.arange(300)), FS_HZ, start_s=0.0)
    lines = path.read_text().splitlines()
    base = next(i for i, line in enumerate(lines) if line.startswith("base "))
    lines[base] = lines[base].replace("base hex", "base heX")
    first = next(i for i, line in enumerate(lines) if " Tx " in line)
    lines[first + 100] = lines[first + 100][:-2] + "ZZ"
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    assert [(s[0], s[-1]) for s in check_blocks(drain(source))] == [(0, 99), (101, 299)]
    assert source.counters.extra["unreadable_entries"] == 2  # the header's base line and the bad frame


def test_a_paced_replay_of_a_log_whose_first_time_stamp_is_nan_does_not_stall(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    lines = log_lines(path, HUB, 500, start_s=5000.0)
    lines[0] = with_stamp(lines[0], "nan")
    path.write_text("\n".join(lines) + "\n")
    clock = FakeClock()
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=1.0, max_block_s=0.5, clock=clock, sleep=clock.sleep)
    assert sum(b.n_samples for b in drain(source)) == 499
    assert clock.now_s == pytest.approx(498 / FS_HZ)


def test_a_paced_replay_waits_out_a_long_silence_for_max_paced_pause_s_only(tmp_path: Path) -> None:
    path = tmp_path / "run.log"
    lines = log_lines(path, HUB, 200, start_s=5000.0)
    lines[100] = with_stamp(lines[100], "4000000000.0")  # a stamp from 2096
    path.write_text("\n".join(lines) + "\n")
    clock = FakeClock()
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=1.0, clock=clock, sleep=clock.sleep)
    drain(source)
    assert clock.now_s < MAX_PACED_PAUSE_S + 1.0


def test_a_blf_with_a_corrupt_header_is_one_recording_error(tmp_path: Path) -> None:
    path = tmp_path / "run.blf"
    path.write_bytes(b"LOGG" + bytes(20))
    with pytest.raises(RecordingError, match=r"run.blf: not a readable CAN log"):
        open_replay(path, rate=0, layout=HUB, fs_hz=FS_HZ)


def test_a_blf_with_a_corrupt_object_ends_the_replay_there_counted(tmp_path: Path) -> None:
    path = tmp_path / "run.blf"
    write_can_log(path, HUB, coded_accel(np.arange(300)), FS_HZ, start_s=1.7e9)
    data = bytearray(path.read_bytes())
    data[-40:] = b"\x00" * 40  # the last container's tail: zlib cannot decompress it
    path.write_bytes(bytes(data))
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    drain(source)
    assert source.counters.extra["unreadable_entries"] == 1
    assert "replay ends here" in (source.last_error or "")


def test_a_blf_object_declaring_zero_bytes_ends_the_replay_instead_of_spinning(tmp_path: Path) -> None:
    path = tmp_path / "run.blf"
    with can.BLFWriter(str(path), compression_level=0) as writer:  # containers stored, not deflated
        for message in layout_frames(HUB, np.arange(300)):
            writer.on_message_received(message)
    data = bytearray(path.read_bytes())
    objects = [i for i in range(len(data)) if data[i : i + 4] == b"LOBJ"]
    # objects[0] is the container; [1] the first frame. Python-can's parser advanced by this size
    # and stayed on the object for ever.
    data[objects[150] + 8 : objects[150] + 12] = bytes(4)
    path.write_bytes(bytes(data))
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    finished = threading.Event()

    def drain_all() -> None:
        drain(source)
        finished.set()

    thread = threading.Thread(target=drain_all, daemon=True)
    thread.start()
    assert finished.wait(60), "the replay spun on a zero-length object"
    assert source.counters.extra["unreadable_entries"] == 1
    assert "BLFParseError: an object of a container declares 0 bytes" in (source.last_error or "")
    assert source.counters.frames == 149  # the frames before it


# --- Recordings read as they are replayed (CSV and Parquet) ----------------------------------------


def whole_file_blocks(path: Path, block_n: int) -> list[Block]:
    """The blocks of a recording held whole in memory (the replay before it streamed), from the
    csv module's reading of it: consecutive block_n samples, the rate of the whole file."""
    rows = list(csv.reader(io.StringIO(path.read_text())))[1:]
    data = np.array([[float(cell) for cell in row] for row in rows])
    fs_hz = nominal_rate_hz((data[-1, 0] - data[0, 0]) / (data.shape[0] - 1))  # snapped to the whole hertz
    return [
        Block(float(data[i, 0]), fs_hz, data[i : i + block_n, 1:], gap_before=i == 0) for i in range(0, data.shape[0], block_n)
    ]


def assert_same_blocks(got: list[Block], expected: list[Block]) -> None:
    assert len(got) == len(expected)
    for g, e in zip(got, expected, strict=True):
        assert (g.start_s, g.fs_hz, g.gap_before, g.status) == (e.start_s, e.fs_hz, e.gap_before, e.status)
        np.testing.assert_array_equal(g.accel_mps2, e.accel_mps2)


@pytest.mark.parametrize("block_s", [1.0, 0.37, 7.0])
def test_a_recording_read_as_it_is_replayed_gives_the_blocks_of_the_whole_file(tmp_path: Path, block_s: float) -> None:
    write_recording(tmp_path / "run.csv", 130_000, start_s=1.7e9)  # several megabytes of text: many chunks
    source = open_replay(tmp_path / "run.csv", rate=0, layout=None, fs_hz=FS_HZ, max_block_s=block_s)
    assert_same_blocks(drain(source), whole_file_blocks(tmp_path / "run.csv", round(block_s * FS_HZ)))
    assert source.counters.frames == 130_000


def test_a_paced_replay_of_a_long_recording_delivers_every_block_once_its_time_has_come(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 60_000)
    clock = FakeClock()
    source = CsvReplaySource(tmp_path / "run.csv", rate=50.0, max_block_s=1.0, clock=clock, sleep=clock.sleep)
    blocks = []
    with pytest.raises(EndOfStream):
        while True:
            block = source.read(1.0)
            if block is not None:
                assert clock.now_s >= (block.end_s - 1 / FS_HZ - 100.0) / 50.0 - 1e-9  # its last sample is due
                blocks.append(block)
    assert_same_blocks(blocks, whole_file_blocks(tmp_path / "run.csv", 500))
    assert clock.now_s == pytest.approx(59_999 / FS_HZ / 50.0)


def test_a_bad_row_found_late_ends_the_replay_after_every_sample_before_it(tmp_path: Path) -> None:
    accel = write_recording(tmp_path / "run.csv", 100_000)
    lines = (tmp_path / "run.csv").read_text().splitlines()
    lines[1 + 70_123] = lines[1 + 70_123].replace(",", ",?", 1)  # 140 s in, megabytes after the open
    (tmp_path / "run.csv").write_text("\n".join(lines) + "\n")
    source = open_replay(tmp_path / "run.csv", rate=0, layout=None, fs_hz=FS_HZ)
    assert source.fs_hz == 99_999 / (float(lines[-1].split(",")[0]) - 100.0)  # the rate is known at the open
    blocks = []
    with pytest.raises(RecordingError, match=r"run.csv: line 70125: a1 is not a number: '\?"):
        for _ in range(1000):
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    got = np.concatenate([b.accel_mps2 for b in blocks])
    np.testing.assert_array_equal(got, accel[:70_123])  # all of them, the last block a short one
    assert [b.n_samples for b in blocks][-2:] == [500, 123]


def test_a_parquet_recording_replays_in_the_blocks_of_the_same_csv(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 80_000, start_s=1.7e9)
    rec = read_recording(tmp_path / "run.csv")
    write_parquet_recording(tmp_path / "run.parquet", rec.time_s, rec.accel_mps2)
    blocks = {name: drain(open_replay(tmp_path / name, rate=0, layout=None, fs_hz=FS_HZ)) for name in ("run.csv", "run.parquet")}
    assert_same_blocks(blocks["run.parquet"], blocks["run.csv"])


def test_clipped_samples_are_counted_by_the_replay_source(tmp_path: Path) -> None:
    t = np.arange(1000) / FS_HZ
    accel = np.full((1000, 3), 9.81)
    accel[400:410, 1] = 1e308
    write_csv_recording(tmp_path / "burst.csv", t, accel)
    source = open_replay(tmp_path / "burst.csv", rate=0, layout=None, fs_hz=FS_HZ)
    got = np.concatenate([b.accel_mps2 for b in drain(source)])
    assert source.counters.extra["clipped_samples"] == 10
    assert np.all(got[400:410, 1] == MAX_ACCEL_MPS2) and np.isfinite(got).all()


def test_a_log_line_of_megabytes_is_counted_and_skipped_unread_and_the_rest_replays(tmp_path: Path) -> None:
    path = tmp_path / "long.log"
    lines = log_lines(path, HUB, 200)
    lines.insert(100, "(1000.1) vcan0 100#" + "0" * (8 << 20))  # 8 MiB on one line, in the middle
    path.write_text("\n".join(lines) + "\n")
    source = CanLogReplaySource(path, HUB, FS_HZ, rate=0)
    assert sum(b.n_samples for b in drain(source)) == 200
    assert source.counters.extra["unreadable_entries"] == 1
    assert "long.log: line 101: longer than 64 KiB" in (source.last_error or "")


def test_a_fifo_named_as_a_recording_is_refused_without_blocking(tmp_path: Path) -> None:
    for name in ("pipe.csv", "pipe.log"):
        os.mkfifo(tmp_path / name)  # nobody writes to it: an open for reading would block
        with pytest.raises(RecordingError, match=rf"{name}: not a regular file; a (recording|CAN log) is"):
            open_replay(tmp_path / name, rate=0, layout=HUB, fs_hz=FS_HZ)
