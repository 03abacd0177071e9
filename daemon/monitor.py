"""The monitor: blocks in, events out. The same object serves `run` and `replay`.

Per block it restarts the windows at a gap and feeds the detection core; per window it checks the
sensors and the gating, decides the load state (configured, or estimated from the window's
spectral shape with `decision.load = "auto"`), advances the suspension decision, commits the
resulting events (with the decision state) to the event store and only then reports them to the
sinks. The per-window judgement without the store (WindowJudge) also serves the evaluation.

When the store refuses a commit (a full disk, read-only or failing media), `replay` stops with the
error (the recording can be replayed once the disk is fixed), while the service, whose live data
cannot be read twice, holds the events in memory and retries at every window: they are reported
once committed, in order, and nothing is reported before; each failure is logged at crit.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from bogiemon.daemon.decision import Decider, DecisionSettings, DecisionState, Judgement
from bogiemon.daemon.events import Event
from bogiemon.daemon.health import HealthSettings, HealthState, HealthTracker, WindowHealth, assess_window
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.models import LoadDiscriminant, LoadModel, LoadSignature, nearest_load
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.store import EventStore, StoreError, StoreWriteError
from bogiemon.daemon.windowing import BlockWindows
from bogiemon.detection import BogieGeometry, ProcessingSettings, WindowIndicators
from bogiemon.drivers.base import Block, SensorStatus

STATE_KEY = "monitor"
# Events held while the store refuses commits: days of a faulty wagon's events (they come at
# changes of state), a few MB at most. Past it the monitor stops (the service exits 3) rather
# than grow without bound.
MAX_HELD_EVENTS = 1000


@dataclass(frozen=True)
class MonitorSettings:
    processing: ProcessingSettings
    geometry: BogieGeometry
    health: HealthSettings
    decision: DecisionSettings
    load: str  # "full", "tare" or "auto" (estimated per window by load_model)
    config_hash: str
    sensor_clear_after_windows: int = 3
    load_model: LoadModel | None = None
    # The load states the wagon was commissioned in: with them, load "auto" takes the nearest, and
    # a window like none of them is not judged (never an alarm for being unfamiliar); with a fixed
    # load, a window excited more gently than that state's commissioning is not judged either.
    load_states: tuple[LoadSignature, ...] = ()
    load_discriminant: LoadDiscriminant | None = None  # with both states: the wagon's own line between them

    def __post_init__(self) -> None:
        if self.load == "auto" and self.load_model is None:
            raise ValueError("load 'auto' needs the load model")


@dataclass(frozen=True)
class WindowReport:
    """Everything the monitor concluded about one window (for status lines and live displays)."""

    window: WindowIndicators
    health: WindowHealth
    judgement: Judgement | None  # None when the window was not judged
    mode: str
    events: tuple[Event, ...]
    load: str | None = None  # the load state the window was judged in
    p_full: float | None = None  # the estimated probability of full load (load "auto")
    unfamiliar: float | None = None  # not judged: its load vector's distance to every commissioned state is beyond the limit


@dataclass
class MonitorCounters:
    blocks: int = 0
    samples: int = 0
    segments: int = 0  # continuous stretches: the first block and every gap start one
    # Every window is judged, gated (standstill, weak excitation) or held by the sensors (a problem
    # in it, or a sensor fault not yet cleared): windows == judged + gated + sensor_fault_windows.
    windows: int = 0
    judged: int = 0
    gated: int = 0
    unfamiliar: int = 0  # of the gated: in a load state unlike any of the commissioning
    sensor_fault_windows: int = 0
    events: int = 0


@dataclass(frozen=True)
class JudgedWindow:
    """What WindowJudge concluded about one window."""

    health: WindowHealth
    judgement: Judgement | None
    events: list[Event]
    load: str | None
    p_full: float | None
    # The distance of the window's load vector to the nearest commissioned load state, when it was
    # farther than that state's limit or excited more gently than its commissioning: not judged.
    unfamiliar: float | None = None


class WindowJudge:
    """Sensor health, gating, load state and the suspension decision for one window at a time.

    Holds the decision and health state; no store, no sinks (Monitor adds those).
    """

    def __init__(self, settings: MonitorSettings, decision: DecisionState | None = None, health: HealthState | None = None) -> None:
        self.settings = settings
        self.decider = Decider(settings.decision, settings.config_hash, decision)
        self.health = HealthTracker(settings.config_hash, settings.sensor_clear_after_windows, health)

    def reconfigure(self, settings: MonitorSettings) -> None:
        self.settings = settings
        self.decider = Decider(settings.decision, settings.config_hash, self.decider.state)
        self.health = HealthTracker(settings.config_hash, settings.sensor_clear_after_windows, self.health.state)

    def judge(
        self,
        window: WindowIndicators,
        status: tuple[SensorStatus, SensorStatus, SensorStatus] = (SensorStatus.OK,) * 3,
        gaps_last_hour: int = 0,
    ) -> JudgedWindow:
        s = self.settings
        health = assess_window(window, s.health, status, gaps_last_hour, s.geometry)
        events = self.health.update(window, health)
        # Nothing is judged until a sensor fault has cleared: a faulty channel can pass a single
        # window's checks (noise that the track's own excitation hides) and still couple the modes.
        if not health.judgeable or self.health.faulted:
            return JudgedWindow(health, None, events, None, None)
        load, p_full, context = s.load, None, {"load_source": "configured"}
        fixed = next((st for st in s.load_states if st.load == s.load), None)
        if fixed is not None and not fixed.familiar_excitation(window):
            # A configured load, commissioned: its excitation range holds as it does for "auto".
            return JudgedWindow(health, None, events, None, None, unfamiliar=math.nan)
        if s.load == "auto" and s.load_states:
            nearest, distance = nearest_load(window, s.geometry, s.load_states, s.load_discriminant)
            if nearest is None:
                return JudgedWindow(health, None, events, None, None, unfamiliar=distance)
            load, context = nearest, {"load_source": "commissioned", "load_distance": round(distance, 3)}
        elif s.load == "auto":
            assert s.load_model is not None
            p_full = s.load_model.probability_full(window, s.geometry)
            # A wagon is loaded or empty; the estimate is either side of 0.5 by a wide margin on
            # the simulated fleets (docs/robust/README.md): no third state is needed.
            load = "full" if p_full >= 0.5 else "tare"
            context = {"load_source": "estimated", "p_full": round(p_full, 4)}
        judgement, decided = self.decider.update(window, load, context)
        return JudgedWindow(health, judgement, events + decided, load, p_full)


class Monitor:
    def __init__(
        self,
        settings: MonitorSettings,
        store: EventStore,
        sinks: Sequence[EventSink] = (),
        observers: Sequence[Callable[[WindowReport], None]] = (),
        hold_uncommitted: bool = False,
        max_held_events: int = MAX_HELD_EVENTS,
        taps: Sequence[Callable[[Block], None]] = (),
    ) -> None:
        self.store = store
        self.sinks = list(sinks)
        self.observers = list(observers)
        self.taps = list(taps)  # see every non-empty block before its windows (the recorder keeps the raw samples)
        self.counters = MonitorCounters()
        self.latest: WindowReport | None = None
        self.hold_uncommitted = hold_uncommitted  # the service: hold what the store refuses, retry per window
        self.max_held_events = max_held_events
        self.held: list[Event] = []  # decided but not yet committed (the store refused), oldest first
        self.store_failure: str | None = None  # the last refused commit's error, None once commits go through
        self.store_failures = 0  # refused commits, ever
        self._log = get_logger(component="store")
        saved = store.get_state(STATE_KEY) or {}
        try:
            decision, health = DecisionState.from_dict(saved.get("decision")), HealthState.from_dict(saved.get("health"))
        except (KeyError, ValueError, TypeError, AttributeError) as exc:  # written by something else than a monitor
            raise StoreError(f"{store.path}: the saved monitor state does not decode ({exc!r}); move the store aside to start afresh") from None
        self._judge = WindowJudge(settings, decision, health)
        self._windows = self._block_windows(settings)  # daemon/windowing.py's rules, shared with fleet/
        self.settings = settings

    @staticmethod
    def _block_windows(settings: MonitorSettings) -> BlockWindows:
        return BlockWindows(lambda fs_hz: replace(settings.processing, fs_hz=fs_hz), settings.geometry, settings.health.clip_level_mps2)

    @property
    def mode(self) -> str:
        return self._judge.decider.state.mode.value

    def reconfigure(self, settings: MonitorSettings) -> None:
        """Apply a reloaded config; the alarm state carries over, the windows restart."""
        self.settings = settings
        self._judge.reconfigure(settings)
        windows = self._block_windows(settings)
        windows.spans, windows.gaps = self._windows.spans, self._windows.gaps  # the gaps and status bits carry on
        self._windows = windows

    def state_dict(self) -> dict[str, Any]:
        return {"decision": self._judge.decider.state.as_dict(), "health": self._judge.health.state.as_dict()}

    def save_state(self) -> None:
        """Commit the decision state, with any events still held. Raises StoreWriteError when the
        store refuses it, unless hold_uncommitted (then store_failure says so)."""
        self._commit([])

    def feed(self, block: Block) -> list[Event]:
        """Process one block; return the events it caused (already committed and reported)."""
        if block.n_samples == 0:
            return []
        for tap in self.taps:
            tap(block)
        self.counters.blocks += 1
        self.counters.samples += block.n_samples
        segments_before = self._windows.segments
        windowed = self._windows.feed(block)
        self.counters.segments += self._windows.segments - segments_before
        events: list[Event] = []
        for w in windowed:
            events += self._on_window(w.window, w.status, w.gaps_last_hour)
        return events

    def _on_window(self, window: WindowIndicators, status: tuple[SensorStatus, SensorStatus, SensorStatus], gaps_last_hour: int) -> list[Event]:
        self.counters.windows += 1
        judged = self._judge.judge(window, status, gaps_last_hour)
        health, judgement, events = judged.health, judged.judgement, judged.events
        if judgement is not None:
            self.counters.judged += 1
        elif health.gate is not None or judged.unfamiliar is not None:
            self.counters.gated += 1
            self.counters.unfamiliar += judged.unfamiliar is not None
        else:
            self.counters.sensor_fault_windows += 1
        if events or self.held:
            events = self._commit(events)
        self.latest = WindowReport(window, health, judgement, self.mode, tuple(events), judged.load, judged.p_full, judged.unfamiliar)
        for observer in self.observers:
            observer(self.latest)
        return events

    def _commit(self, new: list[Event]) -> list[Event]:
        """Commit the held events and new ones with the current state, then report them; returns
        what was committed (nothing while the store refuses, with hold_uncommitted)."""
        batch = [*self.held, *new]
        try:
            to_insert = batch
            if self.held:
                # A commit reported as failed may still have reached the disk (an I/O error
                # after the write): what is already there is not inserted twice, only reported.
                stored = self.store.committed_ids([e.event_id for e in self.held])
                to_insert = [e for e in batch if e.event_id not in stored]
            self.store.append(to_insert, state={STATE_KEY: self.state_dict()})  # durable before reported
        except StoreError as exc:  # StoreWriteError, or a read of the failing store
            if not self.hold_uncommitted:
                raise
            self.held = batch
            self.store_failure = str(exc)
            self.store_failures += 1
            self._log.critical(
                "event store refuses commits: events held in memory and retried at every window, none reported until committed",
                error=str(exc), held=len(batch), held_kinds=[e.kind.value for e in batch], failures=self.store_failures,
            )  # fmt: skip
            if len(batch) > self.max_held_events:
                raise StoreWriteError(
                    f"{self.store.path}: {len(batch)} events could not be committed, more than the {self.max_held_events} "
                    f"held in memory: stopping ({exc})"
                ) from None
            return []
        if self.store_failure is not None:
            self._log.warning("event store takes commits again", committed=len(batch), failures=self.store_failures)
        self.held, self.store_failure = [], None
        self.counters.events += len(batch)
        for event in batch:
            for sink in self.sinks:
                sink.publish(event)
        return batch
