"""Replay: recordings through exactly the pipeline and decision of `run`, as fast as possible.

Each recording becomes the replay source the daemon itself would build from
`[source] kind = "replay"`, and the same Pipeline (source thread, ring with backpressure,
processing thread) feeds one Monitor: the alarm state carries from one recording to the next as
it would on the wagon, and each recording starts a new segment. Events go to a real event store:
the given state directory, or a temporary one that disappears afterwards.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from bogiemon.daemon.config import BogiemonConfig, ReplaySourceConfig
from bogiemon.daemon.monitor import Monitor, MonitorCounters, WindowReport
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.sources import open_source
from bogiemon.daemon.store import EventStore


@dataclass(frozen=True)
class ReplaySummary:
    recordings: int
    counters: MonitorCounters
    final_mode: str


def replay(
    paths: Sequence[str | Path],
    config: BogiemonConfig,
    load: str | None = None,
    realtime: bool = False,
    state_dir: str | Path | None = None,
    sinks: Sequence[EventSink] = (),
    observers: Sequence[Callable[[WindowReport], None]] = (),
) -> ReplaySummary:
    with tempfile.TemporaryDirectory(prefix="bogiemon-replay-") as scratch:
        store = EventStore(state_dir if state_dir is not None else scratch)
        try:
            monitor: Monitor | None = None
            for path in paths:
                source_config = ReplaySourceConfig(kind="replay", path=str(path), realtime=realtime)
                run_config = config.model_copy(update={"source": source_config})
                source = open_source(run_config)
                if monitor is None:
                    monitor = Monitor(config.monitor_settings(load, source.fs_hz), store, sinks, observers)
                ring = BlockRing(max(1, int(config.pipeline.ring_capacity_s * source.fs_hz)), backpressure=source.finite)
                pipeline = Pipeline(source, monitor, ring)
                pipeline.start()
                try:
                    pipeline.wait()
                finally:
                    pipeline.stop()
                    source.close()
                if pipeline.error is not None:
                    raise pipeline.error
            assert monitor is not None, "replay needs at least one recording"
            monitor.save_state()
            return ReplaySummary(len(paths), monitor.counters, monitor.mode)
        finally:
            store.close()
