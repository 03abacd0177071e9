"""The event store: real SQLite files, WAL, durable commits, state beside the events."""

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from bogiemon.daemon.events import Event, EventKind, Severity
from bogiemon.daemon.store import EventStore, OutboxCounts, StoreError


def event(t: float, kind: EventKind = EventKind.SUSPECTED) -> Event:
    return Event(time_s=t, kind=kind, severity=Severity.WARNING, config_hash="c0ffee", indicators={"i4_norm": 0.3}, details={"load": "full"})


def test_events_round_trip_in_commit_order(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    sent = [event(30.0), event(10.0, EventKind.CONFIRMED), event(20.0)]
    store.append(sent[:1])
    store.append(sent[1:])
    assert store.events() == sent
    assert store.events(since_s=20.0) == [sent[0], sent[2]]
    assert store.count() == 3


def test_the_database_is_in_wal_mode_with_full_sync(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    assert store._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store._db.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL


def test_state_is_committed_with_the_events(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    store.append([event(1.0)], state={"monitor": {"mode": "suspected"}})
    store.close()
    again = EventStore(tmp_path)
    assert again.get_state("monitor") == {"mode": "suspected"}
    assert again.get_state("missing") is None


def test_a_failed_transaction_leaves_nothing(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    first = event(1.0)
    store.append([first])
    with pytest.raises(sqlite3.IntegrityError):
        store.append([event(2.0), first])  # the duplicate id aborts the whole batch
    assert store.events() == [first]


def test_committed_events_survive_a_killed_writer(tmp_path: Path) -> None:
    code = (
        "import os, sys\n"
        "from bogiemon.daemon.store import EventStore\n"
        "from bogiemon.daemon.events import Event, EventKind, Severity\n"
        "s = EventStore(sys.argv[1])\n"
        "for i in range(50):\n"
        "    s.append([Event(time_s=i, kind=EventKind.SUSPECTED, severity=Severity.WARNING, config_hash='x', event_id=str(i))])\n"
        "    print(i, flush=True)\n"
        "os.kill(os.getpid(), 9)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == -9
    reported = proc.stdout.split()
    assert [e.event_id for e in EventStore(tmp_path).events()] == reported


def test_a_read_only_open_of_a_missing_store_says_so(tmp_path: Path) -> None:
    with pytest.raises(StoreError, match="no event store here yet"):
        EventStore(tmp_path / "nowhere", readonly=True)


def test_an_unwritable_state_directory_is_named(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    with pytest.raises(StoreError, match="cannot open the event store"):
        EventStore(blocker / "sub")


# Schema 2: the store is the outbox of alarm delivery.

_V1_SCHEMA = """
CREATE TABLE events (seq INTEGER PRIMARY KEY AUTOINCREMENT, event_id TEXT NOT NULL UNIQUE, time_s REAL NOT NULL,
    kind TEXT NOT NULL, severity TEXT NOT NULL, config_hash TEXT NOT NULL, body TEXT NOT NULL);
CREATE INDEX events_time ON events (time_s);
CREATE TABLE state (key TEXT PRIMARY KEY, value TEXT NOT NULL);
PRAGMA user_version=1;
"""


def test_a_version_1_file_migrates_to_2_with_its_events_pending(tmp_path: Path) -> None:
    old = event(5.0, EventKind.CONFIRMED)
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.executescript(_V1_SCHEMA)
    db.execute(
        "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
        (old.event_id, old.time_s, old.kind.value, old.severity.value, old.config_hash, json.dumps(old.as_dict())),
    )
    db.commit()
    db.close()
    store = EventStore(tmp_path)
    assert store.schema_version == 2
    assert store.events() == [old]
    assert [p.event for p in store.pending_events()] == [old]
    assert store.outbox_counts() == OutboxCounts(pending_events=1, pending_alarms=1, pending_status=0, dropped_events=0, dropped_status=0)


def test_a_store_of_a_newer_schema_is_refused(tmp_path: Path) -> None:
    EventStore(tmp_path).close()
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.execute("PRAGMA user_version=3")
    db.close()
    with pytest.raises(StoreError, match=r"written by a newer bogiemon \(schema 3 > 2\)"):
        EventStore(tmp_path)


def test_pending_events_go_oldest_first_until_marked_delivered_and_that_is_durable(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    sent = [event(float(i)) for i in range(5)]
    store.append(sent)
    pending = store.pending_events()
    assert [p.event for p in pending] == sent
    assert [p.seq for p in pending] == sorted(p.seq for p in pending)
    assert [p.event for p in store.pending_events(after_seq=pending[1].seq, limit=2)] == sent[2:4]
    store.mark_delivered([pending[0].seq, pending[2].seq], [], delivered_s=100.0)
    store.close()
    again = EventStore(tmp_path)
    assert [p.event for p in again.pending_events()] == [sent[1], sent[3], sent[4]]
    assert again.events() == sent  # delivery never removes an event from the store


def test_status_records_wait_in_order_and_go_once_delivered(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    seqs = [store.queue_status(float(i), f'{{"n": {i}}}') for i in range(3)]
    assert [(s.time_s, s.body) for s in store.pending_status()] == [(0.0, '{"n": 0}'), (1.0, '{"n": 1}'), (2.0, '{"n": 2}')]
    store.mark_delivered([], seqs[:2], delivered_s=10.0)
    assert [s.seq for s in store.pending_status()] == seqs[2:]


def test_the_outbox_bound_drops_status_first_then_events_that_are_not_alarms_and_never_alarms(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    kinds = [EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.SENSOR_FAULT, EventKind.CLEARED, EventKind.SENSOR_CLEARED]
    events = [event(float(i), kind) for i, kind in enumerate(kinds)]
    store.append(events)
    status = [store.queue_status(float(i), "{}") for i in range(4)]
    assert store.trim_outbox(max_messages=9, now_s=1.0) == (0, 0)
    assert store.trim_outbox(max_messages=7, now_s=1.0) == (2, 0)  # the two oldest status records
    assert [s.seq for s in store.pending_status()] == status[2:]
    assert store.trim_outbox(max_messages=4, now_s=2.0) == (2, 1)  # all status, then the oldest non-alarm
    assert [p.event.kind for p in store.pending_events()] == kinds[1:]
    assert store.trim_outbox(max_messages=0, now_s=3.0) == (0, 2)  # the alarms stay, over the bound
    assert [p.event.kind for p in store.pending_events()] == [EventKind.CONFIRMED, EventKind.CLEARED]
    store.close()
    counts = EventStore(tmp_path).outbox_counts()  # the drop counts survive a restart
    assert counts == OutboxCounts(pending_events=2, pending_alarms=2, pending_status=0, dropped_events=3, dropped_status=4)
