"""The suspension decision: thresholds per load and indicator, k-of-n confirmation, hysteresis.

State machine, advanced once per judged window (gated windows and windows with a sensor
problem are not judged and change nothing):

    NORMAL    --a window at or above a warning level-->          SUSPECTED  (event SUSPECTED)
    NORMAL or SUSPECTED --k of the last n judged windows at or
                          above an alarm level-->                CONFIRMED  (event CONFIRMED)
    SUSPECTED or CONFIRMED --clear_after consecutive judged
                          windows below every warning level-->   NORMAL     (event CLEARED)

A threshold applies to the deviation |value - center| of one indicator; the warning level is
below the alarm level, and clearing needs every indicator back below warning: that gap is the
hysteresis. The state is a plain dict so the service can store it with each event.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from bogiemon.daemon.events import DEFAULT_SEVERITY, Event, EventKind
from bogiemon.detection import WindowIndicators

INDICATOR_FIELDS = ("i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm")


class Level(enum.IntEnum):
    OK = 0
    WARNING = 1
    ALARM = 2


class Mode(enum.Enum):
    NORMAL = "normal"
    SUSPECTED = "suspected"
    CONFIRMED = "confirmed"


@dataclass(frozen=True)
class Threshold:
    """Levels for |value - center| of one indicator."""

    warning: float
    alarm: float
    center: float = 0.0

    def __post_init__(self) -> None:
        if not 0 < self.warning <= self.alarm:
            raise ValueError(f"need 0 < warning <= alarm, got warning={self.warning}, alarm={self.alarm}")

    def level(self, value: float) -> Level:
        deviation = abs(value - self.center)
        if deviation >= self.alarm:
            return Level.ALARM
        if deviation >= self.warning:
            return Level.WARNING
        return Level.OK


@dataclass(frozen=True)
class DecisionSettings:
    thresholds: Mapping[str, Mapping[str, Threshold]]  # load state -> indicator field -> threshold
    confirm_k: int = 3
    confirm_n: int = 5
    clear_after_windows: int = 6

    def __post_init__(self) -> None:
        if not 1 <= self.confirm_k <= self.confirm_n:
            raise ValueError(f"need 1 <= confirm_k <= confirm_n, got {self.confirm_k} of {self.confirm_n}")
        for load, per_indicator in self.thresholds.items():
            unknown = set(per_indicator) - set(INDICATOR_FIELDS)
            if unknown:
                raise ValueError(f"thresholds.{load}: unknown indicators {sorted(unknown)}")


@dataclass(frozen=True)
class Judgement:
    """What one judged window showed: each thresholded indicator's value and level."""

    values: Mapping[str, float]
    levels: Mapping[str, Level]

    @property
    def worst(self) -> Level:
        return max(self.levels.values(), default=Level.OK)

    def at_or_above(self, level: Level) -> dict[str, float]:
        return {name: self.values[name] for name, lv in self.levels.items() if lv >= level}


@dataclass
class DecisionState:
    mode: Mode = Mode.NORMAL
    recent_alarms: deque[bool] = field(default_factory=deque)
    clean_streak: int = 0

    def as_dict(self) -> dict[str, Any]:
        return {"mode": self.mode.value, "recent_alarms": list(self.recent_alarms), "clean_streak": self.clean_streak}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> DecisionState:
        if not data:
            return cls()
        return cls(Mode(data["mode"]), deque(bool(v) for v in data["recent_alarms"]), int(data["clean_streak"]))


class Decider:
    """Turns judged windows into SUSPECTED, CONFIRMED and CLEARED events."""

    def __init__(self, settings: DecisionSettings, config_hash: str, state: DecisionState | None = None) -> None:
        self.settings = settings
        self.config_hash = config_hash
        self.state = state or DecisionState()
        # A reload may shrink n: keep only what still fits.
        self.state.recent_alarms = deque(self.state.recent_alarms, maxlen=settings.confirm_n)

    def judge(self, window: WindowIndicators, load: str) -> Judgement:
        thresholds = self.settings.thresholds.get(load)
        if thresholds is None:
            raise KeyError(f"no thresholds for load state '{load}'")
        values = {name: float(getattr(window, name)) for name in thresholds}
        levels = {name: thresholds[name].level(v) if math.isfinite(v) else Level.OK for name, v in values.items()}
        return Judgement(values, levels)

    def update(self, window: WindowIndicators, load: str) -> tuple[Judgement, list[Event]]:
        """Advance the state machine with one judgeable window; return its judgement and events."""
        judgement = self.judge(window, load)
        s, cfg = self.state, self.settings
        s.recent_alarms.append(judgement.worst >= Level.ALARM)
        s.clean_streak = 0 if judgement.worst >= Level.WARNING else s.clean_streak + 1
        events: list[Event] = []
        details = {"load": load, "window_start_s": window.start_s, "window_end_s": window.end_s, "thresholds": self._limits(load)}

        if s.mode is not Mode.CONFIRMED and sum(s.recent_alarms) >= cfg.confirm_k:
            s.mode = Mode.CONFIRMED
            fired = judgement.at_or_above(Level.ALARM) or judgement.at_or_above(Level.WARNING)
            events.append(self._event(window, EventKind.CONFIRMED, fired, {**details, "alarm_windows": f"{sum(s.recent_alarms)} of {len(s.recent_alarms)}"}))
        elif s.mode is Mode.NORMAL and judgement.worst >= Level.WARNING:
            s.mode = Mode.SUSPECTED
            events.append(self._event(window, EventKind.SUSPECTED, judgement.at_or_above(Level.WARNING), details))
        elif s.mode is not Mode.NORMAL and s.clean_streak >= cfg.clear_after_windows:
            previous = s.mode
            s.mode = Mode.NORMAL
            s.recent_alarms.clear()
            events.append(self._event(window, EventKind.CLEARED, judgement.values, {**details, "cleared": previous.value}))
        return judgement, events

    def _limits(self, load: str) -> dict[str, dict[str, float]]:
        return {n: {"center": t.center, "warning": t.warning, "alarm": t.alarm} for n, t in self.settings.thresholds[load].items()}

    def _event(self, window: WindowIndicators, kind: EventKind, fired: Mapping[str, float], details: Mapping[str, Any]) -> Event:
        return Event(
            time_s=window.end_s,
            kind=kind,
            severity=DEFAULT_SEVERITY[kind],
            config_hash=self.config_hash,
            indicators=dict(fired),
            details=dict(details),
        )
