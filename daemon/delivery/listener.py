"""A small back-office consumer: subscribes to every wagon's topics and keeps each event once.

For bench tests and demos (`bogiemon listen`). Delivery is at least once, so the same event can
arrive twice (after a crash of the daemon, or a PUBACK lost with the connection); the listener
keeps the first copy of each event_id and counts the rest. With a store file the kept events are
committed to SQLite before the broker gets the PUBACK, and the deduplication survives restarts.
The broker keeps this listener's session (a fixed client id, session expiry), so events published
while it is away are queued for it. The client comes from a transport factory (transport.py):
paho by default, memory_transport in tests.
"""

from __future__ import annotations

import json
import random
import sqlite3
import ssl
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from pydantic import ValidationError

from bogiemon.daemon.delivery.connection import ConnectionSettings, describe_connect_error, describe_refusal, is_auth_refusal
from bogiemon.daemon.delivery.paho_transport import paho_transport
from bogiemon.daemon.delivery.schema import EventMessage, StatusMessage, parse_topic, subscriptions
from bogiemon.daemon.delivery.transport import MqttTransport, Reason, TransportEvents, TransportFactory
from bogiemon.drivers.reconnect import Backoff

SESSION_EXPIRY_S = 86_400  # the broker queues events for a listener that is away up to a day
IO_WAIT_S = 0.1


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
    error: str | None = None  # a message that does not follow the schema


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
        """Commit an event; False if its event_id is already there."""
        cursor = self._db.execute(
            "INSERT OR IGNORE INTO received (event_id, wagon_id, seq, time_s, kind, received_s, body) VALUES (?, ?, ?, ?, ?, ?, ?)",
            (message.event_id, message.wagon_id, message.seq, message.time_s, message.kind, received_s, message.model_dump_json(by_alias=True)),
        )
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
    ) -> None:
        self.connection = connection
        self.prefix = prefix
        self.client_id = client_id
        self.store = store
        self.on_message = on_message
        self.on_link = on_link  # one line per change of the link (connected, failing: why)
        self.duplicates = 0
        self.invalid = 0
        self.states: dict[str, str] = {}  # wagon_id -> its last state
        self.statuses: list[StatusMessage] = []
        self._events: list[EventMessage] = []
        self._seen: set[str] = set(store.event_ids()) if store is not None else set()
        self._lock = threading.Lock()
        self._transport_factory = transport_factory
        self._backoff = Backoff(backoff_min_s, backoff_max_s, rng=random.Random(client_id))
        self._last_link: str | None = None
        self.subscribed = threading.Event()  # set once the subscriptions are acknowledged

    @property
    def events(self) -> list[EventMessage]:
        """The kept events of this run, in the order of their first arrival."""
        with self._lock:
            return list(self._events)

    def run(self, stop: threading.Event, max_events: int | None = None) -> None:
        """Receive until stop is set (or max_events new events were kept); reconnects on its own.

        Raises ListenError when the broker refuses the credentials or a certificate: retrying
        would not help.
        """
        while not stop.is_set():
            if max_events is not None and len(self._events) >= max_events:
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
            while outcome.end is None:
                if stop.is_set() or (max_events is not None and len(self._events) >= max_events):
                    stop_now = True
                    break
                error = transport.loop(IO_WAIT_S)
                if error is not None and outcome.end is None:
                    outcome.end = f"connection lost: {error}"
            transport.disconnect()
            if stop_now:
                return
            assert outcome.end is not None
            if outcome.auth_refused:
                raise ListenError(outcome.end)
            self._wait(stop, outcome.end)

    def _wait(self, stop: threading.Event, reason: str) -> None:
        self.subscribed.clear()
        self._link(f"failing: {reason}")
        stop.wait(self._backoff.failed())

    def _link(self, text: str) -> None:
        if text != self._last_link:
            self._last_link = text
            if self.on_link is not None:
                self.on_link(text)

    def _handle(self, topic: str, payload: bytes) -> None:
        where = parse_topic(self.prefix, topic)
        if where is None:
            return
        wagon_id, leaf = where
        received: Received
        try:
            if leaf == "state":
                state = payload.decode("utf-8", "replace")
                self.states[wagon_id] = state
                received = Received(wagon_id, leaf, state=state)
            elif leaf == "status":
                status = StatusMessage.model_validate_json(payload)
                self.statuses.append(status)
                received = Received(wagon_id, leaf, status=status)
            else:
                event = EventMessage.model_validate_json(payload)
                received = Received(wagon_id, leaf, event=event, duplicate=not self._keep(event))
        except (ValidationError, json.JSONDecodeError, UnicodeDecodeError) as exc:
            self.invalid += 1
            first = str(exc).splitlines()
            received = Received(wagon_id, leaf, error=f"{topic}: not a valid message: {' '.join(first[:3])}")
        if self.on_message is not None:
            self.on_message(received)

    def _keep(self, event: EventMessage) -> bool:
        with self._lock:
            if event.event_id in self._seen:
                self.duplicates += 1
                return False
            if self.store is not None and not self.store.add(event, time.time()):
                self.duplicates += 1
                self._seen.add(event.event_id)
                return False
            self._seen.add(event.event_id)
            self._events.append(event)
            return True


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
        self._listener._handle(topic, payload)
        self._transport.acknowledge(mid)  # only now: a kept event is committed to the store first
