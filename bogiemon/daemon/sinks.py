"""Event sinks: where committed events are reported. The event store always comes first.

A sink receives an event only after it is durably committed, so whatever a sink shows is on disk.
LogSink is the service's (structlog JSON on stdout, syslog priority from the severity);
MemorySink is the test double. Later sinks (MQTT, CAN) implement the same two methods.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any

from bogiemon.daemon.event_json import event_body
from bogiemon.judgement.events import Event
from bogiemon.daemon.logs import get_logger


class EventSink(ABC):
    @abstractmethod
    def publish(self, event: Event) -> None:
        """Report one committed event. Must not raise for transport problems: count and retry."""

    def close(self) -> None:  # noqa: B027 - optional
        """Flush and release what the sink holds."""


class LogSink(EventSink):
    def __init__(self, logger: Any | None = None) -> None:
        self._log = logger if logger is not None else get_logger(component="events")

    def publish(self, event: Event) -> None:
        body = event_body(event)
        message = body.pop("kind")
        getattr(self._log, event.severity.log_level)(message, **body)


class MemorySink(EventSink):
    def __init__(self) -> None:
        self.events: list[Event] = []

    def publish(self, event: Event) -> None:
        self.events.append(event)
