"""The durable event store: SQLite in WAL mode with full sync, in the state directory.

An event is committed here before it is logged or sent anywhere, so whatever was reported is on
disk: with journal_mode=WAL and synchronous=FULL a committed transaction survives a crash or a
power cut. The same file holds the decision state, written in the same transaction as the event
it caused, so alarm state and events never disagree after a restart.

The file is also the outbox of alarm delivery (daemon/outbox.py, `store.outbox`); how it is made,
checked and opened, read-only media included, is daemon/store_file.py's. A commit the storage
cannot take (a full disk, read-only or failing media) raises StoreWriteError and leaves nothing
of itself.
"""

from __future__ import annotations

import contextlib
import json
import sqlite3
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from bogiemon.daemon.event_json import event_body, event_from_body
from bogiemon.judgement.events import Event
from bogiemon.daemon.outbox import Outbox
from bogiemon.daemon.store_file import DB_NAME, StoreError, StoreFile, StoreWriteError, transaction

__all__ = ["DB_NAME", "EventStore", "StoreError", "StoreWriteError"]


class EventStore:
    """Append-only events plus a small key-value state, in one SQLite file; `outbox` delivers them."""

    def __init__(self, state_dir: str | Path, readonly: bool = False) -> None:
        self.path = Path(state_dir) / DB_NAME
        self._file = StoreFile(self.path)
        try:
            self.connection = self._file.open_checked() if readonly else self._file.open_writable()
        except (sqlite3.Error, OSError) as exc:
            self._file.close()
            raise StoreError(f"{self.path}: cannot open the event store: {exc}{self._file.storage_hint(exc)}") from None
        except BaseException:
            self._file.close()
            raise
        self.outbox = Outbox(self)

    @property
    def schema_version(self) -> int:
        return int(self.connection.execute("PRAGMA user_version").fetchone()[0])

    def close(self) -> None:
        self.connection.close()
        self._file.close()

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None:
        """Commit events (and the state that goes with them) in one durable transaction.

        Raises StoreWriteError when the storage refuses the commit (nothing of it is stored);
        sqlite3.IntegrityError (an event id committed twice) is a bug of the caller.
        """
        with self.write() as db:
            db.executemany(
                "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
                [(e.event_id, e.time_s, e.kind.value, e.severity.value, e.config_hash, json.dumps(event_body(e))) for e in events],
            )
            for key, value in (state or {}).items():
                db.execute("INSERT OR REPLACE INTO state (key, value) VALUES (?, ?)", (key, json.dumps(value)))

    def committed_ids(self, event_ids: Sequence[str]) -> set[str]:
        """Those of event_ids that are in the store (after a commit whose outcome is in doubt)."""
        found: set[str] = set()
        with self.reading("events"):
            for event_id in event_ids:
                if self.connection.execute("SELECT 1 FROM events WHERE event_id = ?", (event_id,)).fetchone() is not None:
                    found.add(event_id)
        return found

    def get_state(self, key: str) -> Any:
        with self.reading(f"the state '{key}'"):
            row = self.connection.execute("SELECT value FROM state WHERE key = ?", (key,)).fetchone()
            return None if row is None else json.loads(row[0])

    def events(self, since_s: float | None = None, limit: int | None = None) -> list[Event]:
        """Events in commit order, optionally only those at or after since_s (Unix seconds)."""
        query = "SELECT seq, body FROM events"
        args: list[Any] = []
        if since_s is not None:
            query += " WHERE time_s >= ?"
            args.append(since_s)
        query += " ORDER BY seq"
        if limit is not None:
            query += " LIMIT ?"
            args.append(limit)
        with self.reading("events"):
            rows = self.connection.execute(query, args).fetchall()
        return [self.decode(seq, body) for seq, body in rows]

    def count(self) -> int:
        with self.reading("events"):
            return int(self.connection.execute("SELECT COUNT(*) FROM events").fetchone()[0])

    def decode(self, seq: int, body: str) -> Event:
        """One stored event; a row that passed quick_check but does not decode is damage, named by its seq."""
        try:
            return event_from_body(json.loads(body))
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
            raise StoreError(self._file.damaged(f"event {seq} does not decode: {exc!r}")) from None

    @contextlib.contextmanager
    def reading(self, what: str) -> Iterator[None]:
        """Reads that meet damage (a bad page quick_check did not visit, a bad JSON value) raise StoreError."""
        try:
            yield
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot read {what}: {exc}") from None
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
            raise StoreError(self._file.damaged(f"{what} does not decode: {exc!r}")) from None

    @contextlib.contextmanager
    def write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction; a failure of the storage becomes StoreWriteError."""
        try:
            with transaction(self.connection) as db:
                yield db
        except sqlite3.IntegrityError:
            raise  # a constraint the caller broke: a bug, not the storage
        except sqlite3.DatabaseError as exc:  # full, read-only, I/O error, a damaged page met on the way
            raise StoreWriteError(f"{self.path}: cannot commit to the event store: {exc}{self._file.storage_hint(exc)}") from None

