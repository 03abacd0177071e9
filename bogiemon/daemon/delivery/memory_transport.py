"""An MQTT broker in memory and its client transports: delivery without a network, for tests and demos.

MemoryBroker keeps what a broker keeps for the part of MQTT 5 that bogiemon uses: QoS 1 with its
PUBACKs, retained messages, last wills, and sessions that outlive a connection (session expiry)
with their subscriptions and unacknowledged messages. It fails on demand: stop() and start() (a
restart; the sessions survive, as with mosquitto's persistence), drop_links() (the network cut:
the wills fire, PUBACKs under way are lost), refuse_connections (a CONNACK refusal),
refuse_publications (a PUBACK with a failure reason) and withhold_acks (PUBACKs held back).

It has no thread: a client's call acts on the broker at once, and what the broker sends a client
waits in that client's inbox until the client's own thread calls loop(), as paho calls its
callbacks. The same calls in the same order give the same events; wait_for() lets a test await a
condition that changes with any broker or client activity instead of sleeping.
"""

from __future__ import annotations

import errno
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.transport import SUCCESS, MqttTransport, Publication, Reason, TransportEvents, Will

# The reason codes the broker uses, named as in the MQTT 5 standard (and by paho).
REASON_NAMES = {
    0x00: "Success",
    0x01: "Granted QoS 1",
    0x10: "No matching subscribers",  # a PUBACK's, not a failure: mosquitto says so too
    0x80: "Unspecified error",
    0x86: "Bad user name or password",
    0x87: "Not authorized",
    0x88: "Server unavailable",
    0x8B: "Server shutting down",
    0x8E: "Session taken over",
    0x97: "Quota exceeded",
}
GRANTED_QOS_1 = Reason(0x01, REASON_NAMES[0x01])
LINK_LOST = "The connection was lost."  # paho's words for these, so that the logs read the same
NOT_CONNECTED = "The client is not currently connected."


def reason(value: int) -> Reason:
    """The Reason for a code, named as in the standard."""
    return Reason(value, REASON_NAMES.get(value, f"reason code 0x{value:02X}"))


def topic_matches(pattern: str, topic: str) -> bool:
    """MQTT topic filter matching: `+` one level, `#` the rest (and the parent level)."""
    parts, levels = pattern.split("/"), topic.split("/")
    for i, part in enumerate(parts):
        if part == "#":
            return True
        if i >= len(levels) or (part != "+" and part != levels[i]):
            return False
    return len(parts) == len(levels)


@dataclass(frozen=True)
class BrokerMessage:
    """A message as the broker received it (every copy: a resend is a second one)."""

    topic: str
    payload: bytes
    retain: bool
    client_id: str  # who published it ("" for a will: the broker itself)


@dataclass
class _Session:
    client_id: str
    expiry_s: int  # 0: it ends with its connection
    subscriptions: list[str] = field(default_factory=list)
    unacked: dict[int, tuple[str, bytes]] = field(default_factory=dict)  # mid -> message, delivery order
    next_mid: int = 1
    transport: MemoryTransport | None = None  # its connection, if one is up

    def new_mid(self) -> int:
        mid = self.next_mid
        self.next_mid = mid % 65535 + 1
        return mid


class MemoryBroker:
    """One broker; `transport` is its TransportFactory: OutboxPublisher(..., transport_factory=broker.transport)."""

    def __init__(self) -> None:
        self.running = True
        self.refuse_connections: int | None = None  # a CONNACK reason code (0x87: not authorized)
        self.refuse_publications: int | None = None  # a PUBACK reason code for every message
        self.withhold_acks = False  # keep PUBACKs until release_acks() (or lose them with the link)
        self.received: list[BrokerMessage] = []
        self.retained: dict[str, bytes] = {}
        self.connections = 0  # CONNACKs accepted, ever
        self._sessions: dict[str, _Session] = {}
        self._withheld: list[tuple[MemoryTransport, int, Reason]] = []
        self._changed = threading.Condition()  # the one lock: the broker's state and every inbox

    # The broker's side.

    def transport(self, settings: ConnectionSettings, client_id: str, will: Will | None = None) -> MemoryTransport:
        """A TransportFactory: a client of this broker (the settings' address is not used)."""
        return MemoryTransport(self, settings, client_id, will)

    def stop(self) -> None:
        """The broker goes down: every link ends (no will: nobody is there to get it); sessions stay."""
        with self._changed:
            self.running = False
            for session in list(self._sessions.values()):
                if session.transport is not None:
                    self._end_link(session.transport, reason(0x8B), publish_will=False)
            self._changed.notify_all()

    def start(self) -> None:
        with self._changed:
            self.running = True
            self._changed.notify_all()

    def drop_links(self, *client_ids: str) -> None:
        """Cut these clients' links (none named: every one) abruptly: the wills are published, PUBACKs under way lost."""
        with self._changed:
            for session in list(self._sessions.values()):
                if session.transport is not None and (not client_ids or session.client_id in client_ids):
                    self._end_link(session.transport, reason(0x80), publish_will=True)
            self._changed.notify_all()

    def release_acks(self) -> int:
        """Send the withheld PUBACKs to the clients still connected; returns how many went."""
        with self._changed:
            withheld, self._withheld = self._withheld, []
            sent = 0
            for transport, mid, ack in withheld:
                if transport.link_up:
                    transport._post("published", mid, ack)
                    sent += 1
            self._changed.notify_all()
            return sent

    @property
    def withheld_acks(self) -> int:
        with self._changed:
            return len(self._withheld)

    def unacknowledged(self, client_id: str) -> list[tuple[str, bytes]]:
        """What the broker sent (or queued for) a client's session and has no PUBACK for yet."""
        with self._changed:
            session = self._sessions.get(client_id)
            return [] if session is None else list(session.unacked.values())

    def messages(self, topic_filter: str = "#") -> list[BrokerMessage]:
        """What the broker received on topics matching the filter, in order."""
        with self._changed:
            return [m for m in self.received if topic_matches(topic_filter, m.topic)]

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until predicate() holds, re-checked after each change of the broker and each client call."""
        with self._changed:
            return self._changed.wait_for(predicate, timeout_s)

    # What the transports call, holding the lock.

    def _connect(self, transport: MemoryTransport, clean_start: bool, expiry_s: int) -> None:
        if not self.running:
            raise ConnectionRefusedError(errno.ECONNREFUSED, "Connection refused")
        transport.link_up = True
        if self.refuse_connections is not None:
            refusal = reason(self.refuse_connections)
            transport._post("connected", refusal)
            self._end_link(transport, refusal, publish_will=False)  # the broker closes the link after a refusal
            return
        session = self._sessions.get(transport.client_id)
        if session is not None and session.transport is not None:  # the same client id again: take over
            self._end_link(session.transport, reason(0x8E), publish_will=True)
            session = self._sessions.get(transport.client_id)
        if session is None or clean_start:
            session = _Session(transport.client_id, expiry_s)
            self._sessions[transport.client_id] = session
        session.expiry_s = expiry_s
        session.transport = transport
        transport.session = session
        self.connections += 1
        transport._post("connected", SUCCESS)
        for mid, (topic, payload) in session.unacked.items():  # a resumed session: what is unacknowledged goes again
            transport._post("message", topic, payload, mid)

    def _publish(self, transport: MemoryTransport, mid: int, topic: str, payload: bytes, retain: bool) -> None:
        if self.refuse_publications is not None:
            refusal = reason(self.refuse_publications)
            transport._post("published", mid, refusal)
            return
        matched = self._route(BrokerMessage(topic, payload, retain, transport.client_id))
        ack = SUCCESS if matched else reason(0x10)
        if self.withhold_acks:
            self._withheld.append((transport, mid, ack))
        else:
            transport._post("published", mid, ack)

    def _route(self, message: BrokerMessage) -> bool:
        """Keep and forward a message; False if no subscription matched it."""
        self.received.append(message)
        if message.retain:
            if message.payload:
                self.retained[message.topic] = message.payload
            else:
                self.retained.pop(message.topic, None)
        matched = False
        for session in self._sessions.values():
            if any(topic_matches(s, message.topic) for s in session.subscriptions):
                self._deliver(session, message.topic, message.payload)
                matched = True
        return matched

    def _deliver(self, session: _Session, topic: str, payload: bytes) -> None:
        mid = session.new_mid()
        session.unacked[mid] = (topic, payload)
        if session.transport is not None:
            session.transport._post("message", topic, payload, mid)

    def _subscribe(self, transport: MemoryTransport, topics: Sequence[str]) -> None:
        session = transport.session
        assert session is not None
        for pattern in topics:
            if pattern not in session.subscriptions:
                session.subscriptions.append(pattern)
        transport._post("subscribed", [GRANTED_QOS_1] * len(topics))
        for topic, payload in self.retained.items():
            if any(topic_matches(p, topic) for p in topics):
                self._deliver(session, topic, payload)

    def _acknowledge(self, transport: MemoryTransport, mid: int) -> None:
        if transport.session is not None and transport.session.transport is transport:
            transport.session.unacked.pop(mid, None)

    def _end_link(self, transport: MemoryTransport, why: Reason, publish_will: bool, from_client: bool = False) -> None:
        """The link of a transport ends: a clean disconnect (from_client), or the broker's doing."""
        if not transport.link_up:
            return
        transport.link_up = False
        self._withheld = [w for w in self._withheld if w[0] is not transport]
        session = transport.session
        if session is not None and session.transport is transport:
            session.transport = None
            if session.expiry_s == 0:
                del self._sessions[session.client_id]
        if not from_client:
            transport._post("disconnected", why, None)
        if publish_will and transport.will is not None:
            self._route(BrokerMessage(transport.will.topic, transport.will.payload.encode(), True, ""))


class MemoryTransport(MqttTransport):
    """A client of a MemoryBroker; its events wait in its inbox until loop()."""

    def __init__(self, broker: MemoryBroker, settings: ConnectionSettings, client_id: str, will: Will | None = None) -> None:
        self.broker = broker
        self.settings = settings
        self.client_id = client_id
        self.will = will
        self.link_up = False
        self.session: _Session | None = None
        self._events: TransportEvents | None = None
        self._inbox: list[tuple[str, tuple[object, ...]]] = []  # (the TransportEvents method, its arguments)
        self._next_mid = 1

    def connect(self, events: TransportEvents, clean_start: bool, session_expiry_s: int | None = None) -> None:
        with self.broker._changed:
            self._events = events
            try:
                self.broker._connect(self, clean_start, session_expiry_s or 0)
            finally:
                self.broker._changed.notify_all()

    def loop(self, timeout_s: float) -> str | None:
        changed = self.broker._changed
        with changed:
            changed.notify_all()  # the caller's previous turn is over: a waiting test may look again
            changed.wait_for(lambda: bool(self._inbox) or not self.link_up, timeout_s)  # a dead link returns at once
            inbox, self._inbox = self._inbox, []
            link_up = self.link_up
        assert self._events is not None, "connect() first"
        for name, args in inbox:  # outside the lock: a handler may call back (subscribe, acknowledge)
            getattr(self._events, name)(*args)
        return None if link_up else LINK_LOST

    def publish(self, topic: str, payload: str | bytes, retain: bool = False) -> Publication:
        body = payload.encode() if isinstance(payload, str) else bytes(payload)
        with self.broker._changed:
            mid = self._next_mid
            self._next_mid = mid % 65535 + 1
            if not self.link_up:
                return Publication(mid, NOT_CONNECTED)
            self.broker._publish(self, mid, topic, body, retain)
            self.broker._changed.notify_all()
            return Publication(mid)

    def subscribe(self, topics: Sequence[str]) -> None:
        with self.broker._changed:
            if self.link_up:
                self.broker._subscribe(self, list(topics))
                self.broker._changed.notify_all()

    def acknowledge(self, mid: int) -> None:
        with self.broker._changed:
            self.broker._acknowledge(self, mid)
            self.broker._changed.notify_all()

    def disconnect(self) -> None:
        with self.broker._changed:
            self.broker._end_link(self, SUCCESS, publish_will=False, from_client=True)
            self.broker._changed.notify_all()

    def _post(self, event: str, *args: object) -> None:
        """Queue an event (a TransportEvents method's name and arguments) for loop(); the broker's lock is held."""
        self._inbox.append((event, args))
