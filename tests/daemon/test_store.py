"""The event store: real SQLite files, WAL, durable commits, state beside the events."""

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.event_json import event_body
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.store import EventStore, StoreError, StoreWriteError
from bogiemon.daemon.store_file import SCHEMA_VERSION
from bogiemon.daemon.outbox import OutboxCounts
from tests.judgement.event_examples import CHILD_EVENT, CHILD_IMPORTS, event_of


def event(t: float, kind: EventKind = EventKind.SUSPECTED) -> Event:
    return event_of(kind, t, {"i4_norm": 0.3})


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
    assert store.connection.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    assert store.connection.execute("PRAGMA synchronous").fetchone()[0] == 2  # FULL


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
        f"{CHILD_IMPORTS}"
        "s = EventStore(sys.argv[1])\n"
        "for i in range(50):\n"
        f"    s.append([{CHILD_EVENT.format(t='i')}])\n"
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


def test_a_version_1_file_migrates_to_the_current_version_with_its_events_pending(tmp_path: Path) -> None:
    old = event(5.0, EventKind.CONFIRMED)
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.executescript(_V1_SCHEMA)
    db.execute(
        "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
        (old.event_id, old.time_s, old.kind.value, old.severity.value, old.config_hash, json.dumps(event_body(old))),
    )
    db.commit()
    db.close()
    store = EventStore(tmp_path)
    assert store.schema_version == SCHEMA_VERSION == 3
    assert store.events() == [old]
    assert [p.event for p in store.outbox.pending_events()] == [old]
    assert store.outbox.counts() == OutboxCounts(pending_events=1, pending_alarms=1, pending_status=0, dropped_events=0, dropped_status=0)


def test_a_store_of_a_newer_schema_is_refused(tmp_path: Path) -> None:
    EventStore(tmp_path).close()
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.execute("PRAGMA user_version=4")
    db.close()
    with pytest.raises(StoreError, match=r"written by a newer bogiemon \(schema 4 > 3\)"):
        EventStore(tmp_path)


def test_a_store_whose_header_gives_a_negative_schema_version_is_refused_as_damaged(tmp_path: Path) -> None:
    # Found by make fuzz (store): a damaged header read as user_version -1 was migrated from -1.
    EventStore(tmp_path).close()
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.execute("PRAGMA user_version=-1")
    db.close()
    with pytest.raises(StoreError, match=r"the event store is damaged \(its schema version in the header reads -1\)"):
        EventStore(tmp_path)


def test_pending_events_go_oldest_first_until_marked_delivered_and_that_is_durable(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    sent = [event(float(i)) for i in range(5)]
    store.append(sent)
    pending = store.outbox.pending_events()
    assert [p.event for p in pending] == sent
    assert [p.seq for p in pending] == sorted(p.seq for p in pending)
    assert [p.event for p in store.outbox.pending_events(after_seq=pending[1].seq, limit=2)] == sent[2:4]
    store.outbox.mark_delivered([pending[0].seq, pending[2].seq], [], delivered_s=100.0)
    store.close()
    again = EventStore(tmp_path)
    assert [p.event for p in again.outbox.pending_events()] == [sent[1], sent[3], sent[4]]
    assert again.events() == sent  # delivery never removes an event from the store


def test_status_records_wait_in_order_and_go_once_delivered(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    seqs = [store.outbox.queue_status(float(i), f'{{"n": {i}}}') for i in range(3)]
    assert [(s.time_s, s.body) for s in store.outbox.pending_status()] == [(0.0, '{"n": 0}'), (1.0, '{"n": 1}'), (2.0, '{"n": 2}')]
    store.outbox.mark_delivered([], seqs[:2], delivered_s=10.0)
    assert [s.seq for s in store.outbox.pending_status()] == seqs[2:]


def test_the_outbox_bound_drops_status_first_then_events_that_are_not_alarms_and_never_alarms(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    kinds = [EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.SENSOR_FAULT, EventKind.CLEARED, EventKind.SENSOR_CLEARED]
    events = [event(float(i), kind) for i, kind in enumerate(kinds)]
    store.append(events)
    status = [store.outbox.queue_status(float(i), "{}") for i in range(4)]
    assert store.outbox.trim_outbox(max_messages=9, now_s=1.0) == (0, 0)
    assert store.outbox.trim_outbox(max_messages=7, now_s=1.0) == (2, 0)  # the two oldest status records
    assert [s.seq for s in store.outbox.pending_status()] == status[2:]
    assert store.outbox.trim_outbox(max_messages=4, now_s=2.0) == (2, 1)  # all status, then the oldest non-alarm
    assert [p.event.kind for p in store.outbox.pending_events()] == kinds[1:]
    assert store.outbox.trim_outbox(max_messages=0, now_s=3.0) == (0, 2)  # the alarms stay, over the bound
    assert [p.event.kind for p in store.outbox.pending_events()] == [EventKind.CONFIRMED, EventKind.CLEARED]
    store.close()
    counts = EventStore(tmp_path).outbox.counts()  # the drop counts survive a restart
    assert counts == OutboxCounts(pending_events=2, pending_alarms=2, pending_status=0, dropped_events=3, dropped_status=4)


# Damage, refusal and storage faults (issue 17): a store is refused with one StoreError naming the
# file and what to do, and never replaced, repaired or written to when refused.


def filled_store(path: Path, n: int = 200) -> list[Event]:
    store = EventStore(path)
    sent = [padded(event(1.7e9 + i), i) for i in range(n)]
    for e in sent:
        store.append([e], state={"monitor": {"n": e.time_s}})
    store.close()
    return sent


def padded(e: Event, i: int) -> Event:
    """e as a NOT_JUDGED with 200 bytes more of text: the rows fill pages."""
    return event_of(EventKind.NOT_JUDGED, e.time_s, e.indicators, e.config_hash, text=f"{i} " + "x" * 200, event_id=e.event_id)


@pytest.mark.parametrize("readonly", [False, True], ids=["open", "readonly"])
def test_a_zero_length_store_is_refused_not_replaced(tmp_path: Path, readonly: bool) -> None:
    (tmp_path / "events.sqlite3").write_bytes(b"")
    with pytest.raises(StoreError, match=r"events\.sqlite3: the event store is an empty file.*move it aside") as caught:
        EventStore(tmp_path, readonly=readonly)
    assert "\n" not in str(caught.value)
    assert (tmp_path / "events.sqlite3").stat().st_size == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.sqlite3"]


@pytest.mark.parametrize("page", [1, 2, 5, -1], ids=["page-2", "page-3", "page-6", "last-page"])
@pytest.mark.parametrize("damage", ["zeroed", "random"])
@pytest.mark.parametrize("readonly", [False, True], ids=["open", "readonly"])
def test_a_store_with_a_damaged_page_is_refused_at_open_and_left_untouched(tmp_path: Path, page: int, damage: str, readonly: bool) -> None:
    filled_store(tmp_path)
    path = tmp_path / "events.sqlite3"
    data = bytearray(path.read_bytes())
    start = (page % (len(data) // 4096)) * 4096
    data[start : start + 4096] = bytes(4096) if damage == "zeroed" else np.random.default_rng(start).bytes(4096)
    path.write_bytes(bytes(data))
    with pytest.raises(StoreError, match=r"events\.sqlite3: the event store is damaged \(.+\); bogiemon leaves it untouched: move it aside") as caught:
        EventStore(tmp_path, readonly=readonly)
    assert "\n" not in str(caught.value)
    assert path.read_bytes() == bytes(data)


def test_a_file_that_is_not_a_database_is_refused_as_damaged(tmp_path: Path) -> None:
    (tmp_path / "events.sqlite3").write_bytes(b"time_s,a1,a2,a3\n" * 500)
    with pytest.raises(StoreError, match=r"the event store is damaged \(file is not a database\)"):
        EventStore(tmp_path)


def test_a_store_of_a_newer_schema_is_refused_without_a_byte_written(tmp_path: Path) -> None:
    filled_store(tmp_path, n=3)
    path = tmp_path / "events.sqlite3"
    db = sqlite3.connect(path)
    db.execute("PRAGMA user_version=4")
    db.commit()
    db.close()
    before = path.read_bytes()
    for readonly in (False, True):
        with pytest.raises(StoreError, match=r"written by a newer bogiemon \(schema 4 > 3\); left untouched"):
            EventStore(tmp_path, readonly=readonly)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.sqlite3"]


def test_a_start_killed_before_its_new_store_is_in_place_leaves_no_store_and_the_next_start_makes_one(tmp_path: Path) -> None:
    code = (
        "import os, signal, sys\n"
        "os.link = lambda *a, **k: os.kill(os.getpid(), signal.SIGKILL)\n"
        "from bogiemon.daemon.store import EventStore\n"
        "EventStore(sys.argv[1])\n"
    )
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == -9
    assert not (tmp_path / "events.sqlite3").exists()  # only the scratch copy, never a half-made store
    store = EventStore(tmp_path)
    assert store.schema_version == SCHEMA_VERSION and store.events() == []


def test_a_new_store_leaves_no_scratch_file_behind(tmp_path: Path) -> None:
    EventStore(tmp_path).close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["events.sqlite3"]


def test_a_commit_the_disk_cannot_take_is_a_store_write_error_that_leaves_nothing(tmp_path: Path) -> None:
    sent = filled_store(tmp_path, n=5)
    store = EventStore(tmp_path)
    pages = store.connection.execute("PRAGMA page_count").fetchone()[0]
    store.connection.execute(f"PRAGMA max_page_count={pages}")  # SQLite's own SQLITE_FULL, as on a full disk
    burst = [padded(event(2e9 + i), i) for i in range(300)]
    with pytest.raises(StoreWriteError, match=r"events\.sqlite3: cannot commit to the event store: database or disk is full"):
        store.append(burst, state={"monitor": {"n": -1}})
    assert store.events() == sent
    assert store.get_state("monitor") == {"n": sent[-1].time_s}
    store.connection.execute(f"PRAGMA max_page_count={10 * pages}")
    store.append(burst[:1])  # the refused transaction is gone: the next one starts cleanly
    assert store.events() == [*sent, burst[0]]


def test_a_commit_on_a_store_that_turned_read_only_is_a_store_write_error_naming_it(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    store.connection.execute("PRAGMA query_only=1")  # SQLite refuses every write, as on media remounted read-only
    with pytest.raises(StoreWriteError, match=r"cannot commit to the event store: attempt to write a readonly database \(the state directory .+ is read-only"):
        store.append([event(1.0)])
    assert store.count() == 0


def test_committed_ids_names_those_already_in_the_store(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    first = event(1.0)
    store.append([first])
    assert store.committed_ids([first.event_id, "not-there"]) == {first.event_id}


def test_an_event_row_that_does_not_decode_is_a_store_error_naming_its_seq(tmp_path: Path) -> None:
    filled_store(tmp_path, n=3)
    db = sqlite3.connect(tmp_path / "events.sqlite3")
    db.execute("UPDATE events SET body = '{\"kind\": ' WHERE seq = 2")
    db.commit()
    db.close()
    with pytest.raises(StoreError, match=r"the event store is damaged \(event 2 does not decode: JSONDecodeError"):
        EventStore(tmp_path, readonly=True).events()


def test_a_killed_writer_leaves_a_store_that_opens_read_only_with_every_commit(tmp_path: Path) -> None:
    code = (
        "import os, sys\n"
        "from bogiemon.daemon.store import EventStore\n"
        f"{CHILD_IMPORTS}"
        "s = EventStore(sys.argv[1])\n"
        "for i in range(20):\n"
        f"    s.append([{CHILD_EVENT.format(t='i')}])\n"
        "os.kill(os.getpid(), 9)\n"
    )
    assert subprocess.run([sys.executable, "-c", code, str(tmp_path)]).returncode == -9
    assert (tmp_path / "events.sqlite3-wal").stat().st_size > 0  # the commits are in the WAL
    assert [e.event_id for e in EventStore(tmp_path, readonly=True).events()] == [str(i) for i in range(20)]


def test_events_lists_a_stored_time_no_calendar_holds_as_its_number(tmp_path: Path, capsys) -> None:
    from bogiemon.cli.main import main

    store = EventStore(tmp_path)
    store.append([event(float("inf")), event(1e300), event(1.7e9)])  # stores written before times were checked
    store.close()
    assert main(["events", "--state-dir", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert [line.split()[0] for line in lines] == ["time_s=inf", "time_s=1e+300", "2023-11-14T22:13:20Z"]


def test_a_store_whose_schema_names_are_not_utf8_is_refused_as_damaged(tmp_path: Path) -> None:
    filled_store(tmp_path, n=3)
    path = tmp_path / "events.sqlite3"
    data = path.read_bytes()
    # The index's name in sqlite_master's record, overwritten with bytes that are not UTF-8:
    # SQLite's own error message quotes them (a UnicodeDecodeError once, found by mutating stores).
    damaged = data.replace(b"indexevents_time", b"index\x8d\xd9\x8d\xd9\x8d\xd9\x8d\xd9\x8d\xd9\x8d", 1)
    assert damaged != data
    path.write_bytes(damaged)
    for readonly in (True, False):
        with pytest.raises(StoreError, match=r"the event store is damaged \(its schema is unreadable\)"):
            EventStore(tmp_path, readonly=readonly)
