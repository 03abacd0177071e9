"""What bogiemon publishes over MQTT: the topics and the versioned JSON messages (docs/mqtt.md).

pydantic at the edge where events leave the process: the publisher builds these models and the
back-office consumer (`bogiemon listen`) validates what it receives with the same ones. A schema
id ("bogiemon.event/1") changes its number only when a field is removed, renamed or changes its
meaning; new optional fields keep it, so readers ignore fields they do not know.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from bogiemon.daemon.decision import INDICATOR_FIELDS
from bogiemon.daemon.events import Event
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.store import OutboxCounts

EVENT_SCHEMA = "bogiemon.event/1"
STATUS_SCHEMA = "bogiemon.status/1"
# The retained payloads of the state topic: "online" on connect, "offline" as the last will.
STATE_ONLINE, STATE_OFFLINE = "online", "offline"
TOPIC_LEAVES = ("events", "status", "state")


@dataclass(frozen=True)
class Topics:
    """{prefix}/{wagon_id}/events, /status and /state."""

    prefix: str
    wagon_id: str

    @property
    def events(self) -> str:
        return f"{self.prefix}/{self.wagon_id}/events"

    @property
    def status(self) -> str:
        return f"{self.prefix}/{self.wagon_id}/status"

    @property
    def state(self) -> str:
        return f"{self.prefix}/{self.wagon_id}/state"


def subscriptions(prefix: str) -> list[str]:
    """The filters a back office subscribes to for every wagon under prefix."""
    return [f"{prefix}/+/{leaf}" for leaf in TOPIC_LEAVES]


def parse_topic(prefix: str, topic: str) -> tuple[str, str] | None:
    """(wagon_id, leaf) of a topic under prefix, or None if it is not one of ours."""
    head = prefix + "/"
    if not topic.startswith(head):
        return None
    parts = topic[len(head) :].split("/")
    if len(parts) != 2 or parts[1] not in TOPIC_LEAVES or not parts[0]:
        return None
    return parts[0], parts[1]


class _Message(BaseModel):
    # Readers ignore unknown fields: a new optional field does not change the schema id.
    # Non-finite numbers go out as null (strict JSON), hence `float | None` where they can occur.
    model_config = ConfigDict(extra="ignore", frozen=True, populate_by_name=True, ser_json_inf_nan="null")


class EventMessage(_Message):
    """One committed event, on {prefix}/{wagon_id}/events (QoS 1, not retained)."""

    # The JSON field is "schema" (an attribute of that name would shadow BaseModel.schema).
    schema_id: Literal["bogiemon.event/1"] = Field(EVENT_SCHEMA, alias="schema")
    wagon_id: str
    seq: int  # the event's number in this wagon's event store: increases in commit order
    event_id: str  # unique; a duplicate delivery carries the same one
    time_s: float  # end of the window that caused the event, Unix seconds (the source's clock)
    kind: Literal["SUSPECTED", "CONFIRMED", "CLEARED", "SENSOR_FAULT", "SENSOR_CLEARED"]
    severity: Literal["info", "warning", "alarm"]
    config_hash: str
    indicators: dict[str, float | None]  # the values that fired (null: not finite)
    details: dict[str, Any]

    @classmethod
    def from_event(cls, wagon_id: str, seq: int, event: Event) -> EventMessage:
        body = event.as_dict()
        return cls(wagon_id=wagon_id, seq=seq, **body)

    def to_event(self) -> Event:
        body = self.model_dump(exclude={"schema_id", "wagon_id", "seq"})
        body["indicators"] = {name: float("nan") if v is None else v for name, v in self.indicators.items()}
        return Event.from_dict(body)


class LatestWindow(_Message):
    """The latest complete window as the monitor saw it."""

    start_s: float
    end_s: float
    judged: bool
    gate: str | None  # "standstill", "weak_excitation" or null
    sensors_ok: bool
    sensor_problems: dict[str, list[str]]  # channel ("a1".., "source") -> problems
    indicators: dict[str, float | None]  # all eight, i1..i4 and i1_norm..i4_norm
    rms_mps2: list[float | None]  # the three channels' RMS after the high-pass


class OutboxStatus(_Message):
    pending_events: int
    pending_alarms: int
    pending_status: int
    dropped_events: int
    dropped_status: int


class StatusMessage(_Message):
    """The periodic status, on {prefix}/{wagon_id}/status (QoS 1, retained)."""

    schema_id: Literal["bogiemon.status/1"] = Field(STATUS_SCHEMA, alias="schema")
    wagon_id: str
    time_s: float  # when the status was taken, Unix seconds (the gateway's clock)
    mode: Literal["normal", "suspected", "confirmed"]
    config_hash: str
    window: LatestWindow | None  # null until the first window is complete
    counters: dict[str, int]  # the monitor's, since the daemon started
    outbox: OutboxStatus


def status_from_monitor(monitor: Monitor, wagon_id: str, time_s: float, outbox: OutboxCounts) -> StatusMessage:
    """The status message of a running monitor (read from another thread: each field is one read)."""
    report = monitor.latest
    window = None
    if report is not None:
        w, health = report.window, report.health
        window = LatestWindow(
            start_s=w.start_s,
            end_s=w.end_s,
            judged=report.judgement is not None,
            gate=None if health.gate is None else health.gate.value,
            sensors_ok=health.sensors_ok,
            sensor_problems={ch: [p.value for p in problems] for ch, problems in health.problems.items()},
            indicators={name: float(getattr(w, name)) for name in INDICATOR_FIELDS},
            rms_mps2=[float(v) for v in w.rms_mps2],
        )
    return StatusMessage(
        wagon_id=wagon_id,
        time_s=time_s,
        mode=report.mode if report is not None else monitor.mode,  # type: ignore[arg-type]
        config_hash=monitor.settings.config_hash,
        window=window,
        counters=dict(vars(monitor.counters)),
        outbox=OutboxStatus(
            pending_events=outbox.pending_events,
            pending_alarms=outbox.pending_alarms,
            pending_status=outbox.pending_status,
            dropped_events=outbox.dropped_events,
            dropped_status=outbox.dropped_status,
        ),
    )


def dump(message: _Message) -> str:
    """The JSON text that goes on the wire (strict JSON: non-finite numbers are null)."""
    return message.model_dump_json(by_alias=True)
