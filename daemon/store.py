"""The durable event store: SQLite in WAL mode with full sync, in the state directory.

An event is committed here before it is logged or sent anywhere, so whatever was reported is on
disk: with journal_mode=WAL and synchronous=FULL a committed transaction survives a crash or a
power cut. The same file holds the decision state, written in the same transaction as the event
it caused, so alarm state and events never disagree after a restart.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bogiemon.daemon.events import Event

DB_NAME = "events.sqlite3"
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS events (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    event_id TEXT NOT NULL UNIQUE,
    time_s REAL NOT NULL,
    kind TEXT NOT NULL,
    severity TEXT NOT NULL,
    config_hash TEXT NOT NULL,
    body TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_time ON events (time_s);
CREATE TABLE IF NOT EXISTS state (
    key TEXT PRIMARY KEY,
    value TEXT NOT NULL
);
"""


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
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            raise StoreError(f"{self.path}: written by a newer bogiemon (schema {version} > {SCHEMA_VERSION})")
        self._db.executescript(_SCHEMA)
        self._db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

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
