"""Events: what the daemon concludes, as typed records. They cross the process boundary as JSON
(daemon/event_json.py: the event store, the journal, MQTT, the fleet's events.jsonl), never inside it.

Each kind of event carries its own details record, read by attribute. A leaf that loads nothing
heavy (`bogiemon demo` imports it to parse its arguments): the types the records hold from the
judgement's heavier modules (the limits, the diagnosis and its corners) are named for the type
checker only, and the producers (judgement/decision.py, sensor_tracker.py, coverage.py) and the
JSON reader build them.
"""

from __future__ import annotations

import enum
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

from bogiemon.judgement.vocabulary import LoadSource, LoadState, Method, Mode

if TYPE_CHECKING:
    from bogiemon.judgement.diagnosis import Diagnosis
    from bogiemon.judgement.rules import Threshold


# The bogie a one-bogie gateway monitors, and the one an event without a bogie is about.
DEFAULT_BOGIE = "1"

# The paper's indicators as the events, the thresholds and the status name them (detection's
# WindowIndicators fields of the same names).
INDICATOR_FIELDS = ("i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm")


class EventKind(enum.StrEnum):
    SUSPECTED = "SUSPECTED"  # k - 1 of the last n judged windows (or the trend) at a warning level
    CONFIRMED = "CONFIRMED"  # k of the last n judged windows crossed an alarm level: the alarm
    CLEARED = "CLEARED"  # a suspicion or an alarm ended after enough clean windows
    SENSOR_FAULT = "SENSOR_FAULT"  # a sensor is dead, stuck, clipping, noisy or dropping out
    SENSOR_CLEARED = "SENSOR_CLEARED"  # the sensors are healthy again
    NOT_JUDGED = "NOT_JUDGED"  # hours of running not judged: unlike the commissioning (judgement/coverage.py)
    JUDGED_AGAIN = "JUDGED_AGAIN"  # a window is judged again after a NOT_JUDGED


class Severity(enum.StrEnum):
    """How urgent an event is; the log level it is logged at decides its syslog priority (the one
    table of them is daemon/logs.py's), so what `journalctl -p` shows."""

    INFO = "info"
    WARNING = "warning"
    ALARM = "alarm"

    @property
    def log_level(self) -> str:
        """The structlog method an event of this severity is logged with: an alarm at crit."""
        return "critical" if self is Severity.ALARM else self.value


DEFAULT_SEVERITY = {
    EventKind.SUSPECTED: Severity.WARNING,
    EventKind.CONFIRMED: Severity.ALARM,
    EventKind.CLEARED: Severity.INFO,
    EventKind.SENSOR_FAULT: Severity.WARNING,
    EventKind.SENSOR_CLEARED: Severity.INFO,
    EventKind.NOT_JUDGED: Severity.WARNING,
    EventKind.JUDGED_AGAIN: Severity.INFO,
}


class Trigger(enum.StrEnum):
    """What confirmed a fault."""

    WINDOWS = "windows"  # k of the last n judged windows at an alarm level
    TREND = "trend"  # the fused trend at its alarm level (judgement/decision.py)


@dataclass(frozen=True)
class KOfN:
    """k of the last n judged windows (n below the configured confirm_n while the history fills)."""

    k: int
    n: int

    def __str__(self) -> str:
        return f"{self.k} of {self.n}"


@dataclass(frozen=True)
class RunningContext:
    """How a judged window's load state was decided and its levels set (judgement/running.py
    LoadChoice), as the events state it: the numbers rounded as they are written."""

    load_source: LoadSource
    load_distance: float | None = None  # the load vector's distance from its state: evidence, never a gate
    p_full: float | None = None  # the shipped load model's P(full), where it decided
    # Both set only when the window ran outside the commissioning's excitation and was judged with
    # its levels raised by level_margin.
    excitation_outside: float | None = None
    level_margin: float | None = None


# Every details record is keyword-only: a field added later (with its default) changes no caller.


@dataclass(frozen=True, kw_only=True)
class WindowDetails:
    """The window whose verdict raised the event, Unix seconds (the source's clock)."""

    KIND: ClassVar[EventKind]
    window_start_s: float
    window_end_s: float


@dataclass(frozen=True, kw_only=True)
class DecisionDetails(WindowDetails):
    """What a suspension event (SUSPECTED, CONFIRMED, CLEARED) states of the window that moved the
    decision. The optional fields are None in events of versions that did not state them yet."""

    load: LoadState  # the load state the window was judged in
    thresholds: Mapping[str, Threshold]  # the limits of every value judged, as applied (raised by level_margin)
    method: Method | None = None
    running: RunningContext | None = None
    baseline: str | None = None  # "calibrated" or "population": the fused baseline in force
    trend: float | None = None  # the fused trend after the window (None: no trend)


@dataclass(frozen=True)
class SisterDetails:
    """The sister evidence of the window pair that moved a wagon's decision (judgement/sister.py):
    the score of the difference between the bogies against its healthy baseline, that baseline's
    levels and name ("commissioned" or "prior"), the bogie of the pair it named (1: the first, 2:
    the second; None: neither clearly) and each bogie's own coupling score that named it."""

    score: float
    warning: float
    alarm: float
    baseline: str
    blamed: int | None
    own_scores: tuple[float, float]


@dataclass(frozen=True, kw_only=True)
class SuspectedDetails(DecisionDetails):
    KIND: ClassVar[EventKind] = EventKind.SUSPECTED
    warning_windows: KOfN | None = None  # of the last judged windows, those at a warning level or above
    sister: SisterDetails | None = None  # a wagon judged on both bogies: the pair's sister evidence


@dataclass(frozen=True, kw_only=True)
class ConfirmedDetails(DecisionDetails):
    KIND: ClassVar[EventKind] = EventKind.CONFIRMED
    alarm_windows: KOfN  # of the last judged windows, those at an alarm level
    trigger: Trigger | None = None
    diagnosis: Diagnosis | None = None  # the corner the couplings name (judgement/diagnosis.py)
    sister: SisterDetails | None = None  # a wagon judged on both bogies: the pair's sister evidence


@dataclass(frozen=True, kw_only=True)
class ClearedDetails(DecisionDetails):
    KIND: ClassVar[EventKind] = EventKind.CLEARED
    cleared: Mode  # the mode that ended: suspected or confirmed


# A sensor's problems: channel ("a1".."a3", or "source") -> the problems' names (judgement/health.py
# SensorProblem values), sorted.
Problems = Mapping[str, tuple[str, ...]]


@dataclass(frozen=True)
class SuspensionHint:
    """What a window's couplings said of a one-corner suspension fault while a sensor was noisy
    (judgement/verdict.py, "a sensor fault never hides a suspension fault"): the diagonal pair its
    pitch-roll sign names (corner names), the window's fused score and alarm level, and the
    diagnosis's words for the match."""

    corners: tuple[str, ...]
    fused_score: float
    alarm: float
    best_match: str


@dataclass(frozen=True, kw_only=True)
class SensorFaultDetails(WindowDetails):
    KIND: ClassVar[EventKind] = EventKind.SENSOR_FAULT
    rms_mps2: tuple[float, ...]  # the window's RMS per channel after the high-pass
    problems: Problems  # found in this window
    reported: Problems | None = None  # every problem reported since the sensors were last healthy
    suspension: SuspensionHint | None = None  # the couplings moved as a one-corner fault moves them


@dataclass(frozen=True, kw_only=True)
class SensorClearedDetails(WindowDetails):
    KIND: ClassVar[EventKind] = EventKind.SENSOR_CLEARED
    rms_mps2: tuple[float, ...]
    cleared: Problems  # what was reported until now


@dataclass(frozen=True, kw_only=True)
class NotJudgedDetails(WindowDetails):
    KIND: ClassVar[EventKind] = EventKind.NOT_JUDGED
    message: str  # what it means and what to do, in words
    unjudged_running_s: float  # running left unjudged since the last judged window
    last_judged_s: float | None  # the end of the last judged window (None: none yet)
    unlike: str | None = None  # why the last window was left unjudged (judgement/running.py)


@dataclass(frozen=True, kw_only=True)
class JudgedAgainDetails(WindowDetails):
    KIND: ClassVar[EventKind] = EventKind.JUDGED_AGAIN


EventDetails = (
    SuspectedDetails | ConfirmedDetails | ClearedDetails | SensorFaultDetails | SensorClearedDetails | NotJudgedDetails | JudgedAgainDetails
)
DETAILS_TYPES: Mapping[EventKind, type[EventDetails]] = {
    t.KIND: t
    for t in (SuspectedDetails, ConfirmedDetails, ClearedDetails, SensorFaultDetails, SensorClearedDetails, NotJudgedDetails, JudgedAgainDetails)
}


@dataclass(frozen=True)
class Event:
    """One event. time_s is the end of the window that caused it, in Unix seconds (source clock).

    indicators holds the values that fired (name -> value); details the record of its kind (the
    window, the limits and the load state, the channels of a sensor fault, ...). event_id is unique
    and survives a crash unchanged, so a receiver can drop duplicates.
    """

    time_s: float
    kind: EventKind
    severity: Severity
    config_hash: str
    indicators: Mapping[str, float] = field(default_factory=dict)
    details: EventDetails = field(kw_only=True)
    event_id: str = field(default_factory=lambda: uuid.uuid4().hex)
    # The bogie it is about: its id ([[bogie]] id in the config, "1" and "2" by default). A
    # one-bogie gateway's events are bogie "1"'s, and so is every event written before the wagon
    # had two (a body without "bogie" reads as "1": daemon/event_json.py).
    bogie: str = field(default=DEFAULT_BOGIE, kw_only=True)

    def __post_init__(self) -> None:
        if type(self.details) is not DETAILS_TYPES[self.kind]:
            raise TypeError(f"a {self.kind} event carries {DETAILS_TYPES[self.kind].__name__}, not {type(self.details).__name__}")

    @classmethod
    def of(cls, time_s: float, details: EventDetails, config_hash: str, indicators: Mapping[str, float] | None = None) -> Event:
        """The event its details make, at its kind's default severity."""
        return cls(time_s, details.KIND, DEFAULT_SEVERITY[details.KIND], config_hash, dict(indicators or {}), details=details)
