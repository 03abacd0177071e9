"""The outbox publisher's logic on the in-memory broker: order, PUBACKs, resends, the bound, the log.

The broker (daemon/delivery/memory_transport.py) fails on demand and counts every copy it gets, so
these cases assert exact numbers: what was in flight at a cut goes again, and nothing else does.
Every wait is on the broker's condition (re-checked after each client's turn), with a deadline as
a safety net. What needs a real broker (TLS, credentials, a broker process restarted, a daemon
killed) is in test_mqtt_broker_real.py.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
import structlog.testing

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.memory_transport import MemoryBroker
from bogiemon.daemon.delivery import publisher as publisher_module
from bogiemon.daemon.delivery.publisher import TokenBucket
from bogiemon.daemon.messages import EventMessage, Topics
from bogiemon.daemon.outbox import Outbox
from bogiemon.daemon.store import EventStore, StoreWriteError
from tests.daemon.delivery.support import (
    DEADLINE_S,
    PREFIX,
    WAGON,
    assert_all_in_order,
    commit,
    listening,
    make_events,
    mqtt_logs,
    publishing,
    settings,
)

LINK = ConnectionSettings("broker.example", 8883, connect_timeout_s=2.0)  # the memory broker does not use the address
TOPICS = Topics(PREFIX, WAGON)
CLIENT_ID = f"bogiemon-{WAGON}"


def waiter(broker: MemoryBroker) -> Callable[[Callable[[], bool]], bool]:
    return lambda predicate: broker.wait_for(predicate, DEADLINE_S)


def payloads(broker: MemoryBroker, topic: str) -> list[bytes]:
    return [m.payload for m in broker.messages(topic)]


def event_ids(broker: MemoryBroker) -> list[str]:
    """The event_id of every event message the broker got, resends included, in arrival order."""
    return [EventMessage.model_validate_json(p).event_id for p in payloads(broker, TOPICS.events)]


def test_every_event_goes_once_in_commit_order_and_is_marked_delivered_by_its_puback(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = EventStore(tmp_path / "state")
    committed = make_events(30)
    with listening(LINK, transport=memory_broker.transport) as listener:
        with publishing(tmp_path / "state", settings(LINK), transport=memory_broker.transport) as publisher:
            for batch in (committed[:10], committed[10:25], committed[25:]):
                commit(store, batch, publisher)
            assert_all_in_order(listener, committed, until=waiter(memory_broker))
            assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
            assert memory_broker.retained[TOPICS.state] == b"online"
        assert [m.to_event() for m in listener.events] == committed  # every field survives the trip
    assert len(memory_broker.messages(TOPICS.events)) == 30 and listener.duplicates == 0  # no resend without a loss
    assert payloads(memory_broker, TOPICS.state) == [b"online", b"offline"]  # "offline" at a clean stop
    assert (publisher.counters.connections, publisher.counters.published, publisher.counters.delivered_events) == (1, 30, 30)


def test_an_event_stays_pending_until_its_puback_arrives(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = EventStore(tmp_path / "state")
    memory_broker.withhold_acks = True
    with publishing(tmp_path / "state", settings(LINK), transport=memory_broker.transport) as publisher:
        commit(store, make_events(3), publisher)
        assert memory_broker.wait_for(lambda: memory_broker.withheld_acks == 4, DEADLINE_S)  # three events and "online"
        assert store.outbox.counts().pending_events == 3 and publisher.counters.delivered_events == 0  # sent is not delivered
        assert memory_broker.release_acks() == 4
        assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
    assert publisher.counters.published == 3 and publisher.counters.delivered_events == 3


def test_a_link_cut_mid_burst_resends_exactly_what_was_unacknowledged(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    store = EventStore(tmp_path / "state")
    committed = make_events(30)
    memory_broker.withhold_acks = True  # the PUBACKs of what is in flight when the link goes are lost with it
    with listening(LINK, transport=memory_broker.transport) as listener:
        with publishing(tmp_path / "state", settings(LINK, max_inflight=10), transport=memory_broker.transport) as publisher:
            commit(store, committed, publisher)
            assert memory_broker.wait_for(lambda: memory_broker.withheld_acks == 11, DEADLINE_S)  # 10 events and "online"
            assert len(memory_broker.messages(TOPICS.events)) == 10  # no more than max_inflight without a PUBACK
            memory_broker.withhold_acks = False
            memory_broker.drop_links(CLIENT_ID)  # the wagon's link only: the back office stays connected
            assert_all_in_order(listener, committed, until=waiter(memory_broker))
            assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
        assert listener.duplicates == 10  # the ten in flight at the cut, once more each, dropped by event_id
    sent = [m.payload for m in memory_broker.messages(TOPICS.events)]
    assert len(sent) == 40 and sent[10:20] == sent[:10]  # after the cut the backlog starts again at the oldest pending
    assert payloads(memory_broker, TOPICS.state) == [b"online", b"offline", b"online", b"offline"]  # the will, then a new session
    assert (publisher.counters.connections, publisher.counters.connections_lost, publisher.counters.published) == (2, 1, 40)


def test_an_unreachable_broker_is_a_warning_logged_once_and_the_backlog_waits_for_it(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    memory_broker.stop()
    store = EventStore(tmp_path / "state")
    committed = make_events(12)
    with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(LINK, backoff_min_s=0.02, backoff_max_s=0.05), transport=memory_broker.transport) as publisher:
        commit(store, committed, publisher)
        assert memory_broker.wait_for(lambda: publisher.counters.connect_failures >= 3, DEADLINE_S)
        assert store.outbox.counts().pending_events == 12 and memory_broker.received == []
        memory_broker.start()
        assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
    failing = mqtt_logs(logs, "failing")
    assert [(entry["log_level"], entry["reason"]) for entry in failing] == [
        ("warning", "connection refused by broker.example:8883: is the broker running and listening there?")
    ]
    assert len(mqtt_logs(logs, "connected")) == 1
    assert event_ids(memory_broker) == [e.event_id for e in committed]  # oldest first, each once


def test_refused_credentials_are_an_error_logged_once_until_the_broker_accepts(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    memory_broker.refuse_connections = 0x86  # bad user name or password
    store = EventStore(tmp_path / "state")
    committed = make_events(5)
    with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(LINK, backoff_min_s=0.02, backoff_max_s=0.05), transport=memory_broker.transport) as publisher:
        commit(store, committed, publisher)
        assert memory_broker.wait_for(lambda: publisher.counters.connect_failures >= 4, DEADLINE_S)
        assert publisher.counters.connections == 0 and store.outbox.counts().pending_events == 5
        memory_broker.refuse_connections = None
        assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
    failing = mqtt_logs(logs, "failing")
    assert [(entry["log_level"], entry["reason"]) for entry in failing] == [
        ("error", "the broker refused the credentials (Bad user name or password): check mqtt.username_file and mqtt.password_file")
    ]
    assert publisher.counters.connections == 1 and publisher.counters.delivered_events == 5


def test_a_message_the_broker_refuses_stays_pending_and_ends_the_session(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    memory_broker.refuse_publications = 0x87  # not authorized: the broker's ACL
    store = EventStore(tmp_path / "state")
    committed = make_events(3)
    with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(LINK, backoff_min_s=0.02, backoff_max_s=0.05), transport=memory_broker.transport) as publisher:
        commit(store, committed, publisher)
        assert memory_broker.wait_for(lambda: publisher.counters.connections_lost >= 2, DEADLINE_S)
        assert store.outbox.counts().pending_events == 3 and publisher.counters.delivered_events == 0
        memory_broker.stop()  # the ACL fixed during a restart, so that no session straddles the change
        memory_broker.refuse_publications = None
        memory_broker.start()
        assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
    refusals = [entry for entry in mqtt_logs(logs, "lost") if "refused a message" in str(entry["reason"])]
    assert len(refusals) >= 2 and {(entry["log_level"], entry["reason"]) for entry in refusals} == {
        ("warning", f"the broker refused a message (Not authorized): check its ACL for {PREFIX}/{WAGON}/#")  # each session: connected, then lost
    }
    assert publisher.counters.refused >= 2 * 3  # each session offered the three, oldest first, and was refused
    assert event_ids(memory_broker) == [e.event_id for e in committed]  # what the broker took: each once, in order


def test_outbox_full_drops_the_oldest_status_first_and_keeps_every_event(tmp_path: Path, memory_broker: MemoryBroker) -> None:
    with listening(LINK, transport=memory_broker.transport):
        pass  # the back office's session exists: the broker queues for it while it is away
    memory_broker.stop()
    store = EventStore(tmp_path / "state")
    committed = make_events(8)
    bound = 20
    low = settings(LINK, outbox_max_messages=bound, status_period_s=0.02, backoff_min_s=0.2, backoff_max_s=0.2)
    with publishing(tmp_path / "state", low, status=True, transport=memory_broker.transport) as publisher:
        commit(store, committed, publisher)
        assert memory_broker.wait_for(lambda: publisher.counters.dropped_status >= 30, DEADLINE_S)
        counts = store.outbox.counts()
        assert counts.pending_events == 8 and counts.dropped_events == 0  # the events all wait
        assert counts.pending <= bound + 1  # the bound, give or take the status queued since the last trim
        dropped_before = publisher.counters.dropped_status
        memory_broker.start()
        with listening(LINK, transport=memory_broker.transport) as listener:
            assert_all_in_order(listener, committed, until=waiter(memory_broker))
            # The back office learns how many were dropped from a later status.
            assert memory_broker.wait_for(lambda: any(s.outbox.dropped_status >= dropped_before for s in listener.statuses), DEADLINE_S)
            queued_times = [s.time_s for s in listener.statuses]
    assert queued_times == sorted(queued_times)  # oldest first
    assert len(queued_times) >= bound - len(committed)  # what the bound left of the outage's status
    assert publisher.counters.dropped_events == 0


def test_the_token_bucket_allows_the_rate_and_a_burst_on_its_clock() -> None:
    bucket = TokenBucket(rate_per_s=8.0, burst=2.0, now_s=0.0)  # binary fractions: exact arithmetic
    assert [bucket.take(0.0) for _ in range(3)] == [True, True, False]  # the burst, then empty
    assert bucket.take(0.0625) is False and bucket.take(0.125) is True  # one token per 1/8 s
    sent = sum(bucket.take(1.0 + k / 64) for k in range(641))  # 10 s of asking 64 times a second
    assert sent == 2 + 80  # the refilled burst (capped), then 8 per second


def test_a_store_that_refuses_the_deliveries_is_retried_at_crit_and_nothing_is_lost(
    tmp_path: Path, memory_broker: MemoryBroker, monkeypatch: pytest.MonkeyPatch
) -> None:
    # A full disk or a read-only state directory refuses the publisher's own writes (the mark of a
    # PUBACK): the thread must not end, and what went out stays pending until it is marked.
    store = EventStore(tmp_path / "state")
    refusals = {"left": 2}
    mark = Outbox.mark_delivered

    def refusing(self: Outbox, *args: object) -> None:
        if refusals["left"] > 0:
            refusals["left"] -= 1
            raise StoreWriteError(f"{self.store.path}: cannot commit to the event store: database or disk is full")
        mark(self, *args)  # type: ignore[arg-type]

    monkeypatch.setattr(Outbox, "mark_delivered", refusing)
    monkeypatch.setattr(publisher_module, "STORE_RETRY_S", 0.05)
    committed = make_events(3)
    with structlog.testing.capture_logs() as logs, listening(LINK, transport=memory_broker.transport) as listener:
        with publishing(tmp_path / "state", settings(LINK), transport=memory_broker.transport) as publisher:
            commit(store, committed, publisher)
            assert memory_broker.wait_for(lambda: store.outbox.counts().pending_events == 0, DEADLINE_S)
            assert publisher.is_alive() and publisher.error is None
        assert [m.to_event() for m in listener.events] == committed  # copies sent again are dropped by event_id
    assert publisher.counters.store_failures == 2
    crit = [e for e in logs if e["event"].startswith("mqtt delivery cannot write to the event store")]
    assert [e["log_level"] for e in crit] == ["critical", "critical"]
