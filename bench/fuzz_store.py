"""Fuzz target of the event store's reader: EventStore on damaged files, as `events`, `run` and `replay` meet them.

The files are real stores (events, delivered and dropped marks, status records, the monitor's
state; some copied mid-run with their write-ahead log, as a kill -9 leaves them), then damaged:
emptied, truncated, a page zeroed or replaced by random bytes, bits flipped, header fields
changed (a newer schema version among them), the log or its index replaced by garbage, random
bytes or text, a directory in the file's place. Each is opened read-only and printed as
`bogiemon events` does, then read-write with what the monitor does first (its state, the
outbox, one commit). The reference is what was committed: a store that opens and reads without
an error must hold every committed event (an event lost without a word is a wrong result) at a
plausible time. SQLite has no page checksums, so a changed byte inside a record can go unseen:
that is not counted.
"""

from __future__ import annotations

import functools
import os
import random
import struct
from typing import Any

import fuzz_core
from bogiemon.cli.events import format_event
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.store import DB_NAME, EventStore
from bogiemon.daemon.store_file import SCHEMA_VERSION
from tests.judgement.event_examples import event_of

PAGE_BYTES = 4096
BASES = 6  # distinct healthy stores the damage starts from


def _events(rng: random.Random, n: int) -> list[Event]:
    kinds = list(EventKind)
    out = []
    for i in range(n):
        kind = rng.choice(kinds)
        indicators = {"i4_norm": rng.uniform(-1, 1)}
        pad = "x" * rng.choice((0, 100, 3000))  # rows that fill pages and overflow them, where the kind holds free text
        text = pad if kind in (EventKind.NOT_JUDGED, EventKind.CONFIRMED) else ""
        out.append(event_of(kind, 1.7e9 + 10 * i, indicators, text=text, event_id=rng.randbytes(16).hex()))
    return out


@functools.cache
def base(index: int) -> tuple[dict[str, bytes], list[list[Any]]]:
    """Healthy store number `index`: its files, and the events committed in them ([event_id, time_s])."""
    rng = random.Random(f"bogiemon-fuzz-store-base/{index}")
    folder = fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-base-")
    try:
        n = (0, 1, 5, 30, 12, 8)[index]
        events = _events(rng, n)
        store = EventStore(folder)
        for i, event in enumerate(events):
            store.append([event], state={"monitor": {"decision": {"mode": "normal", "n": i}}})
        if n and index % 2:
            store.outbox.mark_delivered([1], [], 1.7e9)
            store.outbox.queue_status(1.7e9, '{"schema": "bogiemon.status/1"}')
        if index == 5:  # a copy taken while the daemon runs: the last commits only in the log
            files = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
        else:
            store.close()
            files = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
        if index == 5:
            store.close()
        return files, [[e.event_id, e.time_s] for e in events]
    finally:
        fuzz_core.remove_tree(folder)


def generate(rng: random.Random) -> fuzz_core.Input:
    m = fuzz_core.Mutator(rng)
    index = rng.randrange(BASES)
    files, committed = base(index)
    files = dict(files)
    db = files.get(DB_NAME, b"")
    kind = rng.choice(("none", "empty", "truncate", "truncate_page", "zero_page", "random_page", "flip", "header", "newer",
                       "garbage", "text", "log_garbage", "index_garbage", "directory", "bytes", "splice"))  # fmt: skip
    reference: list[list[Any]] | None = committed
    pages = max(1, len(db) // PAGE_BYTES)
    if kind == "empty":
        db = b""
    elif kind == "truncate":
        db = db[: rng.randint(0, max(0, len(db) - 1))]
    elif kind == "truncate_page":
        db = db[: PAGE_BYTES * rng.randrange(pages)]
    elif kind in ("zero_page", "random_page"):
        page = rng.randrange(pages)
        fill = bytes(PAGE_BYTES) if kind == "zero_page" else rng.randbytes(PAGE_BYTES)
        db = db[: page * PAGE_BYTES] + fill + db[(page + 1) * PAGE_BYTES :]
    elif kind == "flip":
        out = bytearray(db)
        for _ in range(rng.randint(1, 20)):
            if out:
                i = rng.randrange(len(out))
                out[i] ^= 1 << rng.randrange(8)
        db = bytes(out)
    elif kind in ("header", "newer") and len(db) >= 100:
        out = bytearray(db)
        if kind == "newer":
            out[60:64] = struct.pack(">i", rng.choice((SCHEMA_VERSION + 1, 99, 2**31 - 1)))  # user_version
        else:
            field = rng.choice(((16, 2), (18, 2), (20, 1), (24, 4), (28, 4), (40, 4), (44, 4), (56, 4), (60, 4), (96, 4)))
            out[field[0] : field[0] + field[1]] = rng.choice((bytes(field[1]), b"\xff" * field[1], rng.randbytes(field[1])))
        db = bytes(out)
    elif kind == "garbage":
        db = rng.randbytes(rng.choice((1, 100, PAGE_BYTES, 3 * PAGE_BYTES)))
    elif kind == "text":
        db = b"SQLite format 3\x00" + b"this is not a database\n" * rng.randint(1, 300)
    elif kind == "log_garbage":
        files[DB_NAME + "-wal"] = rng.randbytes(rng.choice((32, 4096 + 24, 10_000)))
        reference = None  # a torn log is how a crash looks: SQLite drops it by design
    elif kind == "index_garbage":
        files[DB_NAME + "-shm"] = rng.randbytes(32768)
    elif kind == "bytes":
        db = m.bytes(db)
    elif kind == "splice":
        other, _ = base(rng.randrange(BASES))
        donor = other.get(DB_NAME, b"")
        cut = rng.randrange(max(1, len(db)))
        db = db[:cut] + donor[cut:]
    files[DB_NAME] = db
    if kind in ("flip", "bytes", "splice", "header"):
        reference = None  # a changed byte inside a record is invisible without checksums (see above)
    return {"files": files, "directory": kind == "directory", "committed": reference, "damage": kind}


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    state_dir = ctx.fresh_dir() / "state"
    state_dir.mkdir()
    for name, content in data["files"].items():
        if name == DB_NAME and data["directory"]:
            (state_dir / name).mkdir()
            continue
        (state_dir / name).write_bytes(content)
    committed = data["committed"]

    # `bogiemon events`: read-only, every event printed.
    reader = EventStore(state_dir, readonly=True)
    try:
        events = reader.events()
        for event in events:
            format_event(event)
    finally:
        reader.close()
    verdict = _compare(events, committed, "read-only")
    if verdict is not None:
        return verdict

    # `bogiemon run` / `replay`: read-write, the monitor's state, the outbox, the first commit.
    store = EventStore(state_dir)
    try:
        store.get_state("monitor")
        store.count()
        store.outbox.pending_events()
        store.outbox.pending_status()
        store.outbox.counts()
        store.append([event_of(EventKind.SUSPECTED, 1.8e9, config_hash="fuzz")],
                     state={"monitor": {"decision": {"mode": "suspected"}}})  # fmt: skip
        after = store.events()
    finally:
        store.close()
    return _compare(after[:-1] if after and after[-1].config_hash == "fuzz" else after, committed, "read-write")


def _compare(events: list[Event], committed: list[list[Any]] | None, how: str) -> fuzz_core.Verdict:
    for event in events:
        if fuzz_core.implausible_time(event.time_s):
            return f"an event at an absurd time, read {how}: time_s {event.time_s!r}"
    if committed is None:
        return None
    ids = {e.event_id for e in events}
    lost = [event_id for event_id, _ in committed if event_id not in ids]
    if lost:
        return f"committed events lost without an error, read {how}: {len(lost)} of {len(committed)}"
    return None



TARGETS = [fuzz_core.Target("store", generate, run)]
