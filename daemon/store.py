"""The durable event store: SQLite in WAL mode with full sync, in the state directory.

An event is committed here before it is logged or sent anywhere, so whatever was reported is on
disk: with journal_mode=WAL and synchronous=FULL a committed transaction survives a crash or a
power cut. The same file holds the decision state, written in the same transaction as the event
it caused, so alarm state and events never disagree after a restart.

The file is also the outbox of alarm delivery (schema 2, docs/mqtt.md): an event is pending
until the MQTT publisher marks it delivered (after the broker's PUBACK) or the outbox bound drops
it from delivery; periodic status records wait in status_outbox and are deleted once delivered.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bogiemon.daemon.events import Event

DB_NAME = "events.sqlite3"
SCHEMA_VERSION = 2
# Alarm kinds are never dropped from delivery by the outbox bound (docs/mqtt.md, "The outbox").
ALARM_KINDS = ("CONFIRMED", "CLEARED")
OUTBOX_STATE_KEY = "outbox"

# The statements that bring a file from version N - 1 to N, each set run in one transaction with
# the version bump, so a crash mid-migration leaves the previous version intact.
_MIGRATIONS: dict[int, tuple[str, ...]] = {
    1: (
        """CREATE TABLE IF NOT EXISTS events (
            seq INTEGER PRIMARY KEY AUTOINCREMENT,
            event_id TEXT NOT NULL UNIQUE,
            time_s REAL NOT NULL,
            kind TEXT NOT NULL,
            severity TEXT NOT NULL,
            config_hash TEXT NOT NULL,
            body TEXT NOT NULL
        )""",
        "CREATE INDEX IF NOT EXISTS events_time ON events (time_s)",
        "CREATE TABLE IF NOT EXISTS state (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    ),
    2: (
        # Delivery bookkeeping: both NULL means pending. Events of a version 1 file are pending.
        "ALTER TABLE events ADD COLUMN delivered_s REAL",
        "ALTER TABLE events ADD COLUMN dropped_s REAL",
        "CREATE INDEX events_pending ON events (seq) WHERE delivered_s IS NULL AND dropped_s IS NULL",
        # Status records wait here until delivered (then deleted) or dropped by the bound.
        "CREATE TABLE status_outbox (seq INTEGER PRIMARY KEY AUTOINCREMENT, time_s REAL NOT NULL, body TEXT NOT NULL)",
    ),
}
_PENDING = "delivered_s IS NULL AND dropped_s IS NULL"


@dataclass(frozen=True)
class PendingEvent:
    seq: int  # the store's commit order, increasing: the event's number in this wagon's sequence
    event: Event


@dataclass(frozen=True)
class PendingStatus:
    seq: int
    time_s: float  # Unix seconds when the status was taken
    body: str  # the message as it will be published (JSON text)


@dataclass(frozen=True)
class OutboxCounts:
    pending_events: int
    pending_alarms: int  # of pending_events, those of ALARM_KINDS
    pending_status: int
    dropped_events: int  # ever, by the bound (still in the store, never delivered)
    dropped_status: int  # ever, by the bound

    @property
    def pending(self) -> int:
        return self.pending_events + self.pending_status


class StoreError(RuntimeError):
    """The state directory or its database cannot be used; the message says which and why."""


class EventStore:
    """Append-only events plus a small key-value state, in one SQLite file."""

    def __init__(self, state_dir: str | Path, readonly: bool = False) -> None:
        self.path = Path(state_dir) / DB_NAME
        try:
            if readonly:
                if not self.path.exists():
                    raise StoreError(f"{self.path}: no event store here yet (has the daemon run with this state directory?)")
                self._db = sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, check_same_thread=False)
            else:
                self.path.parent.mkdir(parents=True, exist_ok=True)
                self._db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
                self._db.execute("PRAGMA journal_mode=WAL")
                self._db.execute("PRAGMA synchronous=FULL")
                self._migrate()
        except (sqlite3.Error, OSError) as exc:
            raise StoreError(f"{self.path}: cannot open the event store: {exc}") from None

    def _migrate(self) -> None:
        with self._transaction() as db:  # IMMEDIATE: two processes opening a new file migrate once
            version = db.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:
                raise StoreError(f"{self.path}: written by a newer bogiemon (schema {version} > {SCHEMA_VERSION})")
            for target in range(version + 1, SCHEMA_VERSION + 1):
                for statement in _MIGRATIONS[target]:
                    db.execute(statement)
            db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    @property
    def schema_version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def close(self) -> None:
        self._db.close()

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None:
        """Commit events (and the state that goes with them) in one durable transaction."""
        with self._transaction() as db:
            db.executemany(
                "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
                [(e.event_id, e.time_s, e.kind.value, e.severity.value, e.config_hash, json.dumps(e.as_dict())) for e in events],
            )
            for key, value in (state or {}).items():
                db.execute("INSERT OR REPLACE INTO state (key, value) VALUES (?, ?)", (key, json.dumps(value)))

    def put_state(self, key: str, value: Any) -> None:
        self.append([], {key: value})

    def get_state(self, key: str) -> Any:
        row = self._db.execute("SELECT value FROM state WHERE key = ?", (key,)).fetchone()
        return None if row is None else json.loads(row[0])

    def events(self, since_s: float | None = None, limit: int | None = None) -> list[Event]:
        """Events in commit order, optionally only those at or after since_s (Unix seconds)."""
        query = "SELECT body FROM events"
        args: list[Any] = []
        if since_s is not None:
            query += " WHERE time_s >= ?"
            args.append(since_s)
        query += " ORDER BY seq"
        if limit is not None:
            query += " LIMIT ?"
            args.append(limit)
        try:
            rows = self._db.execute(query, args).fetchall()
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot read events: {exc}") from None
        return [Event.from_dict(json.loads(body)) for (body,) in rows]

    def count(self) -> int:
        return int(self._db.execute("SELECT COUNT(*) FROM events").fetchone()[0])

    # The outbox: what the MQTT publisher reads and marks. Oldest first everywhere.

    def pending_events(self, after_seq: int = 0, limit: int = 100) -> list[PendingEvent]:
        """Events neither delivered nor dropped, in commit order, after the given seq."""
        rows = self._db.execute(
            f"SELECT seq, body FROM events WHERE {_PENDING} AND seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
        ).fetchall()
        return [PendingEvent(seq, Event.from_dict(json.loads(body))) for seq, body in rows]

    def pending_status(self, after_seq: int = 0, limit: int = 100) -> list[PendingStatus]:
        rows = self._db.execute(
            "SELECT seq, time_s, body FROM status_outbox WHERE seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
        ).fetchall()
        return [PendingStatus(seq, time_s, body) for seq, time_s, body in rows]

    def queue_status(self, time_s: float, body: str) -> int:
        """Queue one status message (durably); returns its seq."""
        with self._transaction() as db:
            cursor = db.execute("INSERT INTO status_outbox (time_s, body) VALUES (?, ?)", (time_s, body))
        return int(cursor.lastrowid or 0)

    def mark_delivered(self, event_seqs: Sequence[int], status_seqs: Sequence[int], delivered_s: float) -> None:
        """Record PUBACKs in one transaction: events get delivered_s, status records go."""
        if not event_seqs and not status_seqs:
            return
        with self._transaction() as db:
            # A dropped event that was in flight when the bound dropped it counts as delivered.
            db.executemany("UPDATE events SET delivered_s = ?, dropped_s = NULL WHERE seq = ?", [(delivered_s, seq) for seq in event_seqs])
            db.executemany("DELETE FROM status_outbox WHERE seq = ?", [(seq,) for seq in status_seqs])

    def trim_outbox(self, max_messages: int, now_s: float) -> tuple[int, int]:
        """Enforce the outbox bound; returns (status records, events) dropped by this call.

        Over the bound, the oldest status records go first; then the oldest pending events that
        are not alarms (SUSPECTED, SENSOR_FAULT, SENSOR_CLEARED) are marked dropped (they stay in
        the store). Alarms (CONFIRMED, CLEARED) are never dropped, so pending alarms alone may
        exceed the bound.
        """
        if self._counts(self._db).pending <= max_messages:  # the usual case: no write lock taken
            return 0, 0
        with self._transaction() as db:
            counts = self._counts(db)
            excess = counts.pending - max_messages
            if excess <= 0:
                return 0, 0
            drop_status = min(excess, counts.pending_status)
            db.execute("DELETE FROM status_outbox WHERE seq IN (SELECT seq FROM status_outbox ORDER BY seq LIMIT ?)", (drop_status,))
            excess -= drop_status
            drop_events = 0
            if excess > 0:
                kinds = ", ".join("?" * len(ALARM_KINDS))
                drop_events = db.execute(
                    f"UPDATE events SET dropped_s = ? WHERE seq IN (SELECT seq FROM events WHERE {_PENDING} "
                    f"AND kind NOT IN ({kinds}) ORDER BY seq LIMIT ?)",
                    (now_s, *ALARM_KINDS, excess),
                ).rowcount
            dropped = {"dropped_status": counts.dropped_status + drop_status}
            db.execute("INSERT OR REPLACE INTO state (key, value) VALUES (?, ?)", (OUTBOX_STATE_KEY, json.dumps(dropped)))
        return drop_status, drop_events

    def outbox_counts(self) -> OutboxCounts:
        return self._counts(self._db)

    def _counts(self, db: sqlite3.Connection) -> OutboxCounts:
        kinds = ", ".join("?" * len(ALARM_KINDS))
        pending_events, pending_alarms, dropped_events = db.execute(
            f"SELECT COUNT(*), COALESCE(SUM(kind IN ({kinds})), 0), "
            "(SELECT COUNT(*) FROM events WHERE dropped_s IS NOT NULL) "
            f"FROM events WHERE {_PENDING}",
            ALARM_KINDS,
        ).fetchone()
        pending_status = db.execute("SELECT COUNT(*) FROM status_outbox").fetchone()[0]
        row = db.execute("SELECT value FROM state WHERE key = ?", (OUTBOX_STATE_KEY,)).fetchone()
        dropped_status = json.loads(row[0])["dropped_status"] if row else 0
        return OutboxCounts(int(pending_events), int(pending_alarms), int(pending_status), int(dropped_events), int(dropped_status))

    @contextlib.contextmanager
    def _transaction(self) -> Iterator[sqlite3.Connection]:
        """BEGIN IMMEDIATE ... COMMIT, rolled back on any exception."""
        self._db.execute("BEGIN IMMEDIATE")
        try:
            yield self._db
        except BaseException:
            self._db.execute("ROLLBACK")
            raise
        self._db.execute("COMMIT")
