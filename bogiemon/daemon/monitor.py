"""The monitor: blocks in, events out. The same object serves `run`, `replay` and `fleet judge`.

Per block it restarts the windows at a gap or a new stream and feeds the detection core
(judgement/windowing.py); per window (on_window, where `fleet judge` feeds a wagon's stored windows)
it takes the window's verdict from WindowJudge (judgement/verdict.py: sensor health, gating, load
state, the suspension decision), counts it, commits the resulting events (with the decision
state) to the event log and only then reports them to the sinks and observers.

When the store refuses a commit (a full disk, read-only or failing media), `replay` stops with the
error (the recording can be replayed once the disk is fixed), while the service, whose live data
cannot be read twice, holds the events in memory and retries at every window: they are reported
once committed, in order, and nothing is reported before; each failure is logged at crit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any, Protocol

from bogiemon.judgement.coverage import CoverageState
from bogiemon.judgement.vocabulary import Mode
from bogiemon.judgement.events import Event
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.store_file import StoreError, StoreWriteError
from bogiemon.judgement.verdict import MonitorSettings, SavedStateError, WindowCounts, WindowJudge, WindowVerdict
from bogiemon.judgement.windowing import BlockWindows, Windowed
from bogiemon.drivers.base import Block

STATE_KEY = "monitor"
# Events held while the store refuses commits: days of a faulty wagon's events (they come at
# changes of state), a few MB at most. Past it the monitor stops (the service exits 3) rather
# than grow without bound.
MAX_HELD_EVENTS = 1000


def windows_of(settings: MonitorSettings) -> tuple[object, ...]:
    """What a monitor's windows are computed from: a reload that changes it restarts them."""
    return (settings.processing, settings.geometry, settings.health.clip_level_mps2)


class EventLog(Protocol):
    """Where the monitor commits its events with its state: the service's SQLite EventStore
    (daemon/store.py), or MemoryEventLog (the benchmarks and tests)."""

    path: Any  # named in errors

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None: ...

    def committed_ids(self, event_ids: Sequence[str]) -> set[str]: ...

    def get_state(self, key: str) -> Any: ...


class MemoryEventLog:
    """An EventLog in memory: events numbered 1, 2, ... in commit order, as the store numbers them."""

    path = "(memory)"

    def __init__(self) -> None:
        self.committed: list[tuple[int, Event]] = []  # (seq, event)
        self.state: dict[str, Any] = {}

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None:
        self.committed += [(len(self.committed) + 1 + i, e) for i, e in enumerate(events)]
        self.state.update(state or {})

    def committed_ids(self, event_ids: Sequence[str]) -> set[str]:
        known = {e.event_id for _, e in self.committed}
        return {i for i in event_ids if i in known}

    def get_state(self, key: str) -> Any:
        return self.state.get(key)


@dataclass
class MonitorCounters(WindowCounts):
    """The windows' outcomes (counted by the judge) and what the monitor itself met: blocks,
    samples, segments and committed events."""

    blocks: int = 0
    samples: int = 0
    segments: int = 0  # continuous stretches: the first block and every gap or new stream start one
    events: int = 0


class Monitor:
    def __init__(
        self,
        settings: MonitorSettings,
        store: EventLog,
        sinks: Sequence[EventSink] = (),
        observers: Sequence[Callable[[WindowVerdict], None]] = (),
        hold_uncommitted: bool = False,
        max_held_events: int = MAX_HELD_EVENTS,
        taps: Sequence[Callable[[Block], None]] = (),
    ) -> None:
        self.store = store
        self.sinks = list(sinks)
        self.observers = list(observers)
        self.taps = list(taps)  # see every non-empty block before its windows (the recorder keeps the raw samples)
        self.counters = MonitorCounters()
        self.latest: WindowVerdict | None = None
        self.hold_uncommitted = hold_uncommitted  # the service: hold what the store refuses, retry per window
        self.max_held_events = max_held_events
        self.held: list[Event] = []  # decided but not yet committed (the store refused), oldest first
        self.store_failure: str | None = None  # the last refused commit's error, None once commits go through
        self.store_failures = 0  # refused commits, ever
        self._log = get_logger(component="store")
        try:
            self._judge = WindowJudge.restore(settings, store.get_state(STATE_KEY), self.counters)
        except SavedStateError as exc:  # written by something else than a monitor
            raise StoreError(f"{store.path}: {exc}; move the store aside to start afresh") from None
        self._windows = self._block_windows(settings)  # judgement/windowing.py's rules, shared with fleet/
        self.settings = settings

    @staticmethod
    def _block_windows(settings: MonitorSettings) -> BlockWindows:
        return BlockWindows(lambda fs_hz: replace(settings.processing, fs_hz=fs_hz), settings.geometry, settings.health.clip_level_mps2)

    @property
    def mode(self) -> Mode:
        return self._judge.mode

    @property
    def coverage(self) -> CoverageState:
        """How much running went unjudged since the last judged window, and whether NOT_JUDGED is in force."""
        return self._judge.coverage.state

    @property
    def sensor_reported(self) -> dict[str, list[str]]:
        """The problems of the SENSOR_FAULT in force, per channel (empty: the sensors are healthy)."""
        return dict(self._judge.health.state.reported)

    def reconfigure(self, settings: MonitorSettings) -> bool:
        """Apply a reloaded config: the alarm and sensor state carry over, the next window is judged
        by the new settings. The windows restart only when what they are computed from changed (the
        processing, the sensors' corners and geometry, the clip level): a reload of anything else
        loses no window, however often it comes. Returns whether they restarted."""
        restart = windows_of(settings) != windows_of(self.settings)
        self.settings = settings
        self._judge.reconfigure(settings)
        if restart:
            windows = self._block_windows(settings)
            windows.spans, windows.gaps = self._windows.spans, self._windows.gaps  # the gaps and status bits carry on
            self._windows = windows
        return restart

    def new_stream(self) -> None:
        """The next block begins another recording: a new segment, never a dropout of the source."""
        self._windows.new_stream()

    def state_dict(self) -> dict[str, Any]:
        return self._judge.state_dict()

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
            events += self.on_window(w)
        return events

    def on_window(self, windowed: Windowed) -> list[Event]:
        """Judge one window, commit its events and report them; return what was committed (the
        back office feeds a wagon's stored windows here, as the blocks' windows come here)."""
        verdict = self._judge.judge(windowed.window, windowed.status, windowed.gaps_last_hour)
        events = list(verdict.events)
        if events or self.held:
            events = self._commit(events)
        self.latest = replace(verdict, events=tuple(events))
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
