"""The MQTT outbox in the event store's file (schema 2, docs/mqtt.md): an event is pending until the
publisher marks it delivered (after the broker's PUBACK) or the outbox bound drops it from
delivery; periodic status records wait in status_outbox and are deleted once delivered. Oldest
first everywhere. The events themselves are the event log's (daemon/store.py)."""

from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from typing import Protocol

from bogiemon.judgement.events import Event, EventKind


# Alarm kinds are never dropped from delivery by the outbox bound (docs/mqtt.md, "The outbox").
ALARM_KINDS = (EventKind.CONFIRMED.value, EventKind.CLEARED.value)
OUTBOX_STATE_KEY = "outbox"
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


class EventTables(Protocol):
    """What the outbox uses of the event store that makes it (daemon/store.py's EventStore): its
    connection, its read and write guards and its decoding of a stored event."""

    connection: sqlite3.Connection

    @property
    def path(self) -> object: ...  # named in errors

    def reading(self, what: str) -> AbstractContextManager[None]: ...

    def write(self) -> AbstractContextManager[sqlite3.Connection]: ...

    def decode(self, seq: int, body: str) -> Event: ...


class Outbox:
    """The outbox of one event store."""

    def __init__(self, store: EventTables) -> None:
        self.store = store

    def pending_events(self, after_seq: int = 0, limit: int = 100) -> list[PendingEvent]:
        """Events neither delivered nor dropped, in commit order, after the given seq."""
        with self.store.reading("pending events"):
            rows = self.store.connection.execute(
                f"SELECT seq, body FROM events WHERE {_PENDING} AND seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
            ).fetchall()
        return [PendingEvent(seq, self.store.decode(seq, body)) for seq, body in rows]

    def pending_status(self, after_seq: int = 0, limit: int = 100) -> list[PendingStatus]:
        with self.store.reading("pending status records"):
            rows = self.store.connection.execute(
                "SELECT seq, time_s, body FROM status_outbox WHERE seq > ? ORDER BY seq LIMIT ?", (after_seq, limit)
            ).fetchall()
        return [PendingStatus(seq, time_s, body) for seq, time_s, body in rows]

    def queue_status(self, time_s: float, body: str) -> int:
        """Queue one status message (durably); returns its seq."""
        with self.store.write() as db:
            cursor = db.execute("INSERT INTO status_outbox (time_s, body) VALUES (?, ?)", (time_s, body))
        return int(cursor.lastrowid or 0)

    def mark_delivered(self, event_seqs: Sequence[int], status_seqs: Sequence[int], delivered_s: float) -> None:
        """Record PUBACKs in one transaction: events get delivered_s, status records go."""
        if not event_seqs and not status_seqs:
            return
        with self.store.write() as db:
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
        if self.counts().pending <= max_messages:  # the usual case: no write lock taken
            return 0, 0
        with self.store.write() as db:
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

    def counts(self) -> OutboxCounts:
        with self.store.reading("the outbox"):
            return self._counts(self.store.connection)

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

