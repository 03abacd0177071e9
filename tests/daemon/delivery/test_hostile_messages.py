"""Every wagon's MQTT input is untrusted: what the back office and the outbox do with what does not fit the schema.

The inputs the issue (17) found crashing `bogiemon listen` are here exactly as it names them; each
is now one line naming the wagon, counted, and acknowledged, so that it never blocks the queue.
The listener's memory is bounded, and the publisher's outbox sends only what a reader accepts.
Real components: the in-memory broker, real SQLite files; `bogiemon listen` against a real
mosquitto is in test_listen.py.
"""

from __future__ import annotations

import json
import math
import threading
from pathlib import Path
from typing import Any

import pytest
import structlog.testing
from hypothesis import HealthCheck, given
from hypothesis import settings as hypothesis_settings
from hypothesis import strategies as st

from bogiemon.cli.listen import format_received
from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.listener import RECENT_STATUSES, Listener, ListenError, Received, ReceivedStore, parse_message
from bogiemon.daemon.delivery.memory_transport import MemoryBroker, MemoryTransport
from bogiemon.daemon.delivery.publisher import OutboxPublisher
from bogiemon.daemon.messages import (
    EventMessage,
    LatestWindow,
    MAX_PAYLOAD_BYTES,
    OutboxStatus,
    SchemaError,
    StatusMessage,
    Topics,
    decode,
    dump,
    encode_event,
    encode_status,
    stored_status,
)
from bogiemon.daemon.delivery.transport import TransportEvents
from bogiemon.judgement.events import Event, EventKind, NotJudgedDetails, SensorFaultDetails
from bogiemon.daemon.store import EventStore
from bogiemon.daemon.outbox import OutboxCounts
from tests.daemon.delivery.support import DEADLINE_S, PREFIX, WAGON, commit, make_events, running, settings
from tests.judgement.event_examples import event_of

LINK = ConnectionSettings("broker.example", 8883)
TOPICS = Topics(PREFIX, WAGON)
WHERE = f"{WAGON}: not a valid message on {TOPICS.events}: "  # how each line about a bad event starts


def sensor_fault(time_s: float = 1.7e9) -> Event:
    """A SENSOR_FAULT as the daemon's health check commits it: the event whose problems are printed."""
    flat = {"a1": ("flat",)}
    return Event.of(time_s, SensorFaultDetails(window_start_s=time_s - 10, window_end_s=time_s, rms_mps2=(0.0, 1.2, 1.1), problems=flat, reported=flat), "c0ffee")


def event_body(seq: int = 1, **fields: Any) -> dict[str, Any]:
    """A valid event message as JSON values, with fields replaced."""
    body = json.loads(dump(EventMessage.from_event(WAGON, 1, sensor_fault())))
    body.update(seq=seq, **fields)
    return body


def with_problems(problems: Any) -> dict[str, Any]:
    body = event_body()
    body["details"]["problems"] = problems
    return body


def status_body(**fields: Any) -> dict[str, Any]:
    window = LatestWindow(start_s=1.7e9 - 10, end_s=1.7e9, judged=False, gate="standstill", sensors_ok=False, sensor_problems={"a1": ["flat"]},
                          indicators={"i1": 0.5, "i1_norm": None}, rms_mps2=[0.0, 1.2, None])  # fmt: skip
    status = StatusMessage(wagon_id=WAGON, time_s=1.7e9, mode="normal", config_hash="c0ffee", window=window, counters={"windows": 3},
                           outbox=OutboxStatus(pending_events=0, pending_alarms=0, pending_status=0, dropped_events=0, dropped_status=0))  # fmt: skip
    body = json.loads(dump(status))
    body.update(fields)
    return body


def as_payload(body: Any) -> bytes:
    return json.dumps(body).encode()  # Python's json writes NaN and Infinity as a careless sender would


def printed(received: Received | None) -> list[str]:
    """What `bogiemon listen` prints for a message, in both output modes (the CLI prints an error itself)."""
    assert received is not None
    return [line for line in (format_received(received, as_json, True) for as_json in (False, True)) if line is not None]


# The inputs the issue names, exactly: each one crashed `bogiemon listen` (printing or --store).


def test_an_event_at_time_1e300_is_one_line_naming_the_wagon_and_counted(tmp_path: Path) -> None:
    listener = Listener(LINK, prefix=PREFIX, store=ReceivedStore(tmp_path / "received.sqlite3"))
    received = listener.handle(TOPICS.events, as_payload(event_body(time_s=1e300)))
    assert received == Received(WAGON, "events", error=WHERE + "time_s: Input should be less than or equal to 10000000000")
    assert printed(received) == [] and (listener.invalid, listener.kept) == (1, 0)


def test_an_event_whose_problems_are_null_is_one_line_naming_the_wagon_and_counted(tmp_path: Path) -> None:
    listener = Listener(LINK, prefix=PREFIX, store=ReceivedStore(tmp_path / "received.sqlite3"))
    received = listener.handle(TOPICS.events, as_payload(with_problems(None)))
    assert received is not None and received.error == WHERE + "details: problems: expected channel -> list of problem names (Input should be a valid dictionary)"
    assert printed(received) == [] and listener.invalid == 1


def test_an_event_whose_problems_are_a_list_of_booleans_is_one_line_naming_the_wagon_and_counted(tmp_path: Path) -> None:
    listener = Listener(LINK, prefix=PREFIX, store=ReceivedStore(tmp_path / "received.sqlite3"))
    received = listener.handle(TOPICS.events, as_payload(with_problems([True, False])))
    assert received is not None and received.error == WHERE + "details: problems: expected channel -> list of problem names (Input should be a valid dictionary)"
    channel_of_booleans = listener.handle(TOPICS.events, as_payload(with_problems({"a1": [True, False]})))
    assert channel_of_booleans is not None
    assert channel_of_booleans.error == WHERE + "details: problems: expected channel -> list of problem names (a1.0: Input should be a valid string (and 1 more))"
    assert listener.invalid == 2


def test_an_event_with_seq_2_to_the_70_is_skipped_and_the_store_is_untouched(tmp_path: Path) -> None:
    store = ReceivedStore(tmp_path / "received.sqlite3")
    listener = Listener(LINK, prefix=PREFIX, store=store)
    received = listener.handle(TOPICS.events, as_payload(event_body(seq=2**70)))
    assert received is not None and received.error == WHERE + "seq: Input should be less than or equal to 9223372036854775807"
    assert store.event_ids() == [] and listener.invalid == 1
    good = event_body(seq=2**63 - 1)  # the largest SQLite holds is kept
    assert listener.handle(TOPICS.events, as_payload(good)) == Received(WAGON, "events", event=EventMessage.model_validate(good))
    assert store.event_ids() == [good["event_id"]]


def test_a_status_with_a_huge_time_is_one_line_naming_the_wagon_and_not_kept() -> None:
    listener = Listener(LINK, prefix=PREFIX)
    received = listener.handle(TOPICS.status, as_payload(status_body(time_s=1e300)))
    assert received == Received(WAGON, "status", error=f"{WAGON}: not a valid message on {TOPICS.status}: time_s: Input should be less than or equal to 10000000000")
    assert printed(received) == [] and listener.statuses == [] and listener.latest_status == {} and listener.invalid == 1


# Anything else the schemas let through before and the code could not handle.

OVERSIZED = as_payload(event_body(details={"pad": "x" * MAX_PAYLOAD_BYTES}))
HOSTILE_EVENTS: list[tuple[str, str, bytes, str]] = [
    ("nan time", TOPICS.events, as_payload(event_body(time_s=math.nan)), "time_s: Input should be a finite number"),
    ("infinite time", TOPICS.events, as_payload(event_body(time_s=math.inf)), "time_s: Input should be a finite number"),
    ("negative time", TOPICS.events, as_payload(event_body(time_s=-1.0)), "time_s: Input should be greater than or equal to 0"),
    ("seq 0", TOPICS.events, as_payload(event_body(seq=0)), "seq: Input should be greater than or equal to 1"),
    ("seq as text", TOPICS.events, as_payload({**event_body(), "seq": "one"}), "seq: Input should be a valid integer, unable to parse string as an integer"),
    ("event id with a line end", TOPICS.events, as_payload(event_body(event_id="abc\ndef")), "event_id: String should match pattern '^[A-Za-z0-9._-]+$'"),
    ("another wagon's event", TOPICS.events, as_payload(event_body(wagon_id="318045339999")), "it names another wagon, 318045339999"),
    ("indicators a list", TOPICS.events, as_payload(event_body(indicators=[1, 2])), "indicators: Input should be an object"),
    ("details null", TOPICS.events, as_payload(event_body(details=None)), "details: Input should be an object"),
    ("reported null", TOPICS.events, as_payload(event_body(details={"reported": None})),
     "details: reported: expected channel -> list of problem names (Input should be a valid dictionary)"),
    ("65 indicators", TOPICS.events, as_payload(event_body(indicators={f"i{n}": 1.0 for n in range(65)})),
     "indicators: Dictionary should have at most 64 items after validation, not more"),
    ("not json", TOPICS.events, b"not json", "Invalid JSON: expected ident at line 1 column 2"),
    ("not utf-8", TOPICS.events, b'{"schema": "\xff"}', "Invalid JSON: invalid unicode code point at line 1 column 13"),
    ("a json list", TOPICS.events, b"[]", "Input should be an object"),
    ("empty", TOPICS.events, b"", "Invalid JSON: EOF while parsing a value at line 1 column 0"),
    ("nested 5000 deep", TOPICS.events, b'{"details": ' + b"[" * 5000 + b"]" * 5000 + b"}", "Invalid JSON: recursion limit exceeded at line 1 column 213"),
    ("over the size limit", TOPICS.events, OVERSIZED, f"{len(OVERSIZED)} bytes, over the limit of {MAX_PAYLOAD_BYTES}"),
    ("counters of 2^70", TOPICS.status, as_payload(status_body(counters={"windows": 2**70})), "counters.windows: Input should be less than or equal to 9223372036854775807"),
    ("a negative outbox", TOPICS.status, as_payload(status_body(outbox={**status_body()["outbox"], "pending_events": -1})),
     "outbox.pending_events: Input should be greater than or equal to 0"),
    ("another wagon's status", TOPICS.status, as_payload(status_body(wagon_id="x")), "it names another wagon, x"),
    ("a window from 1e300", TOPICS.status,
     as_payload(status_body(window={"start_s": 1e300, "end_s": 1e300, "judged": True, "gate": None, "sensors_ok": True, "sensor_problems": {}, "indicators": {}, "rms_mps2": []})),
     "window.start_s: Input should be less than or equal to 10000000000 (and 1 more)"),
    ("a state that is neither", TOPICS.state, b"\x1b[2Jpwned", "the state is '?[2Jpwned', not online or offline"),
]  # fmt: skip


@pytest.mark.parametrize(("topic", "payload", "reason"), [case[1:] for case in HOSTILE_EVENTS], ids=[case[0] for case in HOSTILE_EVENTS])
def test_a_message_outside_the_schema_is_one_line_naming_the_wagon_and_counted(tmp_path: Path, topic: str, payload: bytes, reason: str) -> None:
    store = ReceivedStore(tmp_path / "received.sqlite3")
    listener = Listener(LINK, prefix=PREFIX, store=store)
    received = listener.handle(topic, payload)
    assert received is not None and received.error == f"{WAGON}: not a valid message on {topic}: {reason}"
    assert printed(received) == []
    assert (listener.invalid, listener.kept, store.event_ids(), listener.states, listener.statuses) == (1, 0, [], {}, [])


def test_a_topic_whose_wagon_id_is_not_one_is_said_printably_and_counted() -> None:
    listener = Listener(LINK, prefix=PREFIX)
    received = listener.handle(f"{PREFIX}/wagon\x1b[31m red/events", as_payload(event_body()))
    assert received == Received("wagon?[31m red", "events", error=f"wagon?[31m red: not a valid message on {PREFIX}/wagon?[31m red/events: "
                                                                      "the wagon id in the topic is not one (letters, digits, '.', '_', '-'; at most 64)")  # fmt: skip
    assert listener.invalid == 1


def test_an_empty_retained_state_or_status_forgets_the_wagons() -> None:
    listener = Listener(LINK, prefix=PREFIX)
    listener.handle(TOPICS.state, b"online")
    listener.handle(TOPICS.status, as_payload(status_body()))
    assert listener.handle(TOPICS.state, b"") == Received(WAGON, "state", cleared=True)
    assert listener.handle(TOPICS.status, b"") == Received(WAGON, "status", cleared=True)
    assert (listener.states, listener.latest_status, listener.invalid) == ({}, {}, 0)


def test_a_topic_not_under_the_prefix_is_ignored_uncounted() -> None:
    listener = Listener(LINK, prefix=PREFIX)
    assert listener.handle(f"other/{WAGON}/events", b"\xff") is None and parse_message(PREFIX, f"{PREFIX}/{WAGON}/x", b"") is None
    assert listener.invalid == 0


# Generated and mutated messages: parse_message never raises, and what it accepts prints, stores and
# reads back as it was.

JSON_LEAVES = st.none() | st.booleans() | st.integers(min_value=-(2**80), max_value=2**80) | st.floats() | st.text(max_size=20)
JSON_VALUES = st.recursive(JSON_LEAVES, lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4), max_leaves=12)
EVENT_FIELDS = ["schema", "wagon_id", "seq", "event_id", "time_s", "kind", "severity", "config_hash", "indicators", "details"]
STATUS_FIELDS = ["schema", "wagon_id", "time_s", "mode", "config_hash", "window", "counters", "outbox"]
WINDOW_FIELDS = ["start_s", "end_s", "judged", "gate", "sensors_ok", "sensor_problems", "indicators", "rms_mps2"]


def mutated(body: dict[str, Any], fields: list[str], data: st.DataObject) -> dict[str, Any]:
    # None to three changes: a message left as it was (or changed where nothing is checked) is always
    # kept, so both sides of the edge are tried in every run, whatever the draw (with one to three
    # changes, a run of 300 could draw none that stayed valid: the typed details refuse most changes).
    body = json.loads(json.dumps(body))
    for _ in range(data.draw(st.integers(0, 3))):
        field = data.draw(st.sampled_from(fields))
        if data.draw(st.booleans()):
            body[field] = data.draw(JSON_VALUES)
        elif isinstance(body.get(field), dict):  # a value inside: a detail, an indicator, a problem list
            body[field][data.draw(st.sampled_from([*body[field], "problems", "i1"]))] = data.draw(JSON_VALUES)
        else:
            body.pop(field, None)
    return body


def test_any_mutated_message_is_kept_or_counted_and_what_is_kept_prints_and_reads_back_as_it_was(tmp_path: Path) -> None:
    store = ReceivedStore(tmp_path / "received.sqlite3")
    listener = Listener(LINK, prefix=PREFIX, store=store)
    outcomes = {"kept": 0, "invalid": 0}

    @hypothesis_settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(data=st.data(), n=st.integers(1, 2**40))
    def check(data: st.DataObject, n: int) -> None:
        is_event = data.draw(st.booleans())
        if is_event:
            body = mutated(event_body(seq=n, event_id=f"e{n}"), EVENT_FIELDS, data)
        else:
            body = status_body()
            body = mutated({**body, "window": mutated(body["window"], WINDOW_FIELDS, data)}, STATUS_FIELDS, data)
        invalid_before = listener.invalid
        received = listener.handle(TOPICS.events if is_event else TOPICS.status, as_payload(body))
        assert received is not None
        if received.error is not None:
            assert listener.invalid == invalid_before + 1 and "\n" not in received.error and received.error.startswith(f"{WAGON}: not a valid message on ")
            outcomes["invalid"] += 1
            return
        message = received.event if is_event else received.status
        assert message is not None and len(printed(received)) == (0 if received.duplicate else 2)  # prints in both modes
        again = decode(type(message), dump(message).encode())
        assert dump(again) == dump(message)  # what is printed with --json is read back unchanged
        if received.event is not None and not received.duplicate:
            assert dump(store.events()[-1]) == dump(received.event)  # committed as it was received
        outcomes["kept"] += 1

    check()
    assert outcomes["invalid"] > 0 and outcomes["kept"] > 0  # both sides of the edge were tried


# A poison message on a broker: acknowledged once, never sent again.


def wagon(broker: MemoryBroker) -> MemoryTransport:
    transport = broker.transport(LINK, f"bogiemon-{WAGON}")
    transport.connect(TransportEvents(), clean_start=True)
    transport.loop(0.0)
    return transport


def test_a_poison_message_is_acknowledged_once_and_not_delivered_again_after_a_restart(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    lines: list[str | None] = []
    first, second = (EventMessage.from_event(WAGON, seq, e) for seq, e in enumerate(make_events(2), start=1))

    def listener() -> Listener:
        store = ReceivedStore(tmp_path / "received.sqlite3")
        return Listener(LINK, prefix=PREFIX, client_id="office", store=store, on_message=lambda r: lines.append(r.error), transport_factory=memory_broker.transport)

    with running(listener()) as one:
        sender = wagon(memory_broker)
        sender.publish(TOPICS.events, as_payload(event_body(time_s=1e300)))
        sender.publish(TOPICS.events, dump(first))
        assert memory_broker.wait_for(lambda: one.kept == 1 and memory_broker.unacknowledged("office") == [], DEADLINE_S)
    assert lines == [WHERE + "time_s: Input should be less than or equal to 10000000000", None] and one.invalid == 1
    with running(listener()) as two:
        sender.publish(TOPICS.events, dump(second))
        assert memory_broker.wait_for(lambda: two.kept == 1, DEADLINE_S)
    assert (two.invalid, two.events, lines[2:]) == (0, [second], [None])  # the poison did not come back
    assert ReceivedStore(tmp_path / "received.sqlite3").event_ids() == [first.event_id, second.event_id]


def test_a_message_the_listener_fails_on_is_said_counted_and_acknowledged(memory_broker: MemoryBroker) -> None:
    lines: list[str | None] = []

    def on_message(received: Received) -> None:  # a bug in what prints the events, met by the first one
        lines.append(received.error)
        if received.event is not None and received.event.seq == 1:
            raise KeyError("window_end_s")

    events = [EventMessage.from_event(WAGON, seq, e) for seq, e in enumerate(make_events(2), start=1)]
    with running(Listener(LINK, prefix=PREFIX, client_id="office", on_message=on_message, transport_factory=memory_broker.transport)) as listener:
        sender = wagon(memory_broker)
        for message in events:
            sender.publish(TOPICS.events, dump(message))
        assert memory_broker.wait_for(lambda: listener.kept == 2 and memory_broker.unacknowledged("office") == [], DEADLINE_S)
    assert lines == [None, f"{WAGON}: failed on a message on {TOPICS.events} (a bug, please report it): KeyError: 'window_end_s'", None]
    assert listener.summary() == "events kept: 2, copies dropped: 0, invalid messages skipped: 0, messages failed on (a bug): 1"


def test_an_event_the_store_cannot_commit_ends_the_listener_unacknowledged(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = ReceivedStore(tmp_path / "received.sqlite3")
    store._db.execute("PRAGMA query_only = ON")  # as a read-only file: every commit fails
    listener = Listener(LINK, prefix=PREFIX, client_id="office", store=store, transport_factory=memory_broker.transport)
    errors: list[BaseException] = []
    thread = threading.Thread(target=lambda: _run_into(listener, errors), daemon=True)
    thread.start()
    assert listener.subscribed.wait(DEADLINE_S)
    message = EventMessage.from_event(WAGON, 1, make_events(1)[0])
    wagon(memory_broker).publish(TOPICS.events, dump(message))
    thread.join(DEADLINE_S)
    assert [type(e) for e in errors] == [ListenError]
    assert str(errors[0]) == (f"{store.path}: cannot commit an event to the listener's store: attempt to write a readonly database; "
                              "the broker keeps it for the next run")  # fmt: skip
    assert memory_broker.unacknowledged("office") == [(TOPICS.events, dump(message).encode())]


def _run_into(listener: Listener, errors: list[BaseException]) -> None:
    try:
        listener.run(threading.Event())
    except BaseException as exc:  # surfaced by the test
        errors.append(exc)


# Memory: bounded whatever the fleet sends.


def test_the_listener_keeps_the_latest_state_and_status_of_the_most_recent_max_wagons_only() -> None:
    listener = Listener(LINK, prefix=PREFIX, max_wagons=100, recent_statuses=50)
    wagons = [f"w{n:05d}" for n in range(1000)]
    for _round in range(2):
        for wagon_id in wagons:
            listener.handle(f"{PREFIX}/{wagon_id}/state", b"online")
            listener.handle(f"{PREFIX}/{wagon_id}/status", as_payload(status_body(wagon_id=wagon_id)))
    assert sorted(listener.states) == wagons[-100:] and sorted(listener.latest_status) == wagons[-100:]
    assert [s.wagon_id for s in listener.statuses] == wagons[-50:]
    assert listener.invalid == 0


def test_the_default_bounds_hold_for_a_fleet_larger_than_them() -> None:
    listener = Listener(LINK, prefix=PREFIX)
    for n in range(12_000):
        listener.handle(f"{PREFIX}/w{n}/state", b"offline")
    for n in range(RECENT_STATUSES + 10):
        listener.handle(f"{PREFIX}/w{n}/status", as_payload(status_body(wagon_id=f"w{n}")))
    assert len(listener.states) == 10_000 and len(listener.statuses) == RECENT_STATUSES and len(listener.latest_status) == RECENT_STATUSES + 10


def test_kept_events_held_in_memory_are_the_most_recent_and_the_count_goes_on() -> None:
    listener = Listener(LINK, prefix=PREFIX, recent_events=10)
    bodies = [event_body(seq=n, event_id=f"e{n}") for n in range(1, 101)]
    for body in bodies:
        listener.handle(TOPICS.events, as_payload(body))
    assert [m.event_id for m in listener.events] == [f"e{n}" for n in range(91, 101)] and listener.kept == 100


def test_without_a_store_a_copy_is_dropped_only_among_the_recent_ids_and_with_one_always(tmp_path: Path) -> None:
    memory_only = Listener(LINK, prefix=PREFIX, recent_ids=50)
    stored = Listener(LINK, prefix=PREFIX, recent_ids=50, store=ReceivedStore(tmp_path / "received.sqlite3"))
    bodies = [as_payload(event_body(seq=n, event_id=f"e{n}")) for n in range(1, 101)]
    for listener in (memory_only, stored):
        for payload in [*bodies, bodies[60], bodies[0]]:  # a recent copy, and one older than the last 50 ids
            listener.handle(TOPICS.events, payload)
    assert (memory_only.kept, memory_only.duplicates) == (101, 1)
    assert (stored.kept, stored.duplicates) == (100, 2)


# The outbox: what the store holds goes out only as a reader accepts it.


# Details nested deeper than a reader reads, which the store could once hold, are no longer made:
# every event's details are a record of its kind, a few levels deep (judgement/events.py).
LARGE = event_of(EventKind.NOT_JUDGED, 1.7e9, text="x" * MAX_PAYLOAD_BYTES)
UNSENDABLE: list[tuple[str, Event, str]] = [
    ("infinite time", sensor_fault(math.inf), "time_s: Input should be a finite number"),
    ("nan time", sensor_fault(math.nan), "time_s: Input should be a finite number"),
    ("time 1e300", sensor_fault(1e300), "time_s: Input should be less than or equal to 10000000000"),
    ("an indicator as text", event_of(EventKind.SUSPECTED, 1.7e9, {"i1": "x"}),  # type: ignore[dict-item]
     "indicators.i1: Input should be a valid number, unable to parse string as a number"),
    ("a lone surrogate", event_of(EventKind.NOT_JUDGED, 1.7e9, text="\ud800"),
     "Error serializing to JSON: UnicodeEncodeError: 'utf-8' codec can't encode character '\\ud800' in position 0: surrogates not allowed"),
    ("over the size limit", LARGE, f"{len(dump(EventMessage.from_event(WAGON, 1, LARGE)))} bytes, over the limit of {MAX_PAYLOAD_BYTES}"),
]  # fmt: skip


@pytest.mark.parametrize(("event", "reason"), [case[1:] for case in UNSENDABLE], ids=[case[0] for case in UNSENDABLE])
def test_an_event_a_reader_would_refuse_is_not_encoded(event: Event, reason: str) -> None:
    with pytest.raises(SchemaError) as error:
        encode_event(WAGON, 1, event)
    assert str(error.value) == reason


FLOATS = st.floats() | st.sampled_from([0.0, 1e10, 1e10 + 1, -1e-300, 1e300])


@hypothesis_settings(max_examples=300, deadline=None)
@given(
    time_s=FLOATS, value=FLOATS | st.none(), seq=st.integers(-1, 2**64), rms=FLOATS, text=st.text(max_size=40),
    problems=st.dictionaries(st.text(max_size=8), st.lists(st.text(max_size=8), max_size=3).map(tuple), max_size=3),
)  # fmt: skip
def test_what_the_outbox_encodes_a_reader_accepts_as_the_same_event(
    time_s: float, value: float | None, seq: int, rms: float, text: str, problems: dict[str, tuple[str, ...]]
) -> None:  # fmt: skip
    window = {"window_start_s": time_s - 120.0, "window_end_s": time_s}
    for details in (
        SensorFaultDetails(window_start_s=time_s - 120.0, window_end_s=time_s, rms_mps2=(rms, 1.0, 1.0), problems=problems, reported=problems),
        NotJudgedDetails(**window, message=text, unjudged_running_s=7200.0, last_judged_s=None, unlike=text),
    ):
        check_the_outbox_encodes_as_a_reader_reads(Event.of(time_s, details, "c0ffee", {"i1": value}), seq)  # type: ignore[dict-item]


def check_the_outbox_encodes_as_a_reader_reads(event: Event, seq: int) -> None:
    time_s = event.time_s
    try:
        payload = encode_event(WAGON, seq, event)
    except SchemaError:
        return
    received = parse_message(PREFIX, TOPICS.events, payload.encode())
    assert received is not None and received.error is None and received.event is not None
    assert received.event.seq == seq and received.event.to_event().time_s == time_s
    assert dump(received.event) == payload


def test_the_outbox_skips_an_unsendable_event_says_it_once_and_sends_the_rest_in_order(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = EventStore(tmp_path / "state")
    good = make_events(3)
    bad = [UNSENDABLE[4][1], UNSENDABLE[2][1]]  # a lone surrogate, a time of 1e300: what the store takes back as it was
    listener = Listener(LINK, prefix=PREFIX, client_id="office", transport_factory=memory_broker.transport)
    with structlog.testing.capture_logs() as logs, running(listener):
        publisher = OutboxPublisher(settings(LINK), tmp_path / "state", transport_factory=memory_broker.transport)
        publisher.start()
        try:
            commit(store, [good[0], bad[0], good[1], bad[1]], publisher)
            assert memory_broker.wait_for(lambda: listener.kept == 2, DEADLINE_S)
            memory_broker.drop_links(f"bogiemon-{WAGON}")  # a new session reads the two again from the store
            assert memory_broker.wait_for(lambda: publisher.counters.connections == 2, DEADLINE_S)
            commit(store, [good[2]], publisher)
            assert memory_broker.wait_for(lambda: listener.kept == 3, DEADLINE_S)
        finally:
            publisher.stop()
    assert [m.to_event() for m in listener.events] == good and listener.invalid == 0
    skipped = [(entry["seq"], entry["event_id"], entry["log_level"]) for entry in logs if entry["event"].startswith("mqtt event not sent")]
    assert skipped == [(2, bad[0].event_id, "error"), (4, bad[1].event_id, "error")]  # once each, not again on the new session
    assert publisher.counters.unsendable_events == 2 and publisher.is_alive() is False and publisher.error is None
    assert store.outbox.counts().pending_events == 2 and store.count() == 5  # they stay in the store, pending


def test_a_status_that_does_not_fit_is_not_queued_said_once_and_the_events_still_go(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = EventStore(tmp_path / "state")

    def broken_clock_status(outbox: OutboxCounts, time_s: float) -> StatusMessage:
        return StatusMessage(wagon_id=WAGON, time_s=1e300, mode="normal", config_hash="c0ffee", window=None, counters={},
                             outbox=OutboxStatus(**{k: getattr(outbox, k) for k in OutboxStatus.model_fields}))  # fmt: skip

    listener = Listener(LINK, prefix=PREFIX, client_id="office", transport_factory=memory_broker.transport)
    with structlog.testing.capture_logs() as logs, running(listener):
        publisher = OutboxPublisher(settings(LINK, status_period_s=0.02), tmp_path / "state", status_source=broken_clock_status,
                                    transport_factory=memory_broker.transport)  # fmt: skip
        publisher.start()
        try:
            assert memory_broker.wait_for(lambda: publisher.counters.unsendable_status >= 3, DEADLINE_S)
            committed = make_events(2)
            commit(store, committed, publisher)
            assert memory_broker.wait_for(lambda: listener.kept == 2, DEADLINE_S)
        finally:
            publisher.stop()
    said = [(entry["reason"], entry["log_level"]) for entry in logs if entry["event"].startswith("mqtt status not queued")]
    assert said == [("time_s: Input should be less than or equal to 10000000000", "error")]
    assert publisher.counters.status_queued == 0 and listener.statuses == [] and publisher.error is None


def test_a_status_record_damaged_in_the_store_is_not_published_said_once_and_the_events_still_go(
    tmp_path: Path, memory_broker: MemoryBroker
) -> None:
    # Found by make fuzz (outbox): a status row changed in the store since it was queued (not an
    # object, or -Infinity, which is not JSON) went out as it was.
    store = EventStore(tmp_path / "state")
    store.outbox.queue_status(1.7e9, "[1, 2]")
    store.outbox.queue_status(1.7e9 + 1, '{"time_s": -Infinity}')
    listener = Listener(LINK, prefix=PREFIX, client_id="office", transport_factory=memory_broker.transport)
    with structlog.testing.capture_logs() as logs, running(listener):
        publisher = OutboxPublisher(settings(LINK), tmp_path / "state", transport_factory=memory_broker.transport)
        publisher.start()
        try:
            committed = make_events(2)
            commit(store, committed, publisher)
            assert memory_broker.wait_for(lambda: listener.kept == 2 and publisher.counters.unsendable_status == 2, DEADLINE_S)
        finally:
            publisher.stop()
    said = [entry["seq"] for entry in logs if entry["event"].startswith("mqtt status not sent")]
    assert said == [1, 2]
    assert listener.statuses == [] and listener.invalid == 0 and publisher.error is None


def test_a_stored_status_goes_out_as_its_schema_holds_it_without_fields_it_ignores() -> None:
    # Found by make fuzz (outbox): a stored status with a field the schema ignores, holding
    # -Infinity, was published as it was, which is not JSON.
    message = StatusMessage(wagon_id=WAGON, time_s=1.7e9, mode="normal", config_hash="c0ffee", window=None, counters={"windows": 3},
                            outbox=OutboxStatus(pending_events=0, pending_alarms=0, pending_status=1, dropped_events=0, dropped_status=0))  # fmt: skip
    damaged = json.loads(encode_status(message))
    damaged["extra"] = -math.inf
    out = stored_status(json.dumps(damaged))
    strict = json.loads(out, parse_constant=lambda name: pytest.fail(f"{name} is not JSON"))
    assert "extra" not in strict and strict == json.loads(encode_status(message))
