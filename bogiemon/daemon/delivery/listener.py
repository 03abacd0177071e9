"""A small back-office consumer: subscribes to every wagon's topics and keeps each event once.

For bench tests and demos (`bogiemon listen`). Delivery is at least once, so the same event can
arrive twice (after a crash of the daemon, or a PUBACK lost with the connection); the listener
keeps the first copy of each event_id and counts the rest. With a store file the kept events are
committed to SQLite before the broker gets the PUBACK, and the deduplication survives restarts.
The broker keeps this listener's session (a fixed client id, session expiry), so events published
while it is away are queued for it. The client comes from a transport factory (transport.py):
paho by default, memory_transport in tests.

Every wagon's message is untrusted: one that does not follow the schema is reported with the
wagon id of its topic, counted and acknowledged, so that a poison message never blocks the queue
(unacknowledged, the broker would send it again at every reconnection). What the listener holds
in memory is bounded whatever the fleet sends: the latest state and status of at most max_wagons
wagons, and the most recent events, statuses and event ids.
"""

from __future__ import annotations

import dataclasses
import random
import re
import sqlite3
import ssl
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

from bogiemon.daemon.delivery.connection import ConnectionSettings, describe_connect_error, describe_refusal, is_auth_refusal
from bogiemon.daemon.delivery.paho_transport import paho_transport
from bogiemon.daemon.messages import (
    STATE_OFFLINE,
    STATE_ONLINE,
    EventMessage,
    SchemaError,
    StatusMessage,
    decode,
    parse_topic,
    printable,
    subscriptions,
)
from bogiemon.daemon.delivery.transport import MqttTransport, Reason, TransportEvents, TransportFactory
from bogiemon.drivers.reconnect import Backoff

SESSION_EXPIRY_S = 86_400  # the broker queues events for a listener that is away up to a day
IO_WAIT_S = 0.1
# Memory bounds, whatever the fleet sends: each kept message is at most MAX_PAYLOAD_BYTES of JSON.
MAX_WAGONS = 10_000  # wagons whose latest state and status are kept (a large fleet)
RECENT_EVENTS = 10_000  # kept events held in memory (`Listener.events`); the store keeps them all
RECENT_STATUSES = 1_000  # status messages held in memory, all wagons (`Listener.statuses`)
# Event ids remembered to drop copies without a store (with one, its UNIQUE key drops them all): a
# copy comes with the resend of a lost PUBACK, within the outbox's in-flight window of the original.
RECENT_IDS = 100_000
_WAGON_ID = re.compile("[A-Za-z0-9._-]{1,64}")  # as `[wagon] id` in the config and the schema's wagon_id (fullmatch)

T = TypeVar("T")


class ListenError(Exception):
    """The listener cannot go on (credentials or certificate refused, a bad store file)."""


@dataclass(frozen=True)
class Received:
    """One message as the listener saw it."""

    wagon_id: str
    leaf: str  # "events", "status" or "state"
    event: EventMessage | None = None
    status: StatusMessage | None = None
    state: str | None = None  # "online" or "offline"
    duplicate: bool = False  # an event already kept
    error: str | None = None  # one line naming the wagon and why the message was skipped
    cleared: bool = False  # an empty retained state or status: the wagon's was deleted at the broker


class Latest(Generic[T]):
    """The latest value per key, for at most max_keys keys: the least recently updated goes first."""

    def __init__(self, max_keys: int) -> None:
        self.max_keys = max_keys
        self._items: OrderedDict[str, T] = OrderedDict()

    def put(self, key: str, value: T) -> None:
        self._items[key] = value
        self._items.move_to_end(key)
        while len(self._items) > self.max_keys:
            self._items.popitem(last=False)

    def pop(self, key: str) -> None:
        self._items.pop(key, None)

    def as_dict(self) -> dict[str, T]:
        return dict(self._items)


def parse_message(prefix: str, topic: str, payload: bytes) -> Received | None:
    """One message as the listener sees it, without state: None for a topic not under prefix.

    Never raises for any topic or payload: a message outside the schema (or from a topic whose
    wagon id is not a valid one, or whose payload names another wagon) comes back with `error`
    set, one printable line that starts with the topic's wagon id.
    """
    where = parse_topic(prefix, topic)
    if where is None:
        return None
    wagon_id, leaf = where

    def invalid(reason: str) -> Received:
        return Received(printable(wagon_id, 64), leaf, error=f"{printable(wagon_id, 64)}: not a valid message on {printable(topic, 160)}: {reason}")

    if not _WAGON_ID.fullmatch(wagon_id):
        return invalid("the wagon id in the topic is not one (letters, digits, '.', '_', '-'; at most 64)")
    if not payload and leaf != "events":  # a retained message deleted at the broker
        return Received(wagon_id, leaf, cleared=True)
    try:
        if leaf == "state":
            state = payload.decode("ascii", "replace")
            if state not in (STATE_ONLINE, STATE_OFFLINE):
                return invalid(f"the state is '{printable(state, 16)}', not {STATE_ONLINE} or {STATE_OFFLINE}")
            return Received(wagon_id, leaf, state=state)
        if leaf == "status":
            status = decode(StatusMessage, payload)
            if status.wagon_id != wagon_id:
                return invalid(f"it names another wagon, {status.wagon_id}")
            return Received(wagon_id, leaf, status=status)
        event = decode(EventMessage, payload)
    except SchemaError as exc:
        return invalid(str(exc))
    if event.wagon_id != wagon_id:
        return invalid(f"it names another wagon, {event.wagon_id}")
    return Received(wagon_id, leaf, event=event)


class ReceivedStore:
    """Kept events in SQLite (WAL, full sync): event_id is the primary key, so a copy is a no-op."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        try:
            self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute(
                "CREATE TABLE IF NOT EXISTS received (n INTEGER PRIMARY KEY AUTOINCREMENT, event_id TEXT NOT NULL UNIQUE, "
                "wagon_id TEXT NOT NULL, seq INTEGER NOT NULL, time_s REAL NOT NULL, kind TEXT NOT NULL, "
                "received_s REAL NOT NULL, body TEXT NOT NULL)"
            )
        except sqlite3.Error as exc:
            raise ListenError(f"{self.path}: cannot use it as the listener's store: {exc}") from None

    def add(self, message: EventMessage, received_s: float) -> bool:
        """Commit an event; False if its event_id is already there.

        Raises ListenError when it cannot be committed (a full disk, a read-only or broken file):
        the message is then not acknowledged, and the broker keeps it for the next run.
        """
        try:
            cursor = self._db.execute(
                "INSERT OR IGNORE INTO received (event_id, wagon_id, seq, time_s, kind, received_s, body) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (message.event_id, message.wagon_id, message.seq, message.time_s, message.kind, received_s, message.model_dump_json(by_alias=True)),
            )
        except sqlite3.Error as exc:
            raise ListenError(f"{self.path}: cannot commit an event to the listener's store: {exc}; the broker keeps it for the next run") from None
        return cursor.rowcount == 1

    def event_ids(self) -> list[str]:
        return [row[0] for row in self._db.execute("SELECT event_id FROM received ORDER BY n")]

    def events(self) -> list[EventMessage]:
        return [EventMessage.model_validate_json(row[0]) for row in self._db.execute("SELECT body FROM received ORDER BY n")]

    def close(self) -> None:
        self._db.close()


class Listener:
    """Subscribe to {prefix}/+/events, /status and /state; keep each event once, in arrival order."""

    def __init__(
        self,
        connection: ConnectionSettings,
        prefix: str = "bogiemon",
        client_id: str = "bogiemon-listen",
        store: ReceivedStore | None = None,
        on_message: Callable[[Received], None] | None = None,
        on_link: Callable[[str], None] | None = None,
        backoff_min_s: float = 0.5,
        backoff_max_s: float = 10.0,
        transport_factory: TransportFactory = paho_transport,
        max_wagons: int = MAX_WAGONS,
        recent_events: int = RECENT_EVENTS,
        recent_statuses: int = RECENT_STATUSES,
        recent_ids: int = RECENT_IDS,
    ) -> None:
        self.connection = connection
        self.prefix = prefix
        self.client_id = client_id
        self.store = store
        self.on_message = on_message
        self.on_link = on_link  # one line per change of the link (connected, failing: why)
        # Counters since this listener was made.
        self.kept = 0  # new events kept
        self.duplicates = 0  # copies of kept events, dropped
        self.invalid = 0  # messages outside the schema: reported, skipped and acknowledged
        self.failed = 0  # messages whose handling met a bug: reported, skipped and acknowledged
        self._states: Latest[str] = Latest(max_wagons)
        self._latest_status: Latest[StatusMessage] = Latest(max_wagons)
        self._statuses: deque[StatusMessage] = deque(maxlen=recent_statuses)
        self._events: deque[EventMessage] = deque(maxlen=recent_events)
        self._seen: OrderedDict[str, None] = OrderedDict()  # recent event ids, oldest first
        self._recent_ids = recent_ids
        self._lock = threading.Lock()  # what other threads read: the collections above, the counters
        self._transport_factory = transport_factory
        self._backoff = Backoff(backoff_min_s, backoff_max_s, rng=random.Random(client_id))
        self._last_link: str | None = None
        self.subscribed = threading.Event()  # set once the subscriptions are acknowledged

    @property
    def events(self) -> list[EventMessage]:
        """The most recent kept events (at most recent_events), in the order of their first arrival."""
        with self._lock:
            return list(self._events)

    @property
    def statuses(self) -> list[StatusMessage]:
        """The most recent status messages, all wagons (at most recent_statuses), in arrival order."""
        with self._lock:
            return list(self._statuses)

    @property
    def states(self) -> dict[str, str]:
        """wagon_id -> its last state, for the max_wagons wagons heard from most recently."""
        with self._lock:
            return self._states.as_dict()

    @property
    def latest_status(self) -> dict[str, StatusMessage]:
        """wagon_id -> its last status, for the max_wagons wagons heard from most recently."""
        with self._lock:
            return self._latest_status.as_dict()

    def summary(self) -> str:
        """The counters in one line."""
        with self._lock:
            text = f"events kept: {self.kept}, copies dropped: {self.duplicates}, invalid messages skipped: {self.invalid}"
            return text + (f", messages failed on (a bug): {self.failed}" if self.failed else "")

    def run(self, stop: threading.Event, max_events: int | None = None) -> None:
        """Receive until stop is set (or max_events new events were kept); reconnects on its own.

        Raises ListenError when the broker refuses the credentials or a certificate (retrying
        would not help), or when the store cannot commit an event.
        """
        while not stop.is_set():
            if max_events is not None and self.kept >= max_events:
                return
            transport = self._transport_factory(self.connection, self.client_id, None)
            outcome = _Outcome()
            try:
                # clean_start False: the broker keeps the session, and what it queued while we were away.
                transport.connect(_ListenerEvents(self, transport, outcome), clean_start=False, session_expiry_s=SESSION_EXPIRY_S)
            except OSError as exc:
                problem = describe_connect_error(exc, self.connection)
                if isinstance(exc, ssl.SSLCertVerificationError):  # retrying cannot help
                    raise ListenError(str(problem)) from None
                self._wait(stop, str(problem))
                continue
            stop_now = False
            try:
                while outcome.end is None:
                    if stop.is_set() or (max_events is not None and self.kept >= max_events):
                        stop_now = True
                        break
                    error = transport.loop(IO_WAIT_S)
                    if error is not None and outcome.end is None:
                        outcome.end = f"connection lost: {error}"
            finally:
                transport.disconnect()  # also after a store failure: the message not acknowledged stays queued
            if stop_now:
                return
            assert outcome.end is not None
            if outcome.auth_refused:
                raise ListenError(outcome.end)
            self._wait(stop, outcome.end)

    def handle(self, topic: str, payload: bytes) -> Received | None:
        """Take one message as received from the broker: parse, validate, keep; None if not under prefix.

        Returns what was made of it (`error` set for a message outside the schema, counted in
        `invalid`; `duplicate` for a copy of a kept event). Raises ListenError only when the
        store cannot commit an event, which must then not be acknowledged.
        """
        received = parse_message(self.prefix, topic, payload)
        if received is None:
            return None
        if received.event is not None:
            return dataclasses.replace(received, duplicate=not self._keep(received.event))
        with self._lock:
            if received.error is not None:
                self.invalid += 1
            elif received.state is not None:
                self._states.put(received.wagon_id, received.state)
            elif received.status is not None:
                self._latest_status.put(received.wagon_id, received.status)
                self._statuses.append(received.status)
            elif received.cleared:
                (self._states if received.leaf == "state" else self._latest_status).pop(received.wagon_id)
        return received

    def _failed(self, topic: str, exc: Exception) -> Received:
        """A message whose handling raised what it should not have: counted, and said with its wagon."""
        where = parse_topic(self.prefix, topic) or ("?", "?")
        with self._lock:
            self.failed += 1
        wagon = printable(where[0], 64)
        return Received(wagon, where[1], error=f"{wagon}: failed on a message on {printable(topic, 160)} "
                                                f"(a bug, please report it): {type(exc).__name__}: {printable(str(exc))}")  # fmt: skip

    def _wait(self, stop: threading.Event, reason: str) -> None:
        self.subscribed.clear()
        self._link(f"failing: {reason}")
        stop.wait(self._backoff.failed())

    def _link(self, text: str) -> None:
        if text != self._last_link:
            self._last_link = text
            if self.on_link is not None:
                self.on_link(text)

    def _keep(self, event: EventMessage) -> bool:
        with self._lock:
            if event.event_id in self._seen:
                self.duplicates += 1
                return False
            # A commit that fails raises before the id is remembered: the broker sends the event again.
            added = self.store is None or self.store.add(event, time.time())
            self._remember(event.event_id)
            if not added:
                self.duplicates += 1  # kept by an earlier run
                return False
            self.kept += 1
            self._events.append(event)
            return True

    def _remember(self, event_id: str) -> None:
        self._seen[event_id] = None
        while len(self._seen) > self._recent_ids:
            self._seen.popitem(last=False)


@dataclass
class _Outcome:
    """How one connection ended, as its events tell."""

    end: str | None = None  # why, once it has ended
    auth_refused: bool = False  # the credentials or the subscriptions refused: retrying cannot help


class _ListenerEvents(TransportEvents):
    """One connection's events, in the listener's thread."""

    def __init__(self, listener: Listener, transport: MqttTransport, outcome: _Outcome) -> None:
        self._listener = listener
        self._transport = transport
        self._outcome = outcome

    def connected(self, reason: Reason) -> None:
        listener, outcome = self._listener, self._outcome
        if reason.is_failure:
            outcome.auth_refused = is_auth_refusal(reason)
            outcome.end = str(describe_refusal(reason, "--username-file and --password-file"))
            return
        listener._backoff.reset()
        self._transport.subscribe(subscriptions(listener.prefix))

    def subscribed(self, reasons: Sequence[Reason]) -> None:
        listener, outcome = self._listener, self._outcome
        if any(r.is_failure for r in reasons):
            outcome.auth_refused = True
            outcome.end = f"the broker refused the subscriptions to {listener.prefix}/+/...: ({', '.join(map(str, reasons))})"
        else:
            listener._link(f"connected to {listener.connection.address}, subscribed to {listener.prefix}/+/events, status, state")
            listener.subscribed.set()

    def disconnected(self, reason: Reason, detail: str | None) -> None:
        if self._outcome.end is None:
            self._outcome.end = "connection lost" + ("" if reason.value == 0 else f": {reason}")

    def message(self, topic: str, payload: bytes, mid: int) -> None:
        listener = self._listener
        try:
            received = listener.handle(topic, payload)
            if received is not None and listener.on_message is not None:
                listener.on_message(received)
        except ListenError:
            raise  # the store cannot commit: no PUBACK, the broker keeps the message for the next run
        except Exception as exc:  # noqa: BLE001 - one wagon's message must not stop the fleet's queue
            failure = listener._failed(topic, exc)
            if listener.on_message is not None:
                listener.on_message(failure)
        self._transport.acknowledge(mid)  # only now: a kept event is committed to the store first
