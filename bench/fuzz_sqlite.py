"""Fuzz target of python-can's SQLite CAN log (.db) through open_replay, as `replay` reads it.

The frames of the CAN targets (bench/fuzz_can.py: clean, with bus anomalies, or damaged) are
written in python-can's schema (messages(ts, arbitration_id, extended, remote, error, dlc, data)),
then the log is made hostile: values of other types (text, NULL, huge integers, blobs longer than
a frame), another schema (columns missing, renamed, reordered, extra; no table; a table without
rowid), a `messages` that is a view (of another table, or of an endless recursive query), columns
computed when read (a generated column of a huge blob), and damage to the file's bytes (its
header's page size and count, pages flipped, cut at a page or anywhere). Every frame row of an
undamaged log in the writer's schema must be accounted for, exactly as the reference (cantools per
frame) places it; the blocks must carry plausible, finite times, and a reading's peak RSS is bounded.
"""

from __future__ import annotations

import random
import sqlite3
import struct
from typing import Any

import fuzz_core
import fuzz_can
from fuzz_memory import PeakRss, memory_verdict
from bogiemon.drivers.replay import open_replay

# What one input's reading may add to the worker's resident memory (the unit's 200 MiB, less the
# process's own): a log row is at most a CAN FD frame, read a batch at a time.
PEAK_RSS_BOUND_MIB = 64.0
SCHEMA = "CREATE TABLE messages (ts REAL, arbitration_id INTEGER, extended INTEGER, remote INTEGER, error INTEGER, dlc INTEGER, data BLOB)"
ODD_VALUES: tuple[Any, ...] = (None, "", "x", "1e999", "nan", 2**63 - 1, -(2**63), -1, 1e308, float("inf"), float("nan"),
                               b"", b"\x00" * 65, b"\xff" * 8, "0x100", 3.5)  # fmt: skip


def _rows(frames: list[fuzz_can.Frame]) -> list[tuple[Any, ...]]:
    return [(f[0], f[1], int(f[2]), int(f[3]), int(f[4]), len(f[5]), bytes(f[5])) for f in frames]


def _database(statements: list[str], rows: list[tuple[Any, ...]], insert: str) -> bytes:
    """The file SQLite writes for these statements and rows (built in memory, serialised)."""
    connection = sqlite3.connect(":memory:")
    try:
        for statement in statements:
            connection.execute(statement)
        if rows:
            connection.executemany(insert, rows)
        connection.commit()
        return bytes(connection.serialize())
    finally:
        connection.close()


def _schema_variant(rng: random.Random, rows: list[tuple[Any, ...]]) -> tuple[list[str], list[tuple[Any, ...]], str]:
    """Another schema than python-can's: (statements, rows, the insert)."""
    insert = "INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)"
    kind = rng.choice(("missing", "renamed", "reordered", "extra", "no_table", "without_rowid", "view", "endless_view",
                       "generated_blob", "generated_time", "empty"))  # fmt: skip
    if kind == "missing":
        return ["CREATE TABLE messages (ts REAL, arbitration_id INTEGER, extended INTEGER, remote INTEGER, error INTEGER, dlc INTEGER)"], \
            [r[:6] for r in rows], "INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?)"  # fmt: skip
    if kind == "renamed":
        return [SCHEMA.replace("arbitration_id", "can_id")], rows, insert
    if kind == "reordered":
        return ["CREATE TABLE messages (data BLOB, dlc INTEGER, error INTEGER, remote INTEGER, extended INTEGER, arbitration_id INTEGER, ts REAL)"], \
            [r[::-1] for r in rows], insert  # fmt: skip
    if kind == "extra":
        return [SCHEMA.replace("data BLOB", "data BLOB, channel TEXT")], [(*r, "can0") for r in rows], "INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?, ?, ?)"
    if kind == "no_table":
        return [SCHEMA.replace("messages", "frames")], rows, insert.replace("messages", "frames")
    if kind == "without_rowid":
        return [SCHEMA.replace("ts REAL", "ts REAL PRIMARY KEY") + " WITHOUT ROWID"], list({r[0]: r for r in rows}.values()), \
            "INSERT OR REPLACE INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)"  # fmt: skip
    if kind == "view":
        return [SCHEMA.replace("messages", "raw"), "CREATE VIEW messages AS SELECT * FROM raw"], rows, insert.replace("messages", "raw")
    if kind == "endless_view":  # a view whose rows never end: reading it is no reading of the file
        return ["CREATE VIEW messages AS WITH RECURSIVE r(i) AS (SELECT 1 UNION ALL SELECT i + 1 FROM r) "
                "SELECT i * 0.002 AS ts, 256 AS arbitration_id, 0 AS extended, 0 AS remote, 0 AS error, 8 AS dlc, "
                "zeroblob(8) AS data FROM r"], [], insert  # fmt: skip
    if kind == "generated_blob":  # data computed when read: a blob of hundreds of MiB from a file of a few KiB
        size = rng.choice((1 << 20, 1 << 28, 999_000_000))
        return [SCHEMA.replace("data BLOB", f"data BLOB GENERATED ALWAYS AS (zeroblob({size})) VIRTUAL")], [r[:6] for r in rows], \
            "INSERT INTO messages (ts, arbitration_id, extended, remote, error, dlc) VALUES (?, ?, ?, ?, ?, ?)"  # fmt: skip
    if kind == "generated_time":
        return [SCHEMA.replace("ts REAL", "ts REAL GENERATED ALWAYS AS (length(hex(zeroblob(100000000)))) VIRTUAL")], \
            [r[1:] for r in rows], "INSERT INTO messages (arbitration_id, extended, remote, error, dlc, data) VALUES (?, ?, ?, ?, ?, ?)"  # fmt: skip
    return [SCHEMA], [], insert


def _odd_values(rng: random.Random, rows: list[tuple[Any, ...]]) -> list[tuple[Any, ...]]:
    out = [list(r) for r in rows]
    for _ in range(rng.randint(1, 5)):
        if not out:
            break
        row = rng.choice(out)
        row[rng.randrange(7)] = rng.choice(ODD_VALUES) if rng.random() < 0.8 else fuzz_core.Mutator(rng).random_bytes(200)
    return [tuple(r) for r in out]


def _damage_bytes(rng: random.Random, raw: bytes) -> bytes:
    out = bytearray(raw)
    page_size = struct.unpack(">H", raw[16:18])[0] or 65536 if len(raw) >= 18 else 4096
    kind = rng.choice(("page_size", "page_count", "flip_page", "cut_page", "cut", "bytes", "header"))
    if kind == "page_size":
        out[16:18] = struct.pack(">H", rng.choice((0, 1, 512, 513, 1024, 32768, 65535)))
    elif kind == "page_count":
        out[28:32] = struct.pack(">I", rng.choice((0, 1, 2, 1000, 2**31, 2**32 - 1)))
    elif kind == "flip_page" and len(out) > page_size:
        page = rng.randrange(1, len(out) // page_size) if len(out) // page_size > 1 else 0
        for _ in range(rng.randint(1, 16)):
            out[page * page_size + rng.randrange(page_size)] ^= 1 << rng.randrange(8)
    elif kind == "cut_page":
        return bytes(out[: page_size * rng.randint(0, max(0, len(out) // page_size - 1))])
    elif kind == "cut":
        return bytes(out[: rng.randint(0, len(out))])
    elif kind == "header":
        at = rng.randrange(16, 100)
        out[at] = rng.randrange(256)
    else:
        return fuzz_core.Mutator(rng).bytes(raw)
    return bytes(out)


def generate(rng: random.Random) -> fuzz_core.Input:
    layout_name = rng.choice(("hub", "hub", "per-node"))
    frames = fuzz_can.clean_frames(rng, layout_name)
    if rng.random() < 0.3:
        frames = fuzz_can.mutate_frames(rng, frames, rng.randint(1, 3))
    frames = [f for f in frames if -(2**63) <= f[1] < 2**63]  # what an SQLite integer holds
    rows = _rows(frames)
    kind = rng.choices(("valid", "values", "schema", "bytes"), (25, 20, 25, 30))[0]
    statements, insert = [SCHEMA], "INSERT INTO messages VALUES (?, ?, ?, ?, ?, ?, ?)"
    if kind == "values":
        rows = _odd_values(rng, rows)
    elif kind == "schema":
        statements, rows, insert = _schema_variant(rng, rows)
    raw = _database(statements, rows, insert)
    if kind == "bytes":
        raw = _damage_bytes(rng, raw)
    return {"layout": layout_name, "file": raw, "name": rng.choice(("run.db",) * 4 + ("run.sqlite", "run.log")),
            "frames": frames if kind == "valid" else None, "max_block_s": rng.choice((1.0, 0.1))}  # fmt: skip


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / data["name"]
    path.write_bytes(data["file"])
    with PeakRss() as peak:
        source = open_replay(path, 0.0, fuzz_can.layout(data["layout"]), fuzz_can.FS_HZ, max_block_s=data["max_block_s"])
        blocks = fuzz_can.drain(source)
    if isinstance(blocks, str):
        return blocks
    if (beyond := memory_verdict(ctx, peak, PEAK_RSS_BOUND_MIB)) is not None:
        return beyond
    verdict = fuzz_can.check_blocks(blocks, source.counters)
    if verdict is not None or data["frames"] is None:
        return verdict
    frames = data["frames"]
    counts, _ = fuzz_can.reference(data["layout"], frames)
    return fuzz_can.check_counts(source.counters, counts, frames)


TARGETS = [fuzz_core.Target("canlog-sqlite", generate, run)]
