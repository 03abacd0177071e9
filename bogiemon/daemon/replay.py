"""Replay: recordings through exactly the pipeline and decision of `run`, as fast as possible.

Each recording becomes the replay source the daemon itself would build from
`[source] kind = "replay"`, with the config's own [source] settings (the CAN layout, the DBC,
the block length), and the same Pipeline (source thread, ring with backpressure, processing
thread) feeds one Monitor: the alarm state carries from one recording to the next as it would on
the wagon, and each recording starts a new segment (a new stream: never a gap that the dropouts
check counts, as `fleet judge` judges a day of recordings). Events go to a real event store: the given
state directory, or a temporary one that disappears afterwards.

What a source skipped (unreadable log lines, frames with unusable time stamps or identifiers)
is in each recording's report; a recording from which not one sample could be decoded is a
RecordingError naming what its frames were, since it is a wrong layout or DBC far more often
than an empty log.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from bogiemon.daemon.analysis import recording_settings
from bogiemon.daemon.config import BogiemonConfig, ReplaySourceConfig
from bogiemon.daemon.monitor import Monitor, MonitorCounters
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.daemon.pipeline import Pipeline
from bogiemon.daemon.ringbuffer import BlockRing
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.sources import duty_cycled, open_source, replay_source_config
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Source
from bogiemon.drivers.recording import RecordingError

# What a source skipped, by counter, in the words of a summary (singular, plural).
SKIPPED = (
    ("unreadable_entries", "unreadable log line", "unreadable log lines"),
    ("bad_timestamps", "frame with an unusable time stamp", "frames with unusable time stamps"),
    ("unknown_ids", "frame of an unknown identifier", "frames of unknown identifiers"),
    ("wrong_length", "frame of the wrong length", "frames of the wrong length"),
    ("remote_frames", "remote frame", "remote frames"),
    ("duplicates", "repeated frame", "repeated frames"),
    ("out_of_order", "frame out of order", "frames out of order"),
)


@dataclass(frozen=True)
class RecordingReport:
    """What one recording gave: samples delivered, and its source's counters."""

    path: str
    samples: int
    source_counters: dict[str, int]  # HealthCounters.as_dict() of the recording's source
    last_error: str | None = None  # the source's latest problem (e.g. the first unreadable line)

    def skipped(self) -> list[tuple[str, int]]:
        """(what, how many) of every kind of input the source counted and skipped, in words."""
        out = []
        for name, one, many in SKIPPED:
            n = self.source_counters.get(name, 0)
            if n:
                out.append((one if n == 1 else many, n))
        return out

    def skipped_text(self) -> str | None:
        """One line saying what was skipped, or None if nothing was."""
        parts = [f"{n} {what}" for what, n in self.skipped()]
        return f"{self.path}: skipped {', '.join(parts)}" if parts else None


@dataclass(frozen=True)
class ReplaySummary:
    recordings: int
    counters: MonitorCounters
    final_mode: str
    reports: tuple[RecordingReport, ...] = field(default=())


def replay(
    paths: Sequence[str | Path],
    config: BogiemonConfig,
    load: str | None = None,
    realtime: bool = False,
    state_dir: str | Path | None = None,
    sinks: Sequence[EventSink] = (),
    observers: Sequence[Callable[[WindowVerdict], None]] = (),
    duty: bool = False,
) -> ReplaySummary:
    """Run recordings in order through one Monitor; RecordingError for a file it cannot use.

    duty: each recording read on the config's [duty] cycle as `run` reads its source (its rests
    skip samples by their times): what the duty cycle costs the detection."""
    if not paths:
        raise ValueError("replay needs at least one recording")
    reports: list[RecordingReport] = []
    with tempfile.TemporaryDirectory(prefix="bogiemon-replay-") as scratch:
        store = EventStore(state_dir if state_dir is not None else scratch)
        try:
            monitor: Monitor | None = None
            for path in paths:
                replay = replay_source_config(path, config, realtime)
                run_config = config.model_copy(update={"source": replay})
                source = open_source(run_config)
                if duty:
                    source = duty_cycled(source, config)
                try:
                    # The rate of a CSV recording is its own: check the config can run at it
                    # before the pipeline starts, naming the file, not deep in a thread.
                    recording_settings(path, source.fs_hz, config)
                    if monitor is None:
                        monitor = Monitor(config.monitor_settings(load, source.fs_hz), store, sinks, observers)
                    else:
                        monitor.new_stream()  # the next recording: a new segment, never a dropout
                    samples_before = monitor.counters.samples
                    _run_pipeline(source, monitor, config)
                finally:
                    source.close()
                report = RecordingReport(
                    str(path), monitor.counters.samples - samples_before, source.counters.as_dict(), source.last_error
                )
                reports.append(report)
                if report.samples == 0:
                    raise RecordingError(_no_samples_message(report, replay))
            assert monitor is not None
            monitor.save_state()
            return ReplaySummary(len(paths), monitor.counters, monitor.mode, tuple(reports))
        finally:
            store.close()


def _run_pipeline(source: Source, monitor: Monitor, config: BogiemonConfig) -> None:
    ring = BlockRing(max(1, int(config.pipeline.ring_capacity_s * source.fs_hz)), backpressure=source.finite)
    pipeline = Pipeline(source, monitor, ring)
    pipeline.start()
    try:
        pipeline.wait()
    finally:
        pipeline.stop()
    if pipeline.error is not None:
        raise pipeline.error


def _no_samples_message(report: RecordingReport, src: ReplaySourceConfig) -> str:
    counts = report.source_counters
    frames = counts.get("frames", 0) + counts.get("bad_frames", 0) + counts.get("other_dbc_frames", 0)
    what = [f"{n} {kind}" for kind, n in (
        ("of the layout", counts.get("frames", 0)),
        ("of the DBC's other messages", counts.get("other_dbc_frames", 0)),
        *((w, n) for w, n in report.skipped()),
    ) if n]  # fmt: skip
    detail = f" ({', '.join(what)})" if what else ""
    return (
        f"{report.path}: no samples decoded from {frames} frame(s){detail}: check that [source] layout "
        f"('{src.layout}') and dbc_path ('{src.dbc_path or 'the shipped DBC'}') are those of the log"
    )
