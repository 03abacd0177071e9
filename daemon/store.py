"""The durable event store: SQLite in WAL mode with full sync, in the state directory.

An event is committed here before it is logged or sent anywhere, so whatever was reported is on
disk: with journal_mode=WAL and synchronous=FULL a committed transaction survives a crash or a
power cut. The same file holds the decision state, written in the same transaction as the event
it caused, so alarm state and events never disagree after a restart.

The file is also the outbox of alarm delivery (schema 2, docs/mqtt.md): an event is pending
until the MQTT publisher marks it delivered (after the broker's PUBACK) or the outbox bound drops
it from delivery; periodic status records wait in status_outbox and are deleted once delivered.

A store is never replaced or repaired behind the user's back: a new one is built beside the final
name and linked into place complete, so a file of that name that is empty, not a database, damaged
(`PRAGMA quick_check`) or of a newer schema was not left by an interrupted start; it is refused
with a StoreError naming the file and what to do, and left untouched. A commit the storage cannot
take (a full disk, read-only or failing media) raises StoreWriteError and leaves nothing of itself.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import sqlite3
import tempfile
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
# Below this much free space a failing open or commit is named a full file system: a commit of
# one window's events and state writes a few pages to the WAL, and its index grows in 32 KiB steps.
LOW_SPACE_BYTES = 256 * 1024

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


class StoreWriteError(StoreError):
    """A commit the storage could not take (full disk, read-only or failing media, a damaged page):
    the transaction left nothing in the store, and it may be retried once the storage is fixed."""


class EventStore:
    """Append-only events plus a small key-value state, in one SQLite file."""

    def __init__(self, state_dir: str | Path, readonly: bool = False) -> None:
        self.path = Path(state_dir) / DB_NAME
        self._scratch: tempfile.TemporaryDirectory[str] | None = None  # a private copy's directory (read-only media)
        try:
            if readonly:
                self._db = self._open_checked()
            else:
                self._db = self._open_writable()
        except (sqlite3.Error, OSError) as exc:
            self._drop_scratch()
            raise StoreError(f"{self.path}: cannot open the event store: {exc}{self._storage_hint(exc)}") from None
        except BaseException:
            self._drop_scratch()
            raise

    def _open_writable(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not self.path.exists():
            self._create()
        # Judged on a read-only connection first, so that a file this bogiemon refuses is never
        # written to (not even the checkpoint that closing a writer runs).
        self._open_checked().close()
        self._drop_scratch()
        db = sqlite3.connect(self.path, check_same_thread=False, isolation_level=None)
        try:
            db.execute("PRAGMA journal_mode=WAL")
            db.execute("PRAGMA synchronous=FULL")
            self._migrate(db)
        except BaseException:
            db.close()
            raise
        return db

    def _create(self) -> None:
        """Build a new store beside its final name and link it into place only once it is complete.

        A start killed at any moment then leaves either no store or a whole one, so an empty or
        half-made events.sqlite3 is never ours and can be refused as damage. link() never
        replaces: of two processes creating a store at once, the first one's stays.
        """
        fd, scratch = tempfile.mkstemp(prefix=f".{DB_NAME}.", suffix=".new", dir=self.path.parent)
        os.close(fd)
        try:
            db = sqlite3.connect(scratch, isolation_level=None)
            try:
                db.execute("PRAGMA journal_mode=WAL")
                db.execute("PRAGMA synchronous=FULL")
                self._migrate(db)
            finally:
                db.close()  # the last connection checkpoints the WAL into the file and removes it
            _fsync_path(scratch)
            try:
                os.link(scratch, self.path)
            except FileExistsError:
                pass
            except OSError:  # a file system without hard links (vfat): a rename, if still nobody's
                if not self.path.exists():
                    os.replace(scratch, self.path)
            _fsync_path(self.path.parent)
        finally:
            for leftover in (scratch, f"{scratch}-wal", f"{scratch}-shm"):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(leftover)

    def _open_checked(self) -> sqlite3.Connection:
        """A read-only connection to a store judged usable: present, not empty, intact, not newer."""
        if not self.path.exists():
            raise StoreError(f"{self.path}: no event store here yet (has the daemon run with this state directory?)")
        wal = Path(f"{self.path}-wal")
        if self.path.stat().st_size == 0 and not (wal.exists() and wal.stat().st_size > 0):
            raise StoreError(
                f"{self.path}: the event store is an empty file, so whatever it held was lost outside bogiemon "
                f"(a truncated copy, a failing disk); bogiemon does not start over on it: move it aside "
                f"(mv {self.path} {self.path}.empty) and start again for a new store"
            )
        db = self._connect_readonly()
        try:
            try:
                version = int(db.execute("PRAGMA user_version").fetchone()[0])
                problems = [str(row[0]) for row in db.execute("PRAGMA quick_check(3)")]
            except UnicodeDecodeError:  # SQLite's message quotes a damaged name, in bytes that are not UTF-8
                raise StoreError(self._damaged("its schema is unreadable")) from None
            except sqlite3.DatabaseError as exc:
                if _is_damage(exc):
                    raise StoreError(self._damaged(str(exc))) from None
                raise
            if problems != ["ok"]:
                raise StoreError(self._damaged("; ".join(problems)))
            if version < 0:  # user_version is a signed header field that bogiemon only ever sets to 0..SCHEMA_VERSION
                raise StoreError(self._damaged(f"its schema version in the header reads {version}"))
            if version > SCHEMA_VERSION:
                raise StoreError(
                    f"{self.path}: written by a newer bogiemon (schema {version} > {SCHEMA_VERSION}); "
                    "left untouched: run that version, or move the file aside to start a new store with this one"
                )
        except BaseException:
            db.close()
            raise
        return db

    def _connect_readonly(self) -> sqlite3.Connection:
        wal = Path(f"{self.path}-wal")
        if not wal.exists():
            # No WAL: every commit is in the main file (a writer keeps a WAL while it has the file
            # open). An immutable open reads it without creating a -wal or -shm beside it, which
            # read-only media cannot hold and `sudo bogiemon events` would leave owned by root.
            return self._probe(sqlite3.connect(f"file:{self.path}?mode=ro&immutable=1", uri=True, check_same_thread=False))
        try:
            return self._probe(sqlite3.connect(f"file:{self.path}?mode=ro", uri=True, check_same_thread=False))
        except sqlite3.OperationalError as exc:
            if exc.sqlite_errorcode != sqlite3.SQLITE_CANTOPEN or wal.stat().st_size == 0:
                raise
        # Read-only media with commits still in the WAL: a reader needs a -shm file that cannot be
        # made there, and an immutable open would not see them. Read a private copy instead.
        self._scratch = tempfile.TemporaryDirectory(prefix="bogiemon-events-")
        copy = Path(self._scratch.name) / DB_NAME
        shutil.copyfile(self.path, copy)
        shutil.copyfile(wal, f"{copy}-wal")
        return self._probe(sqlite3.connect(f"file:{copy}?mode=ro", uri=True, check_same_thread=False))

    def _probe(self, db: sqlite3.Connection) -> sqlite3.Connection:
        """The connection, once a first read went through (SQLite opens lazily); damage is a StoreError."""
        try:
            db.execute("PRAGMA user_version").fetchone()
        except UnicodeDecodeError:
            db.close()
            raise StoreError(self._damaged("its schema is unreadable")) from None
        except sqlite3.DatabaseError as exc:
            db.close()
            if _is_damage(exc):
                raise StoreError(self._damaged(str(exc))) from None
            raise
        return db

    def _damaged(self, detail: str) -> str:
        detail = " ".join(detail.split())  # quick_check reports one problem per line: the error is one line
        return (
            f"{self.path}: the event store is damaged ({detail}); bogiemon leaves it untouched: move it aside "
            f"(mv {self.path} {self.path}.damaged, with its -wal and -shm files), then start again for a new store "
            f"(`sqlite3 {self.path}.damaged .recover` may save its events)"
        )

    def _migrate(self, db: sqlite3.Connection) -> None:
        with _transaction(db) as tx:  # IMMEDIATE: two processes opening a new file migrate once
            version = tx.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:  # checked at open too; this is under the write lock
                raise StoreError(f"{self.path}: written by a newer bogiemon (schema {version} > {SCHEMA_VERSION})")
            if version == SCHEMA_VERSION:
                return  # nothing written: a store on a full disk still opens
            for target in range(version + 1, SCHEMA_VERSION + 1):
                for statement in _MIGRATIONS[target]:
                    tx.execute(statement)
            tx.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    @property
    def schema_version(self) -> int:
        return int(self._db.execute("PRAGMA user_version").fetchone()[0])

    def close(self) -> None:
        self._db.close()
        self._drop_scratch()

    def _drop_scratch(self) -> None:
        if self._scratch is not None:
            self._scratch.cleanup()
            self._scratch = None

    def append(self, events: list[Event], state: dict[str, Any] | None = None) -> None:
        """Commit events (and the state that goes with them) in one durable transaction.

        Raises StoreWriteError when the storage refuses the commit (nothing of it is stored);
        sqlite3.IntegrityError (an event id committed twice) is a bug of the caller.
        """
        with self._write() as db:
            db.executemany(
                "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
                [(e.event_id, e.time_s, e.kind.value, e.severity.value, e.config_hash, json.dumps(e.as_dict())) for e in events],
            )
            for key, value in (state or {}).items():
                db.execute("INSERT OR REPLACE INTO state (key, value) VALUES (?, ?)", (key, json.dumps(value)))

    def committed_ids(self, event_ids: Sequence[str]) -> set[str]:
        """Those of event_ids that are in the store (after a commit whose outcome is in doubt)."""
        found: set[str] = set()
        with self._reading("events"):
            for event_id in event_ids:
                if self._db.execute("SELECT 1 FROM events WHERE event_id = ?", (event_id,)).fetchone() is not None:
                    found.add(event_id)
        return found

    def put_state(self, key: str, value: Any) -> None:
        self.append([], {key: value})

    def get_state(self, key: str) -> Any:
        with self._reading(f"the state '{key}'"):
            row = self._db.execute("SELECT value FROM state WHERE key = ?", (key,)).fetchone()
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
        with self._reading("events"):
            rows = self._db.execute(query, args).fetchall()
        return [self._decode(seq, body) for seq, body in rows]

    def count(self) -> int:
        with self._reading("events"):
            return int(self._db.execute("SELECT COUNT(*) FROM events").fetchone()[0])

    def _decode(self, seq: int, body: str) -> Event:
        """One stored event; a row that passed quick_check but does not decode is damage, named by its seq."""
        try:
            return Event.from_dict(json.loads(body))
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
            raise StoreError(self._damaged(f"event {seq} does not decode: {exc!r}")) from None

    @contextlib.contextmanager
    def _reading(self, what: str) -> Iterator[None]:
        """Reads that meet damage (a bad page quick_check did not visit, a bad JSON value) raise StoreError."""
        try:
            yield
        except sqlite3.Error as exc:
            raise StoreError(f"{self.path}: cannot read {what}: {exc}") from None
        except (ValueError, TypeError, KeyError, AttributeError, RecursionError) as exc:
            raise StoreError(self._damaged(f"{what} does not decode: {exc!r}")) from None

    # The outbox: what the MQTT publisher reads and marks. Oldest first everywhere.

    def pending_events(self, after_seq: int = 0, limit: int = 100) -> list[PendingEvent]:
        """Events neither delivered nor dropped, in commit order, after the given seq."""
        with self._reading("pending events"):
            rows = self._db.execute(
                f"SELECT seq, body FROM events WHERE {_PENDING} AND seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
            ).fetchall()
        return [PendingEvent(seq, self._decode(seq, body)) for seq, body in rows]

    def pending_status(self, after_seq: int = 0, limit: int = 100) -> list[PendingStatus]:
        with self._reading("pending status records"):
            rows = self._db.execute(
                "SELECT seq, time_s, body FROM status_outbox WHERE seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
            ).fetchall()
        return [PendingStatus(seq, time_s, body) for seq, time_s, body in rows]

    def queue_status(self, time_s: float, body: str) -> int:
        """Queue one status message (durably); returns its seq."""
        with self._write() as db:
            cursor = db.execute("INSERT INTO status_outbox (time_s, body) VALUES (?, ?)", (time_s, body))
        return int(cursor.lastrowid or 0)

    def mark_delivered(self, event_seqs: Sequence[int], status_seqs: Sequence[int], delivered_s: float) -> None:
        """Record PUBACKs in one transaction: events get delivered_s, status records go."""
        if not event_seqs and not status_seqs:
            return
        with self._write() as db:
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
        if self.outbox_counts().pending <= max_messages:  # the usual case: no write lock taken
            return 0, 0
        with self._write() as db:
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
        with self._reading("the outbox"):
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
    def _write(self) -> Iterator[sqlite3.Connection]:
        """One write transaction; a failure of the storage becomes StoreWriteError."""
        try:
            with _transaction(self._db) as db:
                yield db
        except sqlite3.IntegrityError:
            raise  # a constraint the caller broke: a bug, not the storage
        except sqlite3.DatabaseError as exc:  # full, read-only, I/O error, a damaged page met on the way
            raise StoreWriteError(f"{self.path}: cannot commit to the event store: {exc}{self._storage_hint(exc)}") from None

    def _storage_hint(self, exc: BaseException) -> str:
        """What SQLite's own words leave out ("disk I/O error" is often a full disk)."""
        code = getattr(exc, "sqlite_errorcode", None)
        readonly = (code is not None and (code & 0xFF) == sqlite3.SQLITE_READONLY) or getattr(exc, "errno", None) == errno.EROFS
        if readonly or (self.path.parent.is_dir() and not os.access(self.path.parent, os.W_OK)):
            return f" (the state directory {self.path.parent} is read-only: the daemon must be able to write there)"
        try:
            usage = os.statvfs(self.path.parent)
        except OSError:
            return ""
        free_bytes = usage.f_bavail * usage.f_frsize
        if free_bytes < LOW_SPACE_BYTES:
            return f" (the file system of {self.path.parent} is full, {free_bytes // 1024} KiB free: make room there)"
        return ""


@contextlib.contextmanager
def _transaction(db: sqlite3.Connection) -> Iterator[sqlite3.Connection]:
    """BEGIN IMMEDIATE ... COMMIT, rolled back on any exception (the commit's own included)."""
    db.execute("BEGIN IMMEDIATE")
    try:
        yield db
        db.execute("COMMIT")
    except BaseException:
        # SQLite has already rolled back after some errors (SQLITE_FULL): a second ROLLBACK would
        # raise and hide the error that matters.
        if db.in_transaction:
            with contextlib.suppress(sqlite3.Error):
                db.execute("ROLLBACK")
        raise


def _is_damage(exc: sqlite3.DatabaseError) -> bool:
    """"file is not a database" or "database disk image is malformed": the file, not the moment."""
    code = getattr(exc, "sqlite_errorcode", None)
    return code is not None and (code & 0xFF) in (sqlite3.SQLITE_CORRUPT, sqlite3.SQLITE_NOTADB)


def _fsync_path(path: str | Path) -> None:
    """fsync a file or a directory (a rename or link is durable once its directory is synced)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
