"""The duty cycle (daemon/duty.py, [duty]): what is measured of a running and a standing wagon,
on a recording (rests skip samples by their times) and on a live source (rests close the device)."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import BogiemonConfig, ConfigError, parse_config
from bogiemon.daemon.duty import DutySettings, DutySource, Phase, is_still
from bogiemon.daemon.monitor import MemoryEventLog, Monitor
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.detection import BogieGeometry, ProcessingSettings
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, MemorySource, Source
from bogiemon.drivers.can_source import CanBusPort, CanSource
from bogiemon.judgement.windowing import BlockWindows
from tests.drivers.frames import FS_HZ as CAN_FS_HZ
from tests.drivers.frames import HUB, channel_name, layout_frames, stamped_sender

FS_HZ = 50.0
STILL = 0.05  # m/s^2, [health] standstill_rms_mps2


def wagon(running: list[tuple[float, float]], duration_s: float, seed: int = 0) -> np.ndarray:
    """(n, 3) samples of a wagon running (1 m/s^2 of noise) within the given spans, standing (5 mm/s^2) elsewhere."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(duration_s * FS_HZ)) / FS_HZ
    level = np.full(t.shape, 0.005)
    for start_s, end_s in running:
        level[(t >= start_s) & (t < end_s)] = 1.0
    return rng.standard_normal((t.size, 3)) * level[:, None] + [0.0, 0.0, 9.81]


class Recording(MemorySource):
    finite = True


def recording(accel: np.ndarray, block_s: float = 1.0) -> Recording:
    n = int(block_s * FS_HZ)
    return Recording([Block(i / FS_HZ, FS_HZ, accel[i : i + n]) for i in range(0, accel.shape[0], n)])


def settings(measure_s: float, cycle_s: float, standing_after_s: float = 60.0, probe_every_s: float = 60.0, probe_s: float = 2.0) -> DutySettings:
    return DutySettings(measure_s, cycle_s, standing_after_s, probe_every_s, probe_s, STILL)


def delivered(source: Source) -> list[Block]:
    out = []
    try:
        while True:
            block = source.read(0.0)
            if block is not None:
                out.append(block)
    except EndOfStream:
        return out


def spans(blocks: list[Block]) -> list[tuple[float, float]]:
    """The delivered stretches of samples' time: consecutive blocks joined."""
    out: list[tuple[float, float]] = []
    for b in blocks:
        if out and abs(out[-1][1] - b.start_s) < 1e-9 and not b.new_stream:
            out[-1] = (out[-1][0], b.end_s)
        else:
            out.append((b.start_s, b.end_s))
    return out


def test_a_block_is_still_when_every_channel_is_quieter_than_the_level() -> None:
    rng = np.random.default_rng(1)
    quiet = rng.standard_normal((50, 3)) * 0.01 + 9.81
    assert is_still(Block(0.0, FS_HZ, quiet), STILL)
    one_moves = quiet.copy()
    one_moves[:, 2] += rng.standard_normal(50) * 0.2
    assert not is_still(Block(0.0, FS_HZ, one_moves), STILL)
    assert not is_still(Block(0.0, FS_HZ, quiet[:1]), STILL)  # one sample tells nothing


def test_a_running_wagon_is_measured_measure_s_in_every_cycle_and_each_measurement_is_a_new_stream() -> None:
    source = DutySource(recording(wagon([(0, 1800)], 1800)), settings(measure_s=300, cycle_s=600))
    blocks = delivered(source)
    assert spans(blocks) == [(0.0, 300.0), (600.0, 900.0), (1200.0, 1500.0)]
    assert [b.start_s for b in blocks if b.new_stream] == [600.0, 1200.0]
    assert source.duty.measurements == 3 and source.duty.cycle_rests == 3


def test_without_a_cycle_a_running_wagon_is_measured_whole() -> None:
    blocks = delivered(DutySource(recording(wagon([(0, 900)], 900)), settings(measure_s=600, cycle_s=600)))
    assert spans(blocks) == [(0.0, 900.0)]


def test_a_standing_wagon_rests_listens_every_probe_and_is_measured_again_once_it_moves() -> None:
    source = DutySource(recording(wagon([(0, 300), (1500, 1800)], 1800)), settings(measure_s=3600, cycle_s=3600))
    blocks = delivered(source)
    # Still from 300 s: 60 s of it measured, then rests of 60 s and listens of 2 s, the last of
    # which hears the wagon move again (from 1500 s) and starts a measurement there.
    probe_starts = [360.0 + 60.0 + k * 62.0 for k in range(30)]
    first_moving = next(p for p in probe_starts if p + 2.0 > 1500.0)
    expected_start = max(first_moving, 1500.0)
    assert spans(blocks) == [(0.0, 360.0), (expected_start, 1800.0)]
    assert [b.start_s for b in blocks if b.new_stream] == [expected_start]
    assert source.duty.probes == sum(p + 2.0 <= 1500.0 for p in probe_starts)
    assert source.duty.standing_rests == source.duty.probes + 1 and source.duty.measurements == 2


def test_a_short_stop_is_measured_through() -> None:
    blocks = delivered(DutySource(recording(wagon([(0, 300), (330, 600)], 600)), settings(measure_s=3600, cycle_s=3600)))
    assert spans(blocks) == [(0.0, 600.0)]


def test_a_measurements_new_stream_starts_a_segment_that_is_no_gap() -> None:
    source = DutySource(recording(wagon([(0, 1800)], 1800)), settings(measure_s=300, cycle_s=600))
    windows = BlockWindows(lambda fs_hz: ProcessingSettings(fs_hz=fs_hz, window_s=60.0, hop_s=10.0, max_lag_s=5.0), BogieGeometry(), 150.0, keep_starts=True)
    for block in delivered(source):
        windows.feed(block)
    assert [(s.start_s, s.gap) for s in windows.segment_starts] == [(0.0, False), (600.0, False), (1200.0, False)]


class LiveWagon(Source):
    """A live source on a fake clock: a 1 s block of the wagon at the clock's time per read, none
    while paused (the device closed); counts its pauses."""

    def __init__(self, accel: np.ndarray) -> None:
        self.fs_hz = FS_HZ
        self.counters = HealthCounters()
        self.now_s = 0.0
        self.accel = accel
        self.pauses = 0
        self.read_while_paused = 0
        self.paused = False

    def clock(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.now_s += seconds

    def pause(self) -> None:
        self.pauses += 1
        self.paused = True

    def read(self, timeout_s: float) -> Block | None:
        self.paused = False  # a read opens the device again
        i = int(round(self.now_s * FS_HZ))
        if i >= self.accel.shape[0]:
            raise EndOfStream
        block = Block(self.now_s, FS_HZ, self.accel[i : i + int(FS_HZ)])
        self.now_s += 1.0
        return block


def test_a_live_source_is_paused_for_a_rest_and_sleeps_while_it_says_it_rests() -> None:
    live = LiveWagon(wagon([(0, 1200)], 1200))
    source = DutySource(live, settings(measure_s=300, cycle_s=600), clock=live.clock, sleep=live.sleep)
    resting_reads = 0
    blocks = []
    try:
        while True:
            was_resting = source.resting
            block = source.read(0.5)
            if block is None:
                assert was_resting and source.phase in (Phase.CYCLE_REST, Phase.MEASURING)
                resting_reads += 1
            else:
                blocks.append(block)
    except EndOfStream:
        pass
    assert spans(blocks) == [(0.0, 300.0), (600.0, 900.0)]
    assert live.pauses == 2 and resting_reads == 2 * 300 / 0.5


def test_a_paused_can_source_reopens_its_bus_as_at_the_start_with_nothing_counted_lost() -> None:
    port = CanBusPort("virtual", channel_name())
    sender = stamped_sender(port.channel)
    source = CanSource(port, HUB, CAN_FS_HZ, max_block_s=0.1)
    try:
        for message in layout_frames(HUB, np.arange(0, 50)):
            sender.send(message)
        before = source.read(1.0)
        source.pause()
        for message in layout_frames(HUB, np.arange(50, 100)):  # sent while the bus is closed: never read
            sender.send(message)
        assert not source.connected
        assert source.read(0.05) is None  # opened again, nothing queued on the new bus yet
        for message in layout_frames(HUB, np.arange(100, 150)):
            sender.send(message)
        after = source.read(1.0)
    finally:
        source.close()
        sender.shutdown()
    assert before is not None and after is not None
    assert after.start_s == pytest.approx(1000.0 + 100 / CAN_FS_HZ) and after.gap_before
    extra = source.counters.extra
    assert source.counters.reconnects == 0 and extra["disconnects"] == 0 and source.counters.gaps == 0


def test_the_watchdog_sees_a_resting_source_as_progress() -> None:
    class Resting(Source):
        fs_hz = FS_HZ
        counters = HealthCounters()
        resting = True

        def read(self, timeout_s: float) -> Block | None:
            time.sleep(0.01)
            return None

    pipeline = Pipeline(Resting(), Monitor(BogiemonConfig().monitor_settings("full", FS_HZ), MemoryEventLog()), BlockRing(1000))
    pipeline.last_progress_monotonic = start = time.monotonic() - 100.0
    pipeline.start()
    try:
        deadline = time.monotonic() + 10.0
        while pipeline.last_progress_monotonic == start and time.monotonic() < deadline:
            time.sleep(0.01)
    finally:
        pipeline.stop()
    assert pipeline.last_progress_monotonic > start


@pytest.mark.parametrize(
    ("duty", "message"),
    [
        ("measure_min = 2.0\nevery_min = 10.0", r"duty.measure_min \(2 min\) must hold more than one analysis window and a hop \(processing.window_s \+ hop_s = 130 s\)"),
        ("measure_min = 20.0\nevery_min = 10.0", r"duty: measure_min \(20\) must not exceed every_min \(10\)"),
    ],
)
def test_a_duty_cycle_that_cannot_judge_is_refused_by_the_config(duty: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_config(f"[duty]\nenabled = true\n{duty}\n", "t.toml")


def test_the_config_gives_the_duty_cycle_in_seconds_with_the_health_sections_stillness() -> None:
    config = parse_config("[duty]\nenabled = true\nmeasure_min = 10.0\nevery_min = 30.0\n[health]\nstandstill_rms_mps2 = 0.07\n", "t.toml")
    assert config.duty_settings() == DutySettings(600.0, 1800.0, 60.0, 60.0, 2.0, 0.07)
    assert parse_config("", "t.toml").duty_settings() is None


def test_replay_with_duty_judges_only_the_measured_stretches_of_a_recording(tmp_path: Path) -> None:
    from bogiemon.daemon.replay import replay
    from bogiemon.drivers.recording import write_csv_recording
    from tests.daemon.synthetic import FS_HZ as SHORT_FS_HZ
    from tests.daemon.synthetic import bogie_accel, short_windows_config

    accel = bogie_accel(180, seed=4)
    path = tmp_path / "run.csv"
    write_csv_recording(path, np.arange(accel.shape[0]) / SHORT_FS_HZ, accel)
    plain = parse_config(short_windows_config(), "t.toml")
    cycled = parse_config(short_windows_config() + "\n[duty]\nenabled = true\nmeasure_min = 0.5\nevery_min = 1.0\n", "t.toml")
    whole = replay([path], plain)
    measured = replay([path], cycled, duty=True)
    # 6 s windows every 2 s: (180 - 6) / 2 + 1 over the whole run, (30 - 6) / 2 + 1 per 30 s measurement.
    assert whole.counters.windows == 88 and measured.counters.windows == 3 * 13
    assert measured.counters.segments == 3
