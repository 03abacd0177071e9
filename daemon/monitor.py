"""The monitor: blocks in, events out. The same object serves `run` and `replay`.

Per block it restarts the windows at a gap and feeds the detection core; per window it checks the
sensors and the gating, advances the suspension decision, commits the resulting events (with the
decision state) to the event store and only then reports them to the sinks.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from bogiemon.daemon.decision import Decider, DecisionSettings, DecisionState, Judgement
from bogiemon.daemon.events import Event
from bogiemon.daemon.health import HealthSettings, HealthState, HealthTracker, WindowHealth, assess_window
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.store import EventStore
from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.drivers.base import Block, SensorStatus

GAP_MEMORY_S = 3600.0  # dropouts are judged over the last hour
STATE_KEY = "monitor"


@dataclass(frozen=True)
class MonitorSettings:
    processing: ProcessingSettings
    geometry: BogieGeometry
    health: HealthSettings
    decision: DecisionSettings
    load: str
    config_hash: str
    sensor_clear_after_windows: int = 3


@dataclass(frozen=True)
class WindowReport:
    """Everything the monitor concluded about one window (for status lines and live displays)."""

    window: WindowIndicators
    health: WindowHealth
    judgement: Judgement | None  # None when the window was not judged
    mode: str
    events: tuple[Event, ...]


@dataclass
class MonitorCounters:
    blocks: int = 0
    samples: int = 0
    segments: int = 0  # continuous stretches: the first block and every gap start one
    windows: int = 0
    judged: int = 0
    gated: int = 0
    sensor_fault_windows: int = 0
    events: int = 0


class Monitor:
    def __init__(
        self,
        settings: MonitorSettings,
        store: EventStore,
        sinks: Sequence[EventSink] = (),
        observers: Sequence[Callable[[WindowReport], None]] = (),
    ) -> None:
        self.store = store
        self.sinks = list(sinks)
        self.observers = list(observers)
        self.counters = MonitorCounters()
        self.latest: WindowReport | None = None
        saved = store.get_state(STATE_KEY) or {}
        self._decider = Decider(settings.decision, settings.config_hash, DecisionState.from_dict(saved.get("decision")))
        self._health = HealthTracker(
            settings.config_hash, settings.sensor_clear_after_windows, HealthState.from_dict(saved.get("health"))
        )
        self._status_spans: deque[tuple[float, float, tuple[SensorStatus, ...]]] = deque(maxlen=10_000)
        self._gap_times: deque[float] = deque(maxlen=10_000)
        self._core: IndicatorStream | None = None
        self.settings = settings

    @property
    def mode(self) -> str:
        return self._decider.state.mode.value

    def reconfigure(self, settings: MonitorSettings) -> None:
        """Apply a reloaded config; the alarm state carries over, the windows restart."""
        self.settings = settings
        self._decider = Decider(settings.decision, settings.config_hash, self._decider.state)
        self._health = HealthTracker(settings.config_hash, settings.sensor_clear_after_windows, self._health.state)
        self._core = None

    def state_dict(self) -> dict[str, Any]:
        return {"decision": self._decider.state.as_dict(), "health": self._health.state.as_dict()}

    def save_state(self) -> None:
        self.store.put_state(STATE_KEY, self.state_dict())

    def feed(self, block: Block) -> list[Event]:
        """Process one block; return the events it caused (already committed and reported)."""
        if block.n_samples == 0:
            return []
        self.counters.blocks += 1
        self.counters.samples += block.n_samples
        if self._core is None or self._core.settings.fs_hz != block.fs_hz:
            processing = replace(self.settings.processing, fs_hz=block.fs_hz)
            self._core = IndicatorStream(processing, self.settings.geometry, block.start_s, self.settings.health.clip_level_mps2)
            self.counters.segments += 1
        elif block.gap_before:
            self._core.restart(block.start_s)
            self.counters.segments += 1
            self._gap_times.append(block.start_s)
        if any(block.status):
            self._status_spans.append((block.start_s, block.end_s, block.status))
        events: list[Event] = []
        for window in self._core.process(block.accel_mps2):
            events += self._on_window(window)
        return events

    def _on_window(self, window: WindowIndicators) -> list[Event]:
        self.counters.windows += 1
        health = assess_window(window, self.settings.health, self._status_over(window), self._gaps_before(window.end_s))
        events = self._health.update(window, health)
        judgement = None
        if health.judgeable:
            self.counters.judged += 1
            judgement, decided = self._decider.update(window, self.settings.load)
            events += decided
        elif health.gate is not None:
            self.counters.gated += 1
        if not health.sensors_ok:
            self.counters.sensor_fault_windows += 1
        if events:
            self.store.append(events, state={STATE_KEY: self.state_dict()})  # durable before reported
            self.counters.events += len(events)
            for event in events:
                for sink in self.sinks:
                    sink.publish(event)
        self.latest = WindowReport(window, health, judgement, self.mode, tuple(events))
        for observer in self.observers:
            observer(self.latest)
        return events

    def _status_over(self, window: WindowIndicators) -> tuple[SensorStatus, SensorStatus, SensorStatus]:
        while self._status_spans and self._status_spans[0][1] <= window.start_s:  # windows only move on
            self._status_spans.popleft()
        seen = [SensorStatus.OK] * 3
        for start_s, end_s, status in self._status_spans:
            if start_s < window.end_s and end_s > window.start_s:
                seen = [a | b for a, b in zip(seen, status, strict=True)]
        return (seen[0], seen[1], seen[2])

    def _gaps_before(self, time_s: float) -> int:
        while self._gap_times and self._gap_times[0] < time_s - GAP_MEMORY_S:
            self._gap_times.popleft()
        return sum(1 for t in self._gap_times if t <= time_s)
