"""The event store: real SQLite files, WAL, durable commits, state beside the events."""

import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from bogiemon.daemon.events import Event, EventKind, Severity
from bogiemon.daemon.store import EventStore, StoreError


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
