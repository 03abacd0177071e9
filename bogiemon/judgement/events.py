"""Events: what the daemon concludes, as typed records that leave the process."""

from __future__ import annotations

import enum
import uuid
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any


# The paper's indicators as the events, the thresholds and the status name them (detection's
# WindowIndicators fields of the same names).
INDICATOR_FIELDS = ("i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm")


class EventKind(enum.Enum):
    SUSPECTED = "SUSPECTED"  # k - 1 of the last n judged windows (or the trend) at a warning level
    CONFIRMED = "CONFIRMED"  # k of the last n judged windows crossed an alarm level: the alarm
    CLEARED = "CLEARED"  # a suspicion or an alarm ended after enough clean windows
    SENSOR_FAULT = "SENSOR_FAULT"  # a sensor is dead, stuck, clipping, noisy or dropping out
    SENSOR_CLEARED = "SENSOR_CLEARED"  # the sensors are healthy again
    NOT_JUDGED = "NOT_JUDGED"  # hours of running not judged: unlike the commissioning (judgement/coverage.py)
    JUDGED_AGAIN = "JUDGED_AGAIN"  # a window is judged again after a NOT_JUDGED


class Severity(enum.Enum):
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


@dataclass(frozen=True)
class Event:
    """One event. time_s is the end of the window that caused it, in Unix seconds (source clock).

    indicators holds the values that fired (name -> value); details holds the rest (thresholds,
    window, load state, the channels of a sensor fault, ...). event_id is unique and survives
    a crash unchanged, so a receiver can drop duplicates.
    """

    time_s: float
    kind: EventKind
    severity: Severity
    config_hash: str
    indicators: Mapping[str, float] = field(default_factory=dict)
    details: Mapping[str, Any] = field(default_factory=dict)
    event_id: str = field(default_factory=lambda: uuid.uuid4().hex)
    # The bogie it is about, on a wagon judged on both (judgement/wagon.py): its id, "1" or "2";
    # None on a one-bogie gateway, whose records stay as they were.
    bogie: str | None = None

    def as_dict(self) -> dict[str, Any]:
        out = self._as_dict()
        if self.bogie is not None:
            out["bogie"] = self.bogie
        return out

    def _as_dict(self) -> dict[str, Any]:
        return {
            "event_id": self.event_id,
            "time_s": self.time_s,
            "kind": self.kind.value,
            "severity": self.severity.value,
            "config_hash": self.config_hash,
            "indicators": dict(self.indicators),
            "details": dict(self.details),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Event:
        return cls(
            time_s=float(data["time_s"]),
            kind=EventKind(data["kind"]),
            severity=Severity(data["severity"]),
            config_hash=str(data["config_hash"]),
            indicators=dict(data.get("indicators", {})),
            details=dict(data.get("details", {})),
            event_id=str(data["event_id"]),
            bogie=None if data.get("bogie") is None else str(data["bogie"]),
        )
