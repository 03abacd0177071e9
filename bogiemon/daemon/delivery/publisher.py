"""The MQTT outbox publisher: a thread that sends what the event store holds, oldest first.

The monitor commits events to the store and moves on; this thread reads the pending events (and
the status records it queues itself) and publishes them with QoS 1, marking each one delivered
only when the broker's PUBACK for it arrives. The store, not paho's memory, is the queue: every
connection gets a fresh client, and after any loss the backlog is read again from the oldest
pending row, so a message whose PUBACK was lost goes out again (with the same event_id: the back
office drops it). Events go before status records; within each, oldest first, at most
max_rate_msgs_per_s and max_inflight unacknowledged at a time. The client comes from a transport
factory (transport.py): paho by default, memory_transport in tests.

Connection failures are retried with a doubling, jittered backoff; each change of the link's
state (connected, lost, failing for a new reason) is logged once, not each attempt.

What the store holds is read back as it was written (any float, any string): an event that does
not fit bogiemon.event/2 (a reader would refuse it) is not sent, but logged once and counted, and
it stays in the store and pending; the rest of the outbox goes on.
"""

from __future__ import annotations

import random
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from bogiemon.daemon.delivery.connection import (
    ConnectionSettings,
    CredentialsError,
    LinkProblem,
    describe_closed,
    describe_connect_error,
    describe_refusal,
)
from bogiemon.daemon.delivery.paho_transport import paho_transport
from bogiemon.daemon.messages import (
    EVENT_SCHEMA,
    STATE_OFFLINE,
    STATE_ONLINE,
    SchemaError,
    StatusMessage,
    Topics,
    describe,
    encode_event,
    encode_status,
    stored_status,
)
from bogiemon.daemon.delivery.transport import MqttTransport, Reason, TransportEvents, TransportFactory, Will
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.store import EventStore, StoreWriteError
from bogiemon.daemon.outbox import OutboxCounts, PendingEvent, PendingStatus
from bogiemon.drivers.reconnect import Backoff

StatusSource = Callable[[OutboxCounts, float], StatusMessage]  # (outbox counts, Unix seconds) -> status

IO_WAIT_S = 0.05  # the network loop's select timeout: the latency of a new event at worst
TRIM_PERIOD_S = 1.0  # how often the outbox bound is enforced
FETCH_N = 100  # rows read from the store at a time
# A full disk or a read-only state directory: the publisher retries its writes this often (what was
# acknowledged but not marked stays pending and goes again: the listener drops the copy by event_id).
STORE_RETRY_S = 10.0
MAX_NOTED_UNSENDABLE = 10_000  # unsendable records remembered, so that each is logged once
STOP_FLUSH_S = 1.0  # at stop, how long the "offline" state and the last PUBACKs may take


@dataclass(frozen=True)
class PublisherSettings:
    connection: ConnectionSettings
    wagon_id: str
    topic_prefix: str = "bogiemon"
    client_id: str = ""  # empty: bogiemon-{wagon_id}
    status_period_s: float = 60.0  # 0: no status messages
    max_rate_msgs_per_s: float = 10.0
    max_inflight: int = 10
    outbox_max_messages: int = 10_000
    backoff_min_s: float = 1.0
    backoff_max_s: float = 60.0
    # Rows committed without a wake-up (another process writing the store) are found this late.
    poll_s: float = 0.5

    @property
    def topics(self) -> Topics:
        return Topics(self.topic_prefix, self.wagon_id)


@dataclass
class PublisherCounters:
    connect_attempts: int = 0
    connections: int = 0  # CONNACKs accepted
    connect_failures: int = 0
    connections_lost: int = 0
    published: int = 0  # PUBLISH packets sent, resends included
    delivered_events: int = 0  # PUBACKs recorded in the store
    delivered_status: int = 0
    refused: int = 0  # PUBACKs with a failure reason code (the message stays pending)
    status_queued: int = 0
    dropped_status: int = 0  # by the outbox bound, since start
    dropped_events: int = 0
    unsendable_events: int = 0  # pending events that do not fit the schema: not sent, left pending
    unsendable_status: int = 0  # status messages not queued or not sent: they did not fit the schema
    store_failures: int = 0  # writes to the event store it refused (full disk, read-only), each retried


class TokenBucket:
    """At most rate_per_s on average, bursts of at most burst (a pure function of the clock)."""

    def __init__(self, rate_per_s: float, burst: float, now_s: float) -> None:
        self.rate_per_s = rate_per_s
        self.burst = burst
        self._tokens = burst
        self._last_s = now_s

    def take(self, now_s: float) -> bool:
        self._tokens = min(self.burst, self._tokens + (now_s - self._last_s) * self.rate_per_s)
        self._last_s = now_s
        if self._tokens >= 1.0:
            self._tokens -= 1.0
            return True
        return False


@dataclass
class _Session:
    """One connection: its transport and what is in flight on it."""

    transport: MqttTransport
    started_s: float
    connected: bool = False  # the broker accepted the connection (CONNACK)
    announced: bool = False  # "online" sent and the connection logged
    end_reason: LinkProblem | None = None  # set by a callback: the session is over
    inflight: dict[int, tuple[str, int]] = field(default_factory=dict)  # mid -> ("event"|"status", seq)
    control_mids: set[int] = field(default_factory=set)  # the state messages, not in the outbox
    acked_events: list[int] = field(default_factory=list)
    acked_status: list[int] = field(default_factory=list)
    events: deque[PendingEvent] = field(default_factory=deque)  # read from the store, not yet sent
    status: deque[PendingStatus] = field(default_factory=deque)
    read_event_seq: int = 0  # the last seq read into `events` (or sent)
    read_status_seq: int = 0
    events_exhausted_s: float | None = None  # when a read found no more pending events
    status_exhausted_s: float | None = None


class OutboxPublisher:
    """Publishes the outbox of the event store in state_dir; start() it, wake() it, stop() it."""

    def __init__(
        self,
        settings: PublisherSettings,
        state_dir: str | Path,
        status_source: StatusSource | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
        transport_factory: TransportFactory = paho_transport,
    ) -> None:
        self.settings = settings
        self.state_dir = Path(state_dir)
        self.status_source = status_source
        self.counters = PublisherCounters()
        self.outbox: OutboxCounts | None = None  # as of the last trim (for the CAN heartbeat)
        self.error: BaseException | None = None  # an internal error that ended the thread
        self._clock = clock
        self._wall_clock = wall_clock
        self._transport_factory = transport_factory
        self._topics = settings.topics
        self._client_id = settings.client_id or f"bogiemon-{settings.wagon_id}"
        # Jittered so that a fleet does not reconnect in step; seeded with the wagon id, reproducibly.
        self._backoff = Backoff(settings.backoff_min_s, settings.backoff_max_s, clock, random.Random(settings.wagon_id))
        self._bucket = TokenBucket(settings.max_rate_msgs_per_s, max(1.0, settings.max_rate_msgs_per_s), clock())
        self._session: _Session | None = None
        self._last_state: tuple[str, str] | None = None
        self._unsendable: set[tuple[str, int]] = set()  # ("event" or "status", seq) of records that cannot be sent
        self._last_status_problem: str | None = None
        self._stop = threading.Event()
        self._wake = threading.Event()
        self._log = get_logger(component="mqtt", broker=settings.connection.address, client_id=self._client_id)
        self._thread = threading.Thread(target=self._run, name="bogiemon-mqtt", daemon=True)

    @property
    def connected(self) -> bool:
        session = self._session
        return session is not None and session.connected and session.end_reason is None

    def start(self) -> None:
        self._thread.start()

    def wake(self) -> None:
        """New events were committed: read the store now rather than at the next poll."""
        self._wake.set()

    def stop(self, timeout_s: float = 5.0) -> None:
        """Say "offline", wait briefly for outstanding PUBACKs, disconnect and end the thread."""
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    def is_alive(self) -> bool:
        return self._thread.is_alive()

    # The thread.

    def _run(self) -> None:
        store: EventStore | None = None
        try:
            store = EventStore(self.state_dir)  # its own connection: SQLite connections are per thread
            while True:
                try:
                    self._loop(store)
                    return
                except StoreWriteError as exc:
                    # The storage refuses a write (the monitor holds its events the same way): nothing
                    # is lost, the thread waits and goes on where it was once the disk takes writes.
                    self.counters.store_failures += 1
                    self._log.critical("mqtt delivery cannot write to the event store, retrying", error=str(exc), retry_s=STORE_RETRY_S)
                    if self._stop.wait(STORE_RETRY_S):
                        return
        except BaseException as exc:  # a bug or a broken disk: log it; the monitor goes on, the outbox keeps everything
            self.error = exc
            self._log.error("publisher failed", error=repr(exc))
        finally:
            if store is not None:
                try:
                    self._close_session(store)
                finally:
                    store.close()

    def _loop(self, store: EventStore) -> None:
        period_s = self.settings.status_period_s
        next_status_s = self._clock() + period_s
        next_trim_s = self._clock()
        while not self._stop.is_set():
            now_s = self._clock()
            if period_s > 0 and now_s >= next_status_s and self.status_source is not None:
                next_status_s += period_s
                if next_status_s <= now_s:  # fell behind (a long connect): skip, do not catch up
                    next_status_s = now_s + period_s
                self._queue_status(store)
                next_trim_s = now_s
            if now_s >= next_trim_s:
                next_trim_s = now_s + TRIM_PERIOD_S
                self._trim(store)
            session = self._session
            if session is None:
                due_in_s = self._backoff.due_in_s()
                if due_in_s <= 0:
                    self._open_session(now_s)
                else:
                    until_s = min(now_s + due_in_s, next_status_s if period_s > 0 else now_s + 1.0, next_trim_s)
                    self._stop.wait(max(0.0, min(until_s - now_s, 1.0)))
                continue
            error = session.transport.loop(IO_WAIT_S)  # network I/O; the events are reported here
            if error is not None and session.end_reason is None:
                session.end_reason = LinkProblem("lost", f"connection lost: {error}")
            self._after_io(store, session, self._clock())

    def _after_io(self, store: EventStore, session: _Session, now_s: float) -> None:
        self._commit_acks(store, session)
        if session.end_reason is not None:
            self._end_session(session, session.end_reason)
            return
        if not session.connected:
            if now_s - session.started_s > self.settings.connection.connect_timeout_s:
                self._end_session(session, LinkProblem("unreachable", f"no CONNACK from {self.settings.connection.address} within the connect timeout"))
            return
        if not session.announced:
            session.announced = True
            self._on_connected(session)
        self._send(store, session, now_s)

    # Connections.

    def _open_session(self, now_s: float) -> None:
        self.counters.connect_attempts += 1
        settings = self.settings.connection
        try:
            transport = self._transport_factory(settings, self._client_id, Will(self._topics.state, STATE_OFFLINE))
        except CredentialsError as exc:
            self._failed(LinkProblem("files", str(exc)))
            return
        session = _Session(transport=transport, started_s=now_s)
        try:
            # Blocking: TCP and TLS (bounded by connect_timeout_s). A clean start: the outbox, not
            # the broker's session, holds what is pending.
            transport.connect(_SessionEvents(self, session), clean_start=True)
        except OSError as exc:
            self._failed(describe_connect_error(exc, settings))
            return
        self._session = session

    def _on_connected(self, session: _Session) -> None:
        self.counters.connections += 1
        if self._last_state != ("lost", "rejected-message"):  # a broker refusing a message keeps backing off
            self._backoff.reset()
        counts = self.outbox
        self._note("connected", None, "info", pending=None if counts is None else counts.pending)
        session.control_mids.add(session.transport.publish(self._topics.state, STATE_ONLINE, retain=True).mid)

    def _failed(self, problem: LinkProblem) -> None:
        self.counters.connect_failures += 1
        delay_s = self._backoff.failed()
        # Configuration the broker will go on refusing is an error; an unreachable broker a warning.
        level = "error" if problem.kind in ("credentials", "tls", "files", "refused") else "warning"
        self._note("failing", problem, level, retry_in_s=round(delay_s, 2))

    def _end_session(self, session: _Session, problem: LinkProblem) -> None:
        was_connected = session.connected
        self._session = None
        session.transport.disconnect()
        if was_connected:
            self.counters.connections_lost += 1
            delay_s = self._backoff.failed()
            self._note("lost", problem, "warning", unacknowledged=len(session.inflight), retry_in_s=round(delay_s, 2))
        else:
            self._failed(problem)

    def _close_session(self, store: EventStore) -> None:
        """At stop: the state goes "offline" (a clean disconnect does not fire the will)."""
        session = self._session
        if session is None:
            return
        if self.connected:
            session.control_mids.add(session.transport.publish(self._topics.state, STATE_OFFLINE, retain=True).mid)
            deadline_s = self._clock() + STOP_FLUSH_S
            while (session.control_mids or session.inflight) and session.end_reason is None and self._clock() < deadline_s:
                session.transport.loop(IO_WAIT_S)
            self._commit_acks(store, session)
        self._session = None
        session.transport.disconnect()
        self._note("stopped", None, "info")

    def _note(self, state: str, problem: LinkProblem | None, level: str, **fields: Any) -> None:
        """Log a change of the link's state; a repeat of the same state and kind of problem stays quiet."""
        key = (state, problem.kind if problem is not None else "")
        if key == self._last_state:
            return
        self._last_state = key
        getattr(self._log, level)(f"mqtt {state}", **({"reason": problem.text} if problem is not None else {}), **fields)

    # The outbox.

    def _send(self, store: EventStore, session: _Session, now_s: float) -> None:
        if self._wake.is_set():  # rows were committed: read the store again once what was read is sent
            self._wake.clear()
            session.events_exhausted_s = session.status_exhausted_s = None
        while len(session.inflight) < self.settings.max_inflight:
            item = self._next_item(store, session, now_s)
            if item is None:
                return
            if isinstance(item, PendingEvent):
                try:
                    topic, payload, retain = self._topics.events, encode_event(self.settings.wagon_id, item.seq, item.event), False
                except SchemaError as exc:
                    self._skip_unsendable(item, exc)
                    continue
            else:
                try:
                    topic, payload, retain = self._topics.status, stored_status(item.body), True
                except SchemaError as exc:
                    self._skip_unsendable(item, exc)
                    continue
            if not self._bucket.take(now_s):
                self._put_back(session, item)
                return
            sent = session.transport.publish(topic, payload, retain=retain)
            if sent.error is not None:
                session.end_reason = LinkProblem("lost", f"publish failed: {sent.error}")
                return
            self.counters.published += 1
            session.inflight[sent.mid] = ("event", item.seq) if isinstance(item, PendingEvent) else ("status", item.seq)

    def _skip_unsendable(self, item: PendingEvent | PendingStatus, problem: SchemaError) -> None:
        """A record a reader would refuse: said once, counted once; it stays in the store, pending
        (a status record until the outbox bound drops it)."""
        key = ("event" if isinstance(item, PendingEvent) else "status", item.seq)
        if key in self._unsendable:
            return
        if len(self._unsendable) < MAX_NOTED_UNSENDABLE:
            self._unsendable.add(key)
        if isinstance(item, PendingEvent):
            self.counters.unsendable_events += 1
            self._log.error(
                f"mqtt event not sent: it does not fit {EVENT_SCHEMA}; it stays in the event store",
                seq=item.seq, event_id=item.event.event_id, kind=item.event.kind.value, reason=str(problem),
            )  # fmt: skip
        else:
            self.counters.unsendable_status += 1
            self._log.error("mqtt status not sent: the stored record does not fit its schema", seq=item.seq, reason=str(problem))

    def _next_item(self, store: EventStore, session: _Session, now_s: float) -> PendingEvent | PendingStatus | None:
        """The oldest pending event not yet sent on this session, else the oldest status record."""
        if not session.events and self._due(session.events_exhausted_s, now_s):
            rows = store.outbox.pending_events(after_seq=session.read_event_seq, limit=FETCH_N)
            session.events.extend(rows)
            session.events_exhausted_s = now_s if len(rows) < FETCH_N else None
            if rows:
                session.read_event_seq = rows[-1].seq
        if session.events:
            return session.events.popleft()
        if not session.status and self._due(session.status_exhausted_s, now_s):
            status_rows = store.outbox.pending_status(after_seq=session.read_status_seq, limit=FETCH_N)
            session.status.extend(status_rows)
            session.status_exhausted_s = now_s if len(status_rows) < FETCH_N else None
            if status_rows:
                session.read_status_seq = status_rows[-1].seq
        if session.status:
            return session.status.popleft()
        return None

    def _due(self, exhausted_s: float | None, now_s: float) -> bool:
        """Read the store again: the last read was a full page, or rows came since, or a poll is due."""
        return exhausted_s is None or now_s - exhausted_s >= self.settings.poll_s

    @staticmethod
    def _put_back(session: _Session, item: PendingEvent | PendingStatus) -> None:
        if isinstance(item, PendingEvent):
            session.events.appendleft(item)
        else:
            session.status.appendleft(item)

    def _commit_acks(self, store: EventStore, session: _Session) -> None:
        if not session.acked_events and not session.acked_status:
            return
        store.outbox.mark_delivered(session.acked_events, session.acked_status, self._wall_clock())
        self.counters.delivered_events += len(session.acked_events)
        self.counters.delivered_status += len(session.acked_status)
        session.acked_events.clear()
        session.acked_status.clear()

    def _queue_status(self, store: EventStore) -> None:
        assert self.status_source is not None
        try:
            message = self.status_source(store.outbox.counts(), self._wall_clock())
            body = encode_status(message)
        except (SchemaError, ValidationError) as exc:  # the next period may fit again
            self.counters.unsendable_status += 1
            problem = describe(exc) if isinstance(exc, ValidationError) else str(exc)
            if problem != self._last_status_problem:  # once per kind of problem, not every period
                self._last_status_problem = problem
                self._log.error("mqtt status not queued: it does not fit bogiemon.status/1", reason=problem)
            return
        self._last_status_problem = None
        store.outbox.queue_status(message.time_s, body)
        self.counters.status_queued += 1
        self._wake.set()

    def _trim(self, store: EventStore) -> None:
        dropped_status, dropped_events = store.outbox.trim_outbox(self.settings.outbox_max_messages, self._wall_clock())
        if dropped_status or dropped_events:
            self.counters.dropped_status += dropped_status
            self.counters.dropped_events += dropped_events
            self._log.warning(
                "mqtt outbox full: dropped the oldest undelivered messages",
                status=dropped_status, events=dropped_events, bound=self.settings.outbox_max_messages,
            )  # fmt: skip
            session = self._session
            if session is not None:  # rows read but not sent may be among the dropped: read again
                session.events.clear()
                session.status.clear()
                session.read_event_seq = max([seq for kind, seq in session.inflight.values() if kind == "event"], default=0)
                session.read_status_seq = max([seq for kind, seq in session.inflight.values() if kind == "status"], default=0)
                session.events_exhausted_s = session.status_exhausted_s = None
        self.outbox = store.outbox.counts()


class _SessionEvents(TransportEvents):
    """The transport's events for one session, noted for the publisher's thread (they run in it)."""

    def __init__(self, publisher: OutboxPublisher, session: _Session) -> None:
        self._publisher = publisher
        self._session = session

    def connected(self, reason: Reason) -> None:
        if reason.is_failure:
            self._session.end_reason = describe_refusal(reason)
        else:
            self._session.connected = True

    def disconnected(self, reason: Reason, detail: str | None) -> None:
        session = self._session
        if session.end_reason is None:
            session.end_reason = describe_closed(self._publisher.settings.connection, session.connected, reason, detail)

    def published(self, mid: int, reason: Reason) -> None:
        session = self._session
        if mid in session.control_mids:
            session.control_mids.discard(mid)
            return
        entry = session.inflight.pop(mid, None)
        if entry is None:
            return
        if reason.is_failure:
            # The broker refused the message (e.g. not authorised for the topic): it stays pending,
            # and the session ends so that the order of the backlog is kept.
            publisher = self._publisher
            publisher.counters.refused += 1
            session.end_reason = LinkProblem(
                "rejected-message",
                f"the broker refused a message ({reason}): check its ACL for {publisher.settings.topic_prefix}/{publisher.settings.wagon_id}/#",
            )
            return
        (session.acked_events if entry[0] == "event" else session.acked_status).append(entry[1])
