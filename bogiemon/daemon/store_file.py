"""The event store's SQLite file: built whole, checked at every open, migrated, read from read-only
media; and the one transaction and the storage's own words for what failed.

A store is never replaced or repaired behind the user's back: a new one is built beside the final
name and linked into place complete, so a file of that name that is empty, not a database, damaged
(`PRAGMA quick_check`) or of a newer schema was not left by an interrupted start; it is refused
with a StoreError naming the file and what to do, and left untouched. What the file holds, and
how it is used, is daemon/store.py's (the event log and the state) and daemon/outbox.py's (the
MQTT outbox).
"""

from __future__ import annotations

import contextlib
import errno
import os
import re
import shutil
import sqlite3
import tempfile
from collections.abc import Iterator
from pathlib import Path

from bogiemon.drivers.atomic import fsync_path
from bogiemon.drivers.quoting import quoted

DB_NAME = "events.sqlite3"
# A store being created (_create): tempfile.mkstemp's 8 characters between the prefix and the suffix,
# and the journal files SQLite may leave beside it. Named so that a start can tell it is bogiemon's.
STORE_TEMPORARY = re.compile(rf"\.{re.escape(DB_NAME)}\.[a-z0-9_]{{8}}\.new(?:-wal|-shm|-journal)?")
SCHEMA_VERSION = 3
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
    # The event bodies written from here on count k of n as {"k": 3, "n": 5} (bogiemon.event/2):
    # no statement, the version alone, so that a bogiemon before it refuses the file rather than
    # send those bodies as bogiemon.event/1. The rows of versions 1 and 2 stay as they were written
    # ("3 of 5"); daemon/event_json.py reads both.
    3: (),
}


class StoreError(RuntimeError):
    """The state directory or its database cannot be used; the message says which and why."""


class StoreWriteError(StoreError):
    """A commit the storage could not take (full disk, read-only or failing media, a damaged page):
    the transaction left nothing in the store, and it may be retried once the storage is fixed."""


class StoreFile:
    """The SQLite file at path: open_writable() or open_checked() give its connection; close() drops
    the private copy a read from read-only media may have made."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self._scratch: tempfile.TemporaryDirectory[str] | None = None  # a private copy's directory (read-only media)

    def open_writable(self) -> sqlite3.Connection:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if not self.path.exists():
            self._create()
        # Judged on a read-only connection first, so that a file this bogiemon refuses is never
        # written to (not even the checkpoint that closing a writer runs).
        self.open_checked().close()
        self.close()
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
            fsync_path(scratch)
            try:
                os.link(scratch, self.path)
            except FileExistsError:
                pass
            except OSError:  # a file system without hard links (vfat): a rename, if still nobody's
                if not self.path.exists():
                    os.replace(scratch, self.path)
            fsync_path(self.path.parent)
        finally:
            for leftover in (scratch, f"{scratch}-wal", f"{scratch}-shm"):
                with contextlib.suppress(FileNotFoundError):
                    os.unlink(leftover)

    def open_checked(self) -> sqlite3.Connection:
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
                raise StoreError(self.damaged("its schema is unreadable")) from None
            except sqlite3.DatabaseError as exc:
                if _is_damage(exc):
                    raise StoreError(self.damaged(str(exc))) from None
                raise
            if problems != ["ok"]:
                raise StoreError(self.damaged("; ".join(problems)))
            if version < 0:  # user_version is a signed header field that bogiemon only ever sets to 0..SCHEMA_VERSION
                raise StoreError(self.damaged(f"its schema version in the header reads {version}"))
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
            raise StoreError(self.damaged("its schema is unreadable")) from None
        except sqlite3.DatabaseError as exc:
            db.close()
            if _is_damage(exc):
                raise StoreError(self.damaged(str(exc))) from None
            raise
        return db

    def damaged(self, detail: str) -> str:
        detail = quoted(" ".join(detail.split()), 300)  # quick_check reports one problem per line, which may quote the file
        return (
            f"{self.path}: the event store is damaged ({detail}); bogiemon leaves it untouched: move it aside "
            f"(mv {self.path} {self.path}.damaged, with its -wal and -shm files), then start again for a new store "
            f"(`sqlite3 {self.path}.damaged .recover` may save its events)"
        )

    def _migrate(self, db: sqlite3.Connection) -> None:
        with transaction(db) as tx:  # IMMEDIATE: two processes opening a new file migrate once
            version = tx.execute("PRAGMA user_version").fetchone()[0]
            if version > SCHEMA_VERSION:  # checked at open too; this is under the write lock
                raise StoreError(f"{self.path}: written by a newer bogiemon (schema {version} > {SCHEMA_VERSION})")
            if version == SCHEMA_VERSION:
                return  # nothing written: a store on a full disk still opens
            for target in range(version + 1, SCHEMA_VERSION + 1):
                for statement in _MIGRATIONS[target]:
                    tx.execute(statement)
            tx.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    def close(self) -> None:
        if self._scratch is not None:
            self._scratch.cleanup()
            self._scratch = None

    def storage_hint(self, exc: BaseException) -> str:
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
def transaction(db: sqlite3.Connection) -> Iterator[sqlite3.Connection]:
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



