"""Replay: CSV recordings and CAN logs (.log, .asc, .blf) as sources, paced or not, ending with EndOfStream."""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from bogiemon.drivers.base import EndOfStream, Source
from bogiemon.drivers.player import write_can_log
from bogiemon.drivers.recording import RecordingError
from bogiemon.drivers.replay import CanLogReplaySource, CsvReplaySource, open_replay
from tests.drivers.frames import FS_HZ, HUB, LSB_MPS2, PER_NODE, check_blocks, layout_frames, write_recording


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
    assert source.counters.bad_frames == 1 and "torn.log" in source.last_error


@pytest.mark.parametrize(
    ("name", "message"),
    [("run.mp3", r"run.mp3: not a recording bogiemon replays"), ("missing.log", r"missing.log: cannot read the CAN log")],
)
def test_an_unusable_replay_file_is_named_in_one_line(tmp_path: Path, name: str, message: str) -> None:
    if name.endswith(".mp3"):
        (tmp_path / name).write_bytes(b"ID3")
    with pytest.raises(RecordingError, match=message):
        open_replay(tmp_path / name, rate=0, layout=HUB, fs_hz=FS_HZ)
