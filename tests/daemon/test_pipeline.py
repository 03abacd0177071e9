"""The pipeline (daemon/pipeline.py): its source thread tells the journal when a live source falls
behind real time, by how much, and when it has caught up (BehindWatch); its threads are named in
the kernel, where `top -H` shows them."""

from __future__ import annotations

import threading
from pathlib import Path

import structlog

from bogiemon.daemon.config import parse_config
from bogiemon.daemon.monitor import MemoryEventLog, Monitor
from bogiemon.daemon.pipeline import BEHIND_S, BehindWatch, Pipeline, name_os_thread
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config


class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def test_falling_behind_is_said_once_with_how_far_and_catching_up_with_the_most_and_how_long() -> None:
    clock = Clock()
    with structlog.testing.capture_logs() as logs:
        watch = BehindWatch(structlog.get_logger(), clock)
        for behind_s in (0.0, 0.4, BEHIND_S - 0.01):
            watch.observe(behind_s)
        assert logs == []  # under a second behind: blocks being filled and handed on, not a lag
        watch.observe(2.5)
        clock.now_s += 3.0
        for behind_s in (7.25, 3.0, 0.5):
            watch.observe(behind_s)
        clock.now_s += 1.0
        watch.observe(0.0)
        watch.observe(0.0)
    assert [(e["event"], e["log_level"]) for e in logs] == [
        ("the source fell behind real time", "warning"),
        ("the source caught up with real time", "info"),
    ]
    assert logs[0]["behind_s"] == 2.5
    assert logs[1]["behind_at_most_s"] == 7.25 and logs[1]["behind_for_s"] == 4.0


class LaggingSource(Source):
    """A live source that hands on its blocks and says it is behind by the given seconds after each."""

    finite = False

    def __init__(self, blocks: list[Block], behind: list[float]) -> None:
        self.fs_hz = FS_HZ
        self.counters = HealthCounters()
        self._blocks, self._behind = blocks, behind
        self._next = 0

    def read(self, timeout_s: float) -> Block | None:
        if self._next >= len(self._blocks):
            raise EndOfStream  # ends the test's pipeline; a live source would wait
        self._next += 1
        return self._blocks[self._next - 1]

    def behind_s(self) -> float:
        return self._behind[self._next - 1]


def test_the_pipeline_logs_a_live_source_that_falls_behind_and_catches_up() -> None:
    config = parse_config(short_windows_config(), "test")
    blocks = as_blocks(bogie_accel(10, seed=1))  # 20 blocks
    behind = [0.0] * len(blocks)
    behind[5:9] = [1.5, 4.0, 2.0, 0.0]
    monitor = Monitor(config.monitor_settings(), MemoryEventLog())
    with structlog.testing.capture_logs() as logs:
        pipeline = Pipeline(LaggingSource(blocks, behind), monitor, BlockRing(10_000, backpressure=True))
        pipeline.start()
        assert pipeline.wait(30)
        pipeline.stop()
    said = [e for e in logs if "real time" in e["event"]]
    assert [e["event"] for e in said] == ["the source fell behind real time", "the source caught up with real time"]
    assert said[0]["behind_s"] == 1.5 and said[1]["behind_at_most_s"] == 4.0


def test_a_thread_named_for_the_kernel_shows_its_name_in_proc() -> None:
    seen: list[str] = []

    def run() -> None:
        name_os_thread("bogiemon-source-and-more")  # longer than the kernel's 15 bytes
        seen.append(Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip())

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    assert seen == ["bogiemon-source"]
    assert Path(f"/proc/self/task/{threading.get_native_id()}/comm").read_text().strip() != "bogiemon-source"
