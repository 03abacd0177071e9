"""The back-office listener's logic on the in-memory broker: each event once, the session kept, the PUBACK last.

`bogiemon listen` as a real process against a real mosquitto is in test_listen.py.
"""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.listener import Listener, ListenError, Received, ReceivedStore
from bogiemon.daemon.delivery.memory_transport import MemoryBroker, MemoryTransport
from bogiemon.daemon.messages import EventMessage, Topics, dump
from bogiemon.daemon.delivery.transport import TransportEvents
from tests.daemon.delivery.support import DEADLINE_S, PREFIX, WAGON, listening, make_events

LINK = ConnectionSettings("broker.example", 8883)
TOPICS = Topics(PREFIX, WAGON)


def wagon(broker: MemoryBroker) -> MemoryTransport:
    """A wagon's connection, driven from the test's thread; its PUBACKs are not awaited."""
    transport = broker.transport(LINK, f"bogiemon-{WAGON}")
    transport.connect(TransportEvents(), clean_start=True)
    transport.loop(0.0)  # the CONNACK
    return transport


def messages(n: int) -> list[EventMessage]:
    return [EventMessage.from_event(WAGON, seq, e) for seq, e in enumerate(make_events(n), start=1)]


def test_each_event_is_kept_once_and_copies_and_invalid_messages_are_counted(memory_broker: MemoryBroker) -> None:
    events = messages(2)
    with listening(LINK, transport=memory_broker.transport) as listener:
        sender = wagon(memory_broker)
        for payload in (dump(events[0]), dump(events[0]), "not json", dump(events[1])):
            sender.publish(TOPICS.events, payload)
        sender.publish(TOPICS.state, "online", retain=True)
        assert memory_broker.wait_for(lambda: listener.states.get(WAGON) == "online", DEADLINE_S)
    assert listener.events == events
    assert (listener.duplicates, listener.invalid) == (1, 1)


def test_what_is_published_while_the_listener_is_away_arrives_when_it_returns(memory_broker: MemoryBroker) -> None:
    events = messages(3)
    with listening(LINK, transport=memory_broker.transport):
        pass  # the session exists now, kept by the broker under the listener's client id
    sender = wagon(memory_broker)
    for event in events:
        sender.publish(TOPICS.events, dump(event))
    sender.publish(TOPICS.state, "offline", retain=True)
    with listening(LINK, transport=memory_broker.transport) as listener:
        assert memory_broker.wait_for(lambda: len(listener.events) == 3 and WAGON in listener.states, DEADLINE_S)
    assert listener.events == events and listener.states == {WAGON: "offline"}
    assert memory_broker.unacknowledged("back-office") == []


def test_a_kept_event_is_committed_to_the_store_before_the_broker_gets_its_puback(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    event = messages(1)[0]
    store = ReceivedStore(tmp_path / "received.sqlite3")
    seen_at_arrival: list[tuple[list[str], int]] = []

    def on_message(received: Received) -> None:  # called once the event is kept, before the acknowledgement
        seen_at_arrival.append((ReceivedStore(store.path).event_ids(), len(memory_broker.unacknowledged("office"))))

    listener = Listener(LINK, prefix=PREFIX, client_id="office", store=store, on_message=on_message, transport_factory=memory_broker.transport)
    stop = threading.Event()
    thread = threading.Thread(target=listener.run, args=(stop,), kwargs={"max_events": 1}, daemon=True)
    thread.start()
    assert listener.subscribed.wait(DEADLINE_S)
    wagon(memory_broker).publish(TOPICS.events, dump(event))
    thread.join(DEADLINE_S)
    assert seen_at_arrival == [([event.event_id], 1)]  # in the store, and still unacknowledged
    assert memory_broker.unacknowledged("office") == [] and store.event_ids() == [event.event_id]


def test_refused_credentials_end_the_listener_with_one_line(memory_broker: MemoryBroker) -> None:
    memory_broker.refuse_connections = 0x87
    listener = Listener(LINK, prefix=PREFIX, transport_factory=memory_broker.transport)
    with pytest.raises(ListenError) as error:
        listener.run(threading.Event())
    assert str(error.value) == "the broker refused the credentials (Not authorized): check --username-file and --password-file"


def test_a_lost_link_is_said_once_and_the_listener_reconnects(memory_broker: MemoryBroker) -> None:
    lines: list[str] = []
    listener = Listener(LINK, prefix=PREFIX, client_id="office", on_link=lines.append, backoff_min_s=0.01, backoff_max_s=0.02,
                        transport_factory=memory_broker.transport)  # fmt: skip
    stop = threading.Event()
    thread = threading.Thread(target=listener.run, args=(stop,), daemon=True)
    thread.start()
    try:
        assert listener.subscribed.wait(DEADLINE_S)
        memory_broker.drop_links("office")
        assert memory_broker.wait_for(lambda: len(lines) == 3 and listener.subscribed.is_set(), DEADLINE_S)
    finally:
        stop.set()
        thread.join(DEADLINE_S)
    connected = f"connected to broker.example:8883, subscribed to {PREFIX}/+/events, status, state"
    assert lines == [connected, "failing: connection lost: Unspecified error", connected]
