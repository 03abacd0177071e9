"""What bogiemon publishes over MQTT: the topics and the versioned JSON messages (docs/mqtt.md).

pydantic at the edge where events leave the process: the publisher builds these models and the
back-office consumer (`bogiemon listen`) and the fleet's judgement validate what they receive with
the same ones. A leaf: it imports pydantic and the event record alone (with its JSON,
daemon/event_json.py; never the monitor, the store, paho or python-can), so a reader of the
messages does not load the sender's stack; the status of a
running monitor is built in daemon/delivery/status.py. A schema
id ("bogiemon.event/2") changes its number only when a field is removed, renamed or changes its
meaning; new optional fields keep it, so readers ignore fields they do not know.

An event's details are its kind's record as daemon/event_json.py writes it; a received message
whose details are not a record of its kind is refused like any other field. bogiemon.event/2 writes
the k-of-n counts as objects ({"k": 3, "n": 5}, where /1 wrote "3 of 5"): both are read, so a back
office reads the gateways that still send /1 (and their backlog) as well as the new ones.

Every wagon's input is untrusted at the back office, so the models bound what they accept: finite
times in a plausible range, integers that fit SQLite's INTEGER, names that are topic levels, the
right container types, bounded lengths and a bounded payload. A message outside them is a
SchemaError (one line), never a value the listener's store or printing cannot handle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Final, Literal, TypeVar

from pydantic import BaseModel, ConfigDict, Field, StringConstraints, TypeAdapter, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError, PydanticSerializationError

from bogiemon.daemon.event_json import EventJsonError, details_from_body, event_body
from bogiemon.judgement.events import DEFAULT_BOGIE, Event, EventDetails, EventKind, Severity
from bogiemon.judgement.vocabulary import Mode

EVENT_SCHEMA: Final = "bogiemon.event/2"
STATUS_SCHEMA: Final = "bogiemon.status/1"
# The retained payloads of the state topic: "online" on connect, "offline" as the last will.
STATE_ONLINE, STATE_OFFLINE = "online", "offline"
TOPIC_LEAVES = ("events", "status", "state")

# The bounds of what a reader accepts. A real event or status is under 2 kB.
MAX_PAYLOAD_BYTES = 16_384
# Unix seconds from 1970 to 2286: a relative clock (a replayed recording from 0) fits, and so does
# anything a datetime can print. A time outside is a broken clock, not a moment.
TIME_S_MIN, TIME_S_MAX = 0.0, 1e10
INT_MAX = 2**63 - 1  # SQLite's INTEGER is signed 64-bit
MAX_ENTRIES = 64  # keys of an indicators, counters or details object; channels; problems per channel
MAX_VALUES = 16  # items of a short list (rms_mps2)
NAME = r"^[A-Za-z0-9._-]+$"  # a wagon id is a topic level (as `[wagon] id` in the config); ids and names alike

Name = Annotated[str, StringConstraints(pattern=NAME, max_length=64)]
ShortName = Annotated[str, StringConstraints(pattern=NAME, max_length=32)]  # a channel, problem, gate, indicator
UnixTime = Annotated[float, Field(ge=TIME_S_MIN, le=TIME_S_MAX, allow_inf_nan=False)]
Seq = Annotated[int, Field(ge=1, le=INT_MAX)]
Count = Annotated[int, Field(ge=0, le=INT_MAX)]
Value = float | None  # null (or NaN/Infinity, which go out as null): not finite
Indicators = Annotated[dict[ShortName, Value], Field(max_length=MAX_ENTRIES)]
Problems = Annotated[dict[ShortName, Annotated[list[ShortName], Field(max_length=MAX_ENTRIES)]], Field(max_length=MAX_ENTRIES)]
_PROBLEMS: TypeAdapter[dict[str, list[str]]] = TypeAdapter(Problems)
# The details a reader uses: channel -> problems (a sensor event's `problems` and `reported`).
CHECKED_DETAILS = ("problems", "reported")


class SchemaError(ValueError):
    """A message that does not follow its schema; the text is one line (what and why, never the value)."""


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
    # /1 wrote the k-of-n counts as "k of n" (daemon/event_json.py reads both).
    schema_id: Literal["bogiemon.event/1", "bogiemon.event/2"] = Field(EVENT_SCHEMA, alias="schema")
    wagon_id: Name
    seq: Seq  # the event's number in this wagon's event store: increases in commit order
    event_id: Name  # unique; a duplicate delivery carries the same one
    time_s: UnixTime  # end of the window that caused the event, Unix seconds (the source's clock)
    # NOT_JUDGED and JUDGED_AGAIN since 2026-12: an older reader refuses them as outside the schema
    # (one line, counted) and reads every other event on (docs/mqtt.md).
    kind: EventKind
    severity: Severity
    config_hash: Annotated[str, StringConstraints(max_length=128)]
    indicators: Indicators  # the values that fired (null: not finite)
    details: Annotated[dict[Annotated[str, StringConstraints(max_length=64)], Any], Field(max_length=MAX_ENTRIES)]
    # The bogie the event is about ([[bogie]] id; "1" on a one-bogie gateway). Absent from the
    # messages of gateways before two bogies: bogie "1"'s, as daemon/event_json.py reads a body.
    bogie: Annotated[str, StringConstraints(pattern=NAME, max_length=16)] = DEFAULT_BOGIE

    @field_validator("details")
    @classmethod
    def _details_readers_use(cls, details: dict[str, Any]) -> dict[str, Any]:
        # The rest of details is passed through as it came (JSON nests at most 200 deep when parsed).
        for key in CHECKED_DETAILS:
            if key in details:
                try:
                    _PROBLEMS.validate_python(details[key])
                except ValidationError as exc:
                    expected = "{key}: expected channel -> list of problem names ({reason})"
                    raise PydanticCustomError("problems", expected, {"key": key, "reason": describe(exc)}) from None
        return details

    @model_validator(mode="after")
    def _details_of_its_kind(self) -> EventMessage:
        try:
            self.details_record()
        except EventJsonError as exc:
            raise PydanticCustomError("details", "{reason}", {"reason": str(exc)}) from None
        return self

    def details_record(self) -> EventDetails:
        """The details as the record of the event's kind (judgement/events.py); validated, they read."""
        return details_from_body(self.kind, self.details)

    @classmethod
    def from_event(cls, wagon_id: str, seq: int, event: Event) -> EventMessage:
        return cls(wagon_id=wagon_id, seq=seq, **event_body(event))

    def to_event(self) -> Event:
        indicators = {name: float("nan") if v is None else v for name, v in self.indicators.items()}
        return Event(
            self.time_s, self.kind, self.severity, self.config_hash, indicators, details=self.details_record(), event_id=self.event_id,
            bogie=self.bogie,
        )


class LatestWindow(_Message):
    """The latest complete window as the monitor saw it."""

    start_s: UnixTime
    end_s: UnixTime
    judged: bool
    gate: ShortName | None  # "standstill", "non_stationary", "weak_excitation" or null
    sensors_ok: bool
    sensor_problems: Problems  # channel ("a1".., "source") -> problems
    indicators: Indicators  # all eight, i1..i4 and i1_norm..i4_norm
    rms_mps2: Annotated[list[Value], Field(max_length=MAX_VALUES)]  # the three channels' RMS after the high-pass


class OutboxStatus(_Message):
    pending_events: Count
    pending_alarms: Count
    pending_status: Count
    dropped_events: Count
    dropped_status: Count


class CoverageStatus(_Message):
    not_judged: bool  # a NOT_JUDGED is in force: running left unjudged for long (unlike the commissioning)
    unjudged_running_s: Annotated[float, Field(ge=0, le=TIME_S_MAX, allow_inf_nan=False)]  # since the last judged window
    last_judged_s: UnixTime | None  # the end of the last judged window (null: none yet)


class StatusMessage(_Message):
    """The periodic status, on {prefix}/{wagon_id}/status (QoS 1, retained)."""

    schema_id: Literal["bogiemon.status/1"] = Field(STATUS_SCHEMA, alias="schema")
    wagon_id: Name
    time_s: UnixTime  # when the status was taken, Unix seconds (the gateway's clock)
    mode: Mode
    config_hash: Annotated[str, StringConstraints(max_length=128)]
    window: LatestWindow | None  # null until the first window is complete
    counters: Annotated[dict[ShortName, Count], Field(max_length=MAX_ENTRIES)]  # the monitor's, since the daemon started
    outbox: OutboxStatus
    # How much running went unjudged (judgement/coverage.py); absent from gateways before 2026-12.
    coverage: CoverageStatus | None = None


def dump(message: _Message) -> str:
    """The JSON text that goes on the wire (strict JSON: non-finite numbers are null)."""
    return message.model_dump_json(by_alias=True)


M = TypeVar("M", bound=_Message)


def decode(model: type[M], payload: bytes) -> M:
    """A received message, validated; SchemaError (one line) for anything outside the schema."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise SchemaError(f"{len(payload)} bytes, over the limit of {MAX_PAYLOAD_BYTES}")
    try:
        return model.model_validate_json(payload)
    except ValidationError as exc:
        raise SchemaError(describe(exc)) from None


def encode_event(wagon_id: str, seq: int, event: Event) -> str:
    """The payload of a stored event; SchemaError when it cannot go out as bogiemon.event/2.

    The store gives back what Python's json wrote (any float, lone surrogates): what a reader would
    refuse is refused here, before it is sent.
    """
    try:
        return _encode(EventMessage.from_event(wagon_id, seq, event))
    except ValidationError as exc:
        raise SchemaError(describe(exc)) from None


def stored_status(body: str) -> str:
    """A status record read back from the outbox, as it goes out: validated and written again, so
    that only what the schema holds leaves (no field it ignores, strict JSON); SchemaError when a
    reader would refuse it. It was checked when queued: this is a record damaged in the store since."""
    return _encode(decode(StatusMessage, body.encode("utf-8", "surrogatepass")))


def encode_status(message: StatusMessage) -> str:
    """The payload of a status message; SchemaError when a reader would refuse it."""
    return _encode(message)


def _encode(message: _Message) -> str:
    try:
        payload = dump(message)
    except PydanticSerializationError as exc:  # nesting too deep, a lone surrogate
        raise SchemaError(printable(str(exc), 200)) from None
    # What goes out is what a reader accepts: read back as the listener reads it (a JSON reader
    # nests less deep than the writer, say). Events are rare and a status comes once a period.
    decode(type(message), payload.encode())
    return payload


def describe(exc: ValidationError, limit: int = 200) -> str:
    """A validation error as one printable line: where and why for the first error, and how many more."""
    errors = exc.errors(include_url=False, include_input=False, include_context=False)
    if not errors:
        return printable(str(exc), limit)
    first = errors[0]
    where = ".".join(str(part) for part in first["loc"])
    text = f"{where}: {first['msg']}" if where else str(first["msg"])
    if len(errors) > 1:
        text += f" (and {len(errors) - 1} more)"
    return printable(text, limit)


def printable(text: str, limit: int = 80) -> str:
    """Text from a wagon, safe to print on one line: control characters as '?', at most limit characters."""
    clean = "".join(c if c.isprintable() else "?" for c in text[: limit + 1])
    return clean if len(clean) <= limit else clean[: limit - 3] + "..."
