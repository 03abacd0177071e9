"""What the delivery tests share: events committed as the monitor commits them, a publisher and a
back-office listener run as context managers over any transport, and the checks of what arrived.

Waits have generous deadlines as safety nets; no test asserts a duration.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.listener import Listener
from bogiemon.daemon.delivery.paho_transport import paho_transport
from bogiemon.daemon.delivery.publisher import OutboxPublisher, PublisherSettings
from bogiemon.daemon.messages import OutboxStatus, StatusMessage
from bogiemon.daemon.delivery.transport import TransportFactory
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.store import EventStore
from bogiemon.daemon.outbox import OutboxCounts
from tests.judgement.event_examples import event_of

WAGON = "318045331234"
PREFIX = "fleet/test"
DEADLINE_S = 20.0  # a safety net for waits, never a measured figure
KINDS = [EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.SENSOR_FAULT, EventKind.SENSOR_CLEARED, EventKind.CLEARED]


def wait_until(predicate: Callable[[], bool], deadline_s: float = DEADLINE_S) -> bool:
    """For what a real broker's threads and processes change, which nothing here can await."""
    end_s = time.monotonic() + deadline_s
    while time.monotonic() < end_s:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def make_events(n: int, start_s: float = 1.7e9) -> list[Event]:
    kinds = [KINDS[i % len(KINDS)] for i in range(n)]
    return [event_of(k, start_s + 10 * i, {"i4_norm": 0.2 + i / 1000}) for i, k in enumerate(kinds)]


def commit(store: EventStore, events: list[Event], publisher: OutboxPublisher | None = None) -> None:
    """As the monitor does: commit, then tell the sinks (the publisher's wake-up)."""
    for event in events:
        store.append([event])
        if publisher is not None:
            publisher.wake()


def stub_status(outbox: OutboxCounts, time_s: float) -> StatusMessage:
    return StatusMessage(
        wagon_id=WAGON, time_s=time_s, mode="normal", config_hash="c0ffee", window=None, counters={"windows": 1},
        outbox=OutboxStatus(**{k: getattr(outbox, k) for k in OutboxStatus.model_fields}),
    )  # fmt: skip


def settings(connection: ConnectionSettings, **overrides: object) -> PublisherSettings:
    base: dict[str, object] = dict(
        connection=connection, wagon_id=WAGON, topic_prefix=PREFIX, status_period_s=0.0, max_rate_msgs_per_s=1000.0,
        max_inflight=20, backoff_min_s=0.1, backoff_max_s=0.5, poll_s=0.05,
    )  # fmt: skip
    base.update(overrides)
    return PublisherSettings(**base)  # type: ignore[arg-type]


@contextmanager
def publishing(
    state_dir: Path, publisher_settings: PublisherSettings, status: bool = False, transport: TransportFactory = paho_transport
) -> Iterator[OutboxPublisher]:
    publisher = OutboxPublisher(publisher_settings, state_dir, status_source=stub_status if status else None, transport_factory=transport)
    publisher.start()
    try:
        yield publisher
    finally:
        publisher.stop()


@contextmanager
def running(listener: Listener) -> Iterator[Listener]:
    """The listener in a thread, subscribed when this yields; what it raised fails the test."""
    stop = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            listener.run(stop)
        except BaseException as exc:  # surfaced by the test below
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    assert listener.subscribed.wait(DEADLINE_S), errors
    try:
        yield listener
    finally:
        stop.set()
        thread.join(DEADLINE_S)
    assert not errors, errors


@contextmanager
def listening(connection: ConnectionSettings, client_id: str = "back-office", transport: TransportFactory = paho_transport) -> Iterator[Listener]:
    """A back-office listener in a thread, subscribed when this yields; what it raised fails the test."""
    listener = Listener(connection, prefix=PREFIX, client_id=client_id, backoff_min_s=0.1, backoff_max_s=0.5, transport_factory=transport)
    with running(listener):
        yield listener


def assert_all_in_order(listener: Listener, committed: list[Event], until: Callable[[Callable[[], bool]], bool] = wait_until) -> None:
    """Every committed event kept once, in commit order (until: how to wait for them to arrive)."""
    assert until(lambda: len(listener.events) >= len(committed)), f"{len(listener.events)} of {len(committed)} arrived"
    kept = [m for m in listener.events if m.wagon_id == WAGON]
    assert [m.event_id for m in kept] == [e.event_id for e in committed]  # all, once each, in commit order
    assert [m.seq for m in kept] == sorted(m.seq for m in kept)


def mqtt_logs(logs: Sequence[Mapping[str, Any]], state: str) -> list[Mapping[str, Any]]:
    return [entry for entry in logs if entry.get("event") == f"mqtt {state}"]
