"""Fuzz targets of alarm delivery: the MQTT schema, the listener's handling of each message, the outbox.

Messages are events, statuses and states as docs/mqtt.md describes them (built here from the
document, not with the models under test) from many wagons, damaged as JSON trees (null where an
object goes, a list of booleans, times of 1e300, a seq of 2^70, NaN, deep nesting, strings where
numbers go), as bytes, or sent on strange topics. The listener runs through its public API over a
scripted transport, with and without --store, and each message is printed as `bogiemon listen`
prints it: every message must be acknowledged (a poison message must not come back forever),
what is stored or printed must be finite and plausible, and memory must stay bounded under a flood.
The outbox target writes rows into a real event store as a damaged or foreign file may hold them
and has the publisher read them back: what it would publish must follow its own schema, and a
real publisher thread over the in-memory broker must deliver every readable pending event.
"""

from __future__ import annotations

import functools
import json
import random
import sqlite3
import threading
import time
from typing import Any

import fuzz_core
from bogiemon.cli.listen import format_received
from bogiemon.daemon import messages as schema
from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.listener import Listener, ReceivedStore
from bogiemon.daemon.delivery.memory_transport import MemoryBroker
from bogiemon.daemon.delivery.publisher import FETCH_N, OutboxPublisher, PublisherSettings
from bogiemon.daemon.messages import EventMessage, SchemaError, StatusMessage, dump, encode_event, stored_status
from bogiemon.daemon.delivery.transport import SUCCESS, MqttTransport, Publication, Reason, TransportEvents
from bogiemon.daemon.store import EventStore

PREFIX = "bogiemon"
WAGON = "318045331234"
KINDS = {
    "SUSPECTED": "warning", "CONFIRMED": "alarm", "CLEARED": "info", "SENSOR_FAULT": "warning", "SENSOR_CLEARED": "info", "NOT_JUDGED": "warning",
    "JUDGED_AGAIN": "info",
}  # fmt: skip
INDICATORS = ("i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm")
PROBLEMS = ("flat", "stuck", "clipping", "noisy", "over_range", "sensor_fault_bit", "dropouts")
# At most this many status messages may stay in memory after a flood (the listener keeps a few
# per wagon, or the most recent ones: not every one it ever received).
STATUS_BOUND = 1000


def event_body(rng: random.Random, wagon: str) -> dict[str, Any]:
    kind = rng.choice(list(KINDS))
    time_s = rng.choice((1.7e9, 1.8e9, 0.0, 12.0)) + rng.uniform(0, 1e6)
    details = details_body(rng, kind, time_s)
    indicators = {name: rng.uniform(-1, 1) for name in rng.sample(INDICATORS, rng.randint(0, 3))}
    # Both schemas a back office reads: /1 wrote the counts of windows as "k of n".
    return {"schema": rng.choice(("bogiemon.event/1", "bogiemon.event/2")), "wagon_id": wagon, "seq": rng.randint(1, 10**6), "event_id": rng.randbytes(16).hex(),
            "time_s": time_s, "kind": kind, "severity": KINDS[kind], "config_hash": rng.randbytes(6).hex(),
            "indicators": indicators, "details": details}  # fmt: skip


def details_body(rng: random.Random, kind: str, time_s: float) -> dict[str, Any]:
    """An event's details as the daemon writes them for its kind (daemon/event_json.py), either schema's counts."""
    window = {"window_start_s": time_s - 120, "window_end_s": time_s}
    problems = {rng.choice(("a1", "a2", "a3", "source")): rng.sample(PROBLEMS, rng.randint(1, 3))}
    rms = [rng.uniform(0, 3) for _ in range(3)]
    if kind == "SENSOR_FAULT":
        return {**window, "rms_mps2": rms, "problems": problems, "reported": problems}
    if kind == "SENSOR_CLEARED":
        return {**window, "rms_mps2": rms, "cleared": problems}
    if kind == "NOT_JUDGED":
        return {**window, "message": "not judged for the last 2.0 h of running", "unjudged_running_s": 7200.0, "last_judged_s": rng.choice((None, time_s - 7300))}
    if kind == "JUDGED_AGAIN":
        return window
    details: dict[str, Any] = {"load": rng.choice(("full", "tare")), **window, "thresholds": {"i4_norm": {"center": 0.0, "warning": 0.1, "alarm": 0.2}}}
    if kind == "CONFIRMED":
        details |= {"trigger": rng.choice(("windows", "trend")), "alarm_windows": rng.choice(("3 of 5", {"k": 3, "n": 5}))}
    elif kind == "CLEARED":
        details["cleared"] = rng.choice(("suspected", "confirmed"))
    return details


def status_body(rng: random.Random, wagon: str) -> dict[str, Any]:
    time_s = 1.7e9 + rng.uniform(0, 1e6)
    window = None
    if rng.random() < 0.8:
        window = {"start_s": time_s - 130, "end_s": time_s - 10, "judged": rng.random() < 0.5,
                  "gate": rng.choice((None, "standstill", "weak_excitation")), "sensors_ok": rng.random() < 0.9,
                  "sensor_problems": {} if rng.random() < 0.8 else {"a2": ["stuck"]},
                  "indicators": {name: rng.choice((rng.uniform(-1, 1), None)) for name in INDICATORS},
                  "rms_mps2": [rng.uniform(0, 3) for _ in range(3)]}  # fmt: skip
    counters = {name: rng.randint(0, 10**6) for name in ("blocks", "samples", "segments", "windows", "judged", "gated", "sensor_fault_windows", "events")}
    outbox = {name: rng.randint(0, 100) for name in ("pending_events", "pending_alarms", "pending_status", "dropped_events", "dropped_status")}
    return {"schema": "bogiemon.status/1", "wagon_id": wagon, "time_s": time_s, "mode": rng.choice(("normal", "suspected", "confirmed")),
            "config_hash": rng.randbytes(6).hex(), "window": window, "counters": counters, "outbox": outbox}  # fmt: skip


# Payloads too big to keep in a saved input: ["big", name] stands for them (built once per worker).
_EXAMPLE = {"schema": "bogiemon.event/2", "wagon_id": WAGON, "seq": 1, "event_id": "e1", "time_s": 1.7e9, "kind": "JUDGED_AGAIN",
            "severity": "info", "config_hash": "c0ffee", "indicators": {"i4_norm": 0.2}, "details": {"window_start_s": 1.7e9 - 120, "window_end_s": 1.7e9}}  # fmt: skip
BIG = {
    "deep_list": lambda: b"[" * 100_000 + b"]" * 100_000,
    "deep_object": lambda: b'{"a":' * 50_000 + b"1" + b"}" * 50_000,
    "trailing_space": lambda: json.dumps(_EXAMPLE).encode() + b" " * 200_000,
    "padded": lambda: json.dumps({**_EXAMPLE, "details": {"pad": "x" * 1_000_000}}).encode(),
    "many_keys": lambda: json.dumps({**_EXAMPLE, "details": {f"k{i}": i for i in range(50_000)}}).encode(),
    "long_wagon": lambda: json.dumps({**_EXAMPLE, "wagon_id": "w" * 100_000}).encode(),
}


@functools.cache
def _big(name: str) -> bytes:
    return BIG[name]()


def payload_bytes(payload: bytes | list[str]) -> bytes:
    return payload if isinstance(payload, bytes) else _big(payload[1])


def wagon_id(rng: random.Random) -> str:
    return rng.choice((WAGON, "318045331235", f"w{rng.randrange(1000)}", "a.b-c_d"))


def generate_message(rng: random.Random) -> list[Any]:
    """[topic, payload] of one message, valid or damaged (a payload may stand for a big one: BIG)."""
    m = fuzz_core.Mutator(rng)
    wagon = wagon_id(rng)
    leaf = rng.choices(("events", "status", "state"), (6, 3, 1))[0]
    if leaf == "events":
        body: Any = event_body(rng, wagon)
    elif leaf == "status":
        body = status_body(rng, wagon)
    else:
        body = None
    kind = rng.random()
    payload: bytes | list[str]  # a list names a big payload the target builds
    if body is None:
        payload = rng.choice((b"online", b"offline", b"", b"\xff\xfe", b"x" * 10_000, m.random_bytes(32)))
    elif kind < 0.25:
        payload = json.dumps(body).encode()
    elif kind < 0.8:
        payload = json.dumps(m.tree(body), allow_nan=True).encode("utf-8", "surrogatepass")
    elif kind < 0.9:
        payload = m.bytes(json.dumps(body).encode())
    else:
        payload = rng.choice([["big", name] for name in BIG]) if rng.random() < 0.5 else rng.choice((b"null", b"[]", b'"x"', b"1e999", b"{}"))
    topic = f"{PREFIX}/{wagon}/{leaf}"
    if rng.random() < 0.05:
        topic = rng.choice((f"{PREFIX}/{wagon}/{leaf}/x", f"{PREFIX}//{leaf}", f"{PREFIX}/+/{leaf}", f"other/{wagon}/{leaf}",
                            f"{PREFIX}/{'w' * 10_000}/{leaf}", f"{PREFIX}/\u0000/{leaf}", f"{PREFIX}/\u202e/{leaf}", f"{PREFIX}/{wagon}/"))  # fmt: skip
    return [topic, payload]


# ---- mqtt-schema ----------------------------------------------------------------------------


def generate_schema(rng: random.Random) -> fuzz_core.Input:
    topic, payload = generate_message(rng)
    return {"topic": topic, "payload": payload}


def _decode(model: type[Any], payload: bytes) -> Any:
    """The schema's reader where it has one (schema.decode, raising its own error), else pydantic's."""
    reader = getattr(schema, "decode", None)
    return reader(model, payload) if reader is not None else model.model_validate_json(payload)


def run_schema(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    leaf = data["topic"].rsplit("/", 1)[-1]
    if leaf not in ("events", "status"):
        return None
    model = EventMessage if leaf == "events" else StatusMessage
    message = _decode(model, payload_bytes(data["payload"]))
    if fuzz_core.implausible_time(message.time_s):
        return f"accepted an absurd time: time_s {message.time_s!r}"
    if leaf == "events":
        if not fuzz_core.SQLITE_INT_RANGE[0] <= message.seq <= fuzz_core.SQLITE_INT_RANGE[1]:
            return f"accepted a seq beyond SQLite's integers: {message.seq}"
        message.to_event()
    text = dump(message)
    try:
        fuzz_core.strict_json(text)
    except ValueError as exc:
        return f"dumps what is not strict JSON: {exc}"
    again = _decode(model, text.encode())
    if dump(again) != text:
        return "a message does not survive dump and read back unchanged"
    return None


# ---- mqtt-listen ----------------------------------------------------------------------------


class ScriptedTransport(MqttTransport):
    """Plays the broker's side: CONNACK, SUBACK, then one message per loop(); stops the listener after the last."""

    def __init__(self, messages: list[tuple[str, bytes]], stop: threading.Event) -> None:
        self.messages = messages
        self.stop = stop
        self.events: TransportEvents | None = None
        self.step = 0
        self.subscribed_to: list[str] = []
        self.acked: list[int] = []
        self.delivered: list[int] = []

    def connect(self, events: TransportEvents, clean_start: bool, session_expiry_s: int | None = None) -> None:
        self.events = events

    def loop(self, timeout_s: float) -> str | None:
        assert self.events is not None
        step, self.step = self.step, self.step + 1
        if step == 0:
            self.events.connected(SUCCESS)
        elif step == 1:
            self.events.subscribed([Reason(0x01, "Granted QoS 1")] * max(1, len(self.subscribed_to)))
        elif step - 2 < len(self.messages):
            topic, payload = self.messages[step - 2]
            mid = step - 1
            self.delivered.append(mid)
            self.events.message(topic, payload, mid)
        else:
            self.stop.set()
        return None

    def publish(self, topic: str, payload: str | bytes, retain: bool = False) -> Publication:
        return Publication(0)

    def subscribe(self, topics: Any) -> None:
        self.subscribed_to = list(topics)

    def acknowledge(self, mid: int) -> None:
        self.acked.append(mid)

    def disconnect(self) -> None:
        pass


def generate_listen(rng: random.Random) -> fuzz_core.Input:
    messages = [generate_message(rng) for _ in range(rng.randint(1, 6))]
    if rng.random() < 0.2:  # the same message again: at-least-once delivery
        messages.append(list(rng.choice(messages)))
    flood = {"wagons": rng.choice((3, 50)), "messages": 3000, "seed": rng.randrange(2**32)} if rng.random() < 0.0005 else None
    return {"messages": messages, "store": rng.random() < 0.25, "flood": flood}


def run_listen(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    messages = [(topic, payload_bytes(payload)) for topic, payload in data["messages"]]
    if data["flood"] is not None:
        rng = random.Random(data["flood"]["seed"])
        wagons = [f"w{i}" for i in range(data["flood"]["wagons"])]
        for _ in range(data["flood"]["messages"]):
            wagon = rng.choice(wagons)
            messages.append((f"{PREFIX}/{wagon}/status", json.dumps(status_body(rng, wagon)).encode()))
    store = ReceivedStore(ctx.fresh_dir() / "received.sqlite3") if data["store"] else None
    stop = threading.Event()
    transports: list[ScriptedTransport] = []

    def factory(settings: ConnectionSettings, client_id: str, will: Any) -> ScriptedTransport:
        transports.append(ScriptedTransport(messages, stop))
        return transports[-1]

    def show(received: Any) -> None:  # as `bogiemon listen --status` prints, both ways
        if received.error is None:
            format_received(received, True, True)
            format_received(received, False, True)

    listener = Listener(ConnectionSettings("fuzz.invalid", 1883), prefix=PREFIX, client_id="fuzz", store=store, on_message=show,
                        transport_factory=factory, backoff_min_s=0.001, backoff_max_s=0.002)  # fmt: skip
    try:
        listener.run(stop)
        (transport,) = transports
        missing = sorted(set(transport.delivered) - set(transport.acked))
        if missing:
            return f"a message was not acknowledged: {len(missing)} of {len(transport.delivered)} (it would come back at every restart)"
        held = len(getattr(listener, "statuses", ()))
        if data["flood"] is not None and held > max(STATUS_BOUND, data["flood"]["wagons"]):
            return f"memory grows with the messages: {held} status messages held after {data['flood']['messages']}"
        if store is not None:
            store.close()
            store = None
            return _check_received(ctx)
    finally:
        if store is not None:
            store.close()
    return None


def _check_received(ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    db = sqlite3.connect(ctx.root / "input" / "received.sqlite3")
    try:
        rows = db.execute("SELECT seq, time_s, body FROM received").fetchall()
    finally:
        db.close()
    for seq, time_s, body in rows:
        if fuzz_core.implausible_time(time_s):
            return f"stored an absurd time: time_s {time_s!r}"
        if not isinstance(seq, int):
            return f"stored a seq that is not an integer: {seq!r}"
        try:
            fuzz_core.strict_json(body)
        except ValueError as exc:
            return f"stored a body that is not strict JSON: {exc}"
    store = ReceivedStore(ctx.root / "input" / "received.sqlite3")
    try:
        store.events()  # what a later run reads back
    finally:
        store.close()
    return None


# ---- outbox ----------------------------------------------------------------------------------


def generate_outbox(rng: random.Random) -> fuzz_core.Input:
    m = fuzz_core.Mutator(rng)
    events = []
    seq = 0
    for _ in range(rng.randint(1, 8)):
        seq += rng.choice((1, 1, 1, 2, 1000))
        body = event_body(rng, WAGON)
        row: dict[str, Any] = {"seq": seq, "event_id": body["event_id"], "time_s": body["time_s"], "kind": body["kind"],
                               "severity": body["severity"], "config_hash": body["config_hash"], "delivered_s": None, "dropped_s": None}  # fmt: skip
        stored = {k: body[k] for k in ("event_id", "time_s", "kind", "severity", "config_hash", "indicators", "details")}
        kind = rng.random()
        if kind < 0.5:
            row["body"] = json.dumps(stored)
        elif kind < 0.8:
            row["body"] = json.dumps(m.tree(stored), allow_nan=True)
        elif kind < 0.9:
            row["body"] = m.bytes(json.dumps(stored).encode())  # a blob: not even text
        else:
            row["body"] = rng.choice(("", "null", "[]", "{}", json.dumps({**stored, "time_s": 1e300}), json.dumps({**stored, "kind": "EXPLODED"})))
        if rng.random() < 0.05:
            row["seq"] = rng.choice((2**63 - 1, -1, 0))
        if rng.random() < 0.1:
            row["delivered_s"] = 1.7e9
        events.append(row)
    statuses = []
    for _ in range(rng.choice((0, 0, 1, 2))):
        body = status_body(rng, WAGON)
        text = json.dumps(body) if rng.random() < 0.6 else json.dumps(m.tree(body), allow_nan=True)
        statuses.append({"time_s": body["time_s"], "body": text})
    state = None
    if rng.random() < 0.1:
        state = rng.choice(('{"dropped_status": 3}', '{"dropped_status": "x"}', "[]", "not json", '{"dropped_status": 1e300}'))
    return {"events": events, "statuses": statuses, "outbox_state": state, "publish": rng.random() < 0.1}


def _fill_store(data: fuzz_core.Input, state_dir: Any) -> None:
    EventStore(state_dir).close()  # today's schema
    db = sqlite3.connect(state_dir / "events.sqlite3", isolation_level=None)
    try:
        for row in data["events"]:
            try:
                db.execute(
                    "INSERT INTO events (seq, event_id, time_s, kind, severity, config_hash, body, delivered_s, dropped_s) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                    (row["seq"], row["event_id"], row["time_s"], row["kind"], row["severity"], row["config_hash"], row["body"], row["delivered_s"], row["dropped_s"]),
                )
            except sqlite3.IntegrityError:
                pass  # a seq or an event_id twice: the file cannot hold it either
        for row in data["statuses"]:
            db.execute("INSERT INTO status_outbox (time_s, body) VALUES (?, ?)", (row["time_s"], row["body"]))
        if data["outbox_state"] is not None:
            db.execute("INSERT OR REPLACE INTO state (key, value) VALUES ('outbox', ?)", (data["outbox_state"],))
    finally:
        db.close()


def run_outbox(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    state_dir = ctx.fresh_dir() / "state"
    _fill_store(data, state_dir)
    store = EventStore(state_dir)
    try:
        # What the publisher's thread reads and sends: the pending events page by page, then the status.
        sent: list[int] = []
        after = 0
        for _ in range(1000):
            rows = store.outbox.pending_events(after_seq=after, limit=FETCH_N)
            for row in rows:
                try:  # what the publisher sends, or refuses (counted, left pending) before sending
                    payload = encode_event(WAGON, row.seq, row.event)
                except SchemaError:
                    continue
                verdict = _check_payload(payload, EventMessage)
                if verdict is not None:
                    return verdict
                sent.append(row.seq)
            if len(rows) < FETCH_N:
                break
            after = rows[-1].seq
        for status in store.outbox.pending_status(after_seq=0, limit=FETCH_N):
            try:  # the publisher's own check of a stored status record before it goes out
                payload = stored_status(status.body)
            except SchemaError:
                continue
            verdict = _check_payload(payload, StatusMessage)
            if verdict is not None:
                return "a status record " + verdict
        store.outbox.counts()
        if data["publish"] and sent:
            verdict = _publish(state_dir, sent)
            if verdict is not None:
                return verdict
        store.outbox.trim_outbox(10, time.time())
        store.outbox.counts()
    finally:
        store.close()
    return None


def _check_payload(payload: str, model: type[Any]) -> fuzz_core.Verdict:
    try:
        fuzz_core.strict_json(payload)
    except ValueError as exc:
        return f"would be published as what is not strict JSON: {exc}"
    try:
        message = _decode(model, payload.encode("utf-8", "surrogatepass"))
    except Exception as exc:  # noqa: BLE001 - whatever the listener would say
        return f"would be published as what its own schema refuses: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    if fuzz_core.implausible_time(message.time_s):
        return f"would be published at an absurd time: time_s {message.time_s!r}"
    return None


def _publish(state_dir: Any, expected: list[int]) -> fuzz_core.Verdict:
    """A real publisher thread over the in-memory broker: every readable pending event arrives."""
    broker = MemoryBroker()
    topics = f"{PREFIX}/{WAGON}/events"
    settings = PublisherSettings(connection=ConnectionSettings("fuzz.invalid", 1883), wagon_id=WAGON, topic_prefix=PREFIX,
                                 status_period_s=0.0, max_rate_msgs_per_s=10_000.0, max_inflight=50, backoff_min_s=0.01,
                                 backoff_max_s=0.05, poll_s=0.01)  # fmt: skip
    publisher = OutboxPublisher(settings, state_dir, transport_factory=broker.transport)

    def arrived() -> set[int]:
        seqs = set()
        for message in broker.messages(topics):
            try:
                seqs.add(json.loads(message.payload)["seq"])
            except (ValueError, KeyError, TypeError):
                pass
        return seqs

    publisher.start()
    try:
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline and publisher.is_alive() and publisher.error is None:
            if broker.wait_for(lambda: set(expected) <= arrived(), 0.02):
                break
    finally:
        publisher.stop()
    if publisher.error is not None:
        raise publisher.error
    missing = set(expected) - arrived()
    if missing:
        return f"pending events not published within 2 s: {len(missing)} of {len(expected)} (the outbox is stuck)"
    return None


TARGETS = [
    fuzz_core.Target("mqtt-schema", generate_schema, run_schema),
    fuzz_core.Target("mqtt-listen", generate_listen, run_listen),
    fuzz_core.Target("outbox", generate_outbox, run_outbox),
]
