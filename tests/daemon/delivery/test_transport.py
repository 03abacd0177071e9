"""The transport contract, run on both transports: the in-memory broker must behave as mosquitto does.

Each case drives transports from the test's thread (loop() until the awaited event arrives, with
a deadline as a safety net) against the MemoryBroker and against a real mosquitto through paho,
so the double the publisher's and the listener's tests rely on is checked against the real thing.
"""

from __future__ import annotations

import signal
import socket
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import pytest

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.memory_transport import MemoryBroker, MemoryTransport, topic_matches
from bogiemon.daemon.delivery.paho_transport import PahoTransport, paho_transport
from bogiemon.daemon.delivery.transport import MqttTransport, Reason, TransportEvents, TransportFactory, Will
from tests.daemon.delivery.mqtt_broker import Broker, free_port, make_password_file
from tests.daemon.delivery.support import DEADLINE_S, wait_until

SESSION_S = 600


class Recorder(TransportEvents):
    """Every event, by kind, in order of arrival."""

    def __init__(self) -> None:
        self.connacks: list[int] = []  # reason codes
        self.disconnects = 0
        self.pubacks: list[tuple[int, int]] = []  # (mid, reason code)
        self.subacks: list[list[int]] = []
        self.messages: list[tuple[str, bytes, int]] = []  # (topic, payload, mid)

    def connected(self, reason: Reason) -> None:
        self.connacks.append(reason.value)

    def disconnected(self, reason: Reason, detail: str | None) -> None:
        self.disconnects += 1

    def published(self, mid: int, reason: Reason) -> None:
        self.pubacks.append((mid, reason.value))

    def subscribed(self, reasons: Sequence[Reason]) -> None:
        self.subacks.append([r.value for r in reasons])

    def message(self, topic: str, payload: bytes, mid: int) -> None:
        self.messages.append((topic, payload, mid))

    def received(self) -> list[tuple[str, bytes]]:
        return [(topic, payload) for topic, payload, _ in self.messages]


@dataclass
class Side:
    """One broker and how to reach it, cut a client's link, and make it refuse a connection."""

    factory: TransportFactory
    connection: ConnectionSettings
    cut: Callable[[MqttTransport], None]
    refusing: Callable[[], ConnectionSettings]  # settings of a broker that refuses this client
    nowhere: Callable[[], tuple[TransportFactory, ConnectionSettings]]  # no broker at all


@pytest.fixture(params=["memory", "mosquitto"])
def side(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Side]:
    if request.param == "memory":
        broker = MemoryBroker()
        link = ConnectionSettings("broker.example", 1883)

        def refuse() -> ConnectionSettings:
            broker.refuse_connections = 0x87
            return link

        def nowhere() -> tuple[TransportFactory, ConnectionSettings]:
            down = MemoryBroker()
            down.stop()
            return down.transport, link

        def cut_memory(transport: MqttTransport) -> None:
            assert isinstance(transport, MemoryTransport)
            broker.drop_links(transport.client_id)

        yield Side(broker.transport, link, cut_memory, refuse, nowhere)
        return
    request.getfixturevalue("mosquitto")
    brokers = [Broker(tmp_path / "broker").start()]

    def cut(transport: MqttTransport) -> None:
        assert isinstance(transport, PahoTransport)
        sock = transport.client.socket()
        assert isinstance(sock, socket.socket)
        sock.shutdown(socket.SHUT_RDWR)  # the link dies without a DISCONNECT

    def refuse_real() -> ConnectionSettings:
        guarded = Broker(tmp_path / "guarded", password_file=make_password_file(tmp_path / "passwords", "office", "Pa55")).start()
        brokers.append(guarded)
        return ConnectionSettings("127.0.0.1", guarded.port, connect_timeout_s=2.0)  # anonymous: refused

    def nowhere_real() -> tuple[TransportFactory, ConnectionSettings]:
        return paho_transport, ConnectionSettings("127.0.0.1", free_port(), connect_timeout_s=2.0)

    try:
        yield Side(paho_transport, ConnectionSettings("127.0.0.1", brokers[0].port, connect_timeout_s=2.0), cut, refuse_real, nowhere_real)
    finally:
        for b in brokers:
            b.kill(signal.SIGTERM)


def pump(until: Callable[[], bool], *transports: MqttTransport) -> bool:
    """Drive the transports' I/O until the condition holds (False at the deadline)."""

    def turn() -> bool:
        for transport in transports:
            transport.loop(0.01)
        return until()

    return wait_until(turn, DEADLINE_S)


def client(side: Side, client_id: str, clean_start: bool = True, will: Will | None = None) -> tuple[MqttTransport, Recorder]:
    transport, events = side.factory(side.connection, client_id, will), Recorder()
    transport.connect(events, clean_start=clean_start, session_expiry_s=None if clean_start else SESSION_S)
    assert pump(lambda: bool(events.connacks), transport)
    assert events.connacks == [0]
    return transport, events


def subscriber(side: Side, client_id: str, clean_start: bool = True) -> tuple[MqttTransport, Recorder]:
    transport, events = client(side, client_id, clean_start)
    transport.subscribe(["t/#"])
    assert pump(lambda: bool(events.subacks), transport)
    assert events.subacks == [[1]]  # granted QoS 1
    return transport, events


def test_no_broker_is_an_oserror_from_connect(side: Side) -> None:
    factory, connection = side.nowhere()
    with pytest.raises(ConnectionRefusedError):
        factory(connection, "wagon", None).connect(Recorder(), clean_start=True)


def test_a_refused_connection_is_a_connack_with_an_authorisation_failure(side: Side) -> None:
    transport, events = side.factory(side.refusing(), "wagon", None), Recorder()
    transport.connect(events, clean_start=True)
    assert pump(lambda: bool(events.connacks), transport)
    assert events.connacks == [0x87]  # not authorized (mosquitto: anonymous clients are not allowed)
    transport.disconnect()


def test_a_publication_is_acknowledged_under_its_mid_and_reaches_the_subscriber(side: Side) -> None:
    sub, sub_events = subscriber(side, "office")
    pub, pub_events = client(side, "wagon")
    sent = pub.publish("t/a", b"one")
    assert sent.error is None
    assert pump(lambda: bool(pub_events.pubacks) and bool(sub_events.messages), pub, sub)
    assert pub_events.pubacks == [(sent.mid, 0)]
    assert sub_events.received() == [("t/a", b"one")]
    pub.disconnect()
    sub.disconnect()


def test_a_retained_message_reaches_a_later_subscriber(side: Side) -> None:
    pub, pub_events = client(side, "wagon")
    sent = pub.publish("t/state", "online", retain=True)
    assert pump(lambda: bool(pub_events.pubacks), pub)
    assert pub_events.pubacks == [(sent.mid, 0x10)]  # no matching subscribers: kept, not refused
    sub, sub_events = subscriber(side, "office")
    assert pump(lambda: bool(sub_events.messages), sub)
    assert sub_events.received() == [("t/state", b"online")]
    pub.disconnect()
    sub.disconnect()


def test_a_kept_session_gets_again_what_it_did_not_acknowledge_and_what_came_while_it_was_away(side: Side) -> None:
    sub, sub_events = subscriber(side, "office", clean_start=False)
    pub, pub_events = client(side, "wagon")
    pub.publish("t/1", b"first")
    assert pump(lambda: bool(sub_events.messages), pub, sub)  # received, never acknowledged
    sub.disconnect()
    pub.publish("t/2", b"second")
    assert pump(lambda: len(pub_events.pubacks) == 2, pub)
    again, again_events = side.factory(side.connection, "office", None), Recorder()
    again.connect(again_events, clean_start=False, session_expiry_s=SESSION_S)
    assert pump(lambda: len(again_events.messages) == 2, again)
    assert again_events.received() == [("t/1", b"first"), ("t/2", b"second")]
    for _, _, mid in again_events.messages:
        again.acknowledge(mid)
    pub.disconnect()
    again.disconnect()


def test_the_will_is_published_when_a_link_dies_and_not_at_a_clean_disconnect(side: Side) -> None:
    sub, sub_events = subscriber(side, "office")
    clean, _ = client(side, "wagon-1", will=Will("t/wagon-1/state", "offline"))
    clean.disconnect()
    dying, dying_events = client(side, "wagon-2", will=Will("t/wagon-2/state", "offline"))
    side.cut(dying)
    assert pump(lambda: bool(sub_events.messages) and dying_events.disconnects == 1, sub, dying)
    assert sub_events.received() == [("t/wagon-2/state", b"offline")]
    sub.disconnect()


@pytest.mark.parametrize(
    ("pattern", "topic", "matches"),
    [("a/+/c", "a/b/c", True), ("a/+/c", "a/b/d", False), ("a/#", "a", True), ("a/#", "a/b/c", True), ("a/b", "a/b/c", False), ("+/+", "a", False)],
)  # fmt: skip
def test_topic_filters_match_as_mqtt_says(pattern: str, topic: str, matches: bool) -> None:
    assert topic_matches(pattern, topic) is matches
