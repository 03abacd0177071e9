"""Fuzz targets of compressed recordings: .csv.gz and .parquet files through the reading path of
`bogiemon replay` (drivers/replay.py's RecordingReplaySource, block by block) and `bogiemon analyze`
(daemon/analysis.py's open_recording and analyze_recording, window by window; `bogiemon calibrate`
reads its recordings through the same two).

recording-gz: the CSV inputs of the csv target (valid and mutated) gzip-compressed at any level,
in one member or several, then damaged as gzip streams (cut anywhere, header and trailer fields
changed, deflate bits flipped, trailing bytes, a stream inside a stream, a Parquet file inside),
bz2 and xz files (no reader decompresses them: refused as they are, under any name, bombs too),
and decompression bombs: a small gzip holding a line of up to 4 GiB, a huge file of blank lines or
of padded rows, or a stream just under and just over drivers/files.py's bound (100 times its size).
recording-parquet: recordings from the product's writer and from pyarrow with other options
(codecs, dictionary or not, page versions, row groups of 1 row to the 1 048 576 allowed and one
more, empty row groups), with the wrong schema (names, order, types, nested, extra or missing
columns), nulls, NaN, times that go back or jump, and damage to the bytes: the footer's thrift
fields replaced (row counts and sizes that lie, offsets, schema types and repetitions, codecs),
page headers that lie about their sizes and counts (the file's offsets moved to match), the footer
length, the magic, bit flips and truncations.

The reference is a plain reader of the whole file: Python's gzip module (bounded as files.py
bounds a stream) and the csv module (fuzz_csv.reference), or pyarrow.parquet.read_table. What the
replay delivers must be exactly the reference's samples (clipped to the converter's range), each
block at its first sample's time and at the file's rate ((n - 1) / (last - first)); what a
recording that ends in an error delivered first must be the reference's first samples, and its
blocks must follow one another at the rate they claim. A valid recording must be read whole. One
short input in four is also analysed as `analyze` does, with 2 s windows: the windows must be the ones
the reference's samples hold, at their samples' times. The peak RSS of each input's reading
(VmHWM after /proc/self/clear_refs) is bounded: PEAK_RSS_BOUND_MIB.
"""

from __future__ import annotations

import bz2
import csv
import functools
import gzip
import io
import lzma
import math
import os
import random
import re
import struct
import sys
import tempfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

import fuzz_core
import fuzz_csv
from fuzz_memory import PeakRss, memory_verdict
from fuzz_parquet_bytes import encode_struct, int_fields, join_parquet, move_offsets, page_headers, split_parquet
from bogiemon.daemon.analysis import analyze_recording, open_recording
from bogiemon.daemon.config import BogiemonConfig, parse_config
from bogiemon.drivers.base import EndOfStream
from bogiemon.drivers.columns import ColumnMap
from bogiemon.drivers.files import MIN_INFLATED_BYTES
from bogiemon.drivers.recording import (
    COLUMNS,
    MAX_ACCEL_MPS2,
    MAX_INFLATE_RATIO,
    MAX_LINE_BYTES,
    MAX_PARQUET_GROUP_ROWS,
    MAX_RECORDING_BYTES,
    MIN_ACCEL_MPS2,
    RecordingError,
    write_recording,
)
from bogiemon.drivers.replay import RecordingReplaySource

# The most an input's reading may add to the worker's resident memory (its peak over its RSS
# before), measured in the full run of make fuzz (seed 17): see the module's figures in the README.
PEAK_RSS_BOUND_MIB = {"recording-gz": 96.0, "recording-parquet": 192.0}
RATES_HZ = (500.0, 500.0, 1000.0, 200.0, 100.0, 2000.0, 50.0, 20_000.0, 333.33, 10.0)
HEADER = b"time_s,a1,a2,a3\n"
# `analyze` with 2 s windows every second (the shipped 120 s would refuse most fuzzed files as too short).
ANALYZE_CONFIG = """
[processing]
window_s = 2.0
hop_s = 1.0
max_lag_s = 0.5
highpass_hz = 0.5
lowpass_hz = 5.0
[health]
structure_checks = false
[decision]
method = "thresholds"
"""
STEP_SLACK = 0.011  # a step may be 1 % off the file's (drivers/recording.py), and rounding


# ---- generating: .csv.gz ----------------------------------------------------------------------


def _gzip_member(data: bytes, level: int, rng: random.Random) -> bytes:
    """One gzip member, with the optional header fields a writer may set."""
    flags, extra = 0, b""
    if rng.random() < 0.1:
        flags |= 0x04  # FEXTRA
        payload = rng.randbytes(rng.randint(0, 40))
        extra += struct.pack("<H", len(payload)) + payload
    if rng.random() < 0.1:
        flags |= 0x08  # FNAME
        extra += b"run.csv\x00"
    if rng.random() < 0.05:
        flags |= 0x10  # FCOMMENT
        extra += b"logger 1.2\x00"
    header = b"\x1f\x8b\x08" + bytes([flags]) + struct.pack("<I", 0) + b"\x00\xff" + extra
    if rng.random() < 0.05:
        with_crc = bytearray(header)
        with_crc[3] |= 0x02  # FHCRC
        header = bytes(with_crc) + struct.pack("<H", zlib.crc32(bytes(with_crc)) & 0xFFFF)
    packer = zlib.compressobj(level, zlib.DEFLATED, -15)
    body = packer.compress(data) + packer.flush()
    return header + body + struct.pack("<II", zlib.crc32(data), len(data) & 0xFFFFFFFF)


@functools.cache
def _flushed(piece: bytes) -> bytes:
    """Raw deflate of `piece`, byte-aligned and independent of what precedes it (a full flush):
    copies of it concatenated inflate to copies of piece."""
    packer = zlib.compressobj(9, zlib.DEFLATED, -15)
    return packer.compress(piece) + packer.flush(zlib.Z_FULL_FLUSH)


def gzip_bomb(prefix: bytes, piece: bytes, copies: int, suffix: bytes) -> bytes:
    """A gzip member of prefix, `copies` times piece, then suffix, built without inflating it:
    a small file that decompresses to len(piece) * copies bytes. Its CRC is the real one up to
    256 MiB (a reader stops long before the end of a bigger one: its CRC is left zero)."""
    total = len(prefix) + len(piece) * copies + len(suffix)
    crc = 0
    if total <= 256 << 20:
        crc = zlib.crc32(prefix)
        for _ in range(copies):
            crc = zlib.crc32(piece, crc)
        crc = zlib.crc32(suffix, crc)
    tail = zlib.compressobj(9, zlib.DEFLATED, -15)
    body = _flushed(prefix) + _flushed(piece) * copies + tail.compress(suffix) + tail.flush()
    return b"\x1f\x8b\x08\x00\x00\x00\x00\x00\x02\xff" + body + struct.pack("<II", crc, total & 0xFFFFFFFF)


def _written(suffix: str, time_s: np.ndarray, accel: np.ndarray) -> bytes:
    """The bytes drivers/recording.py's writer writes for these samples (it takes a path: a temporary one)."""
    with tempfile.TemporaryDirectory(prefix="bogiemon-fuzz-gen-", dir="/dev/shm" if os.access("/dev/shm", os.W_OK) else None) as folder:
        path = Path(folder) / f"run{suffix}"
        write_recording(path, time_s, accel)
        return path.read_bytes()


def _rows_text(rng: random.Random, n: int, fs_hz: float, start_s: float) -> bytes:
    """The product's CSV of n rows at fs_hz (6 decimals), as the recorder writes it before compressing."""
    accel = np.random.default_rng(rng.randrange(2**32)).normal(9.81, 3.0, (n, 3))
    return _written(".csv", start_s + np.arange(n) / fs_hz, accel)


def generate_gz(rng: random.Random) -> fuzz_core.Input:
    """A .csv.gz recording: the csv target's file compressed, damaged as a stream, or a bomb."""
    kind = rng.choices(
        ("csv", "big", "members", "cut", "flip", "trailer", "header", "trailing", "nested", "parquet", "not_gzip", "bytes",
         "bomb_line", "bomb_blank", "bomb_padded", "bomb_edge", "bz2", "xz"),
        weights=(30, 3, 6, 8, 6, 4, 3, 4, 1, 1, 2, 6, 3, 2, 2, 3, 2, 2),
    )[0]  # fmt: skip
    csv_input = fuzz_csv.generate(rng)
    text, valid = csv_input["file"], csv_input["valid"]
    level = rng.choice((1, 6, 6, 9, 0))
    name = rng.choice(("run.csv.gz",) * 8 + ("run.csv", "RUN.CSV.GZ"))  # gzip by its name, or by its magic alone
    if kind == "big":
        n = rng.choice((20_000, 50_000, 100_000))
        text, valid = _rows_text(rng, n, rng.choice(RATES_HZ[:6]), rng.choice((0.0, 1.7e9))), True
    raw = _gzip_member(text, level, rng)
    if kind == "members":  # several members, one of them maybe empty: one stream for every reader
        cuts = sorted(rng.randint(0, len(text)) for _ in range(rng.randint(1, 4)))
        pieces = [text[a:b] for a, b in zip([0, *cuts], [*cuts, len(text)], strict=True)]
        raw = b"".join(_gzip_member(p, level, rng) for p in pieces)
    elif kind == "cut":
        raw, valid = raw[: rng.randint(0, len(raw) - 1)], False
    elif kind == "flip":
        out = bytearray(raw)
        for _ in range(rng.randint(1, 8)):
            i = rng.randrange(10, len(out)) if len(out) > 10 else rng.randrange(len(out))
            out[i] ^= 1 << rng.randrange(8)
        raw, valid = bytes(out), False
    elif kind == "trailer":  # the CRC or the length of the data wrong
        out = bytearray(raw)
        at = len(out) - rng.choice((8, 4))
        out[at : at + 4] = rng.choice((bytes(4), b"\xff" * 4, rng.randbytes(4)))
        raw, valid = bytes(out), valid and bytes(out) == raw
    elif kind == "header":  # method, flags, or an extra field that lies about its length
        out = bytearray(raw)
        choice = rng.randrange(4)
        if choice == 0:
            out[2] = rng.choice((0, 7, 9, 255))
        elif choice == 1:
            out[3] = rng.choice((0x04, 0x08, 0x10, 0x02, 0xE0, 0xFF))
        elif choice == 2:
            out[3] |= 0x04
            out[10:10] = struct.pack("<H", rng.choice((0, 1, 1000, 65535)))
        else:
            out[0:2] = rng.choice((b"\x1f\x8c", b"\x00\x00", b"\x1f"))
        raw, valid = bytes(out), False
    elif kind == "trailing":
        tail = rng.choice((bytes(rng.randint(1, 600)), b"garbage", rng.randbytes(rng.randint(1, 40)), b"\x1f\x8b", b"\n"))
        raw, valid = raw + tail, valid and not any(tail)
    elif kind == "nested":
        raw, valid = _gzip_member(raw, level, rng), False
    elif kind == "parquet":
        raw, valid = _gzip_member(_parquet_valid(rng, rng.randint(2, 200)), level, rng), False
    elif kind == "not_gzip":
        name, valid = "run.csv.gz", False
        raw = rng.choice((text, rng.randbytes(rng.randint(0, 200)), b"\x1f\x8b"))
    elif kind == "bytes":
        raw, valid = fuzz_core.Mutator(rng).bytes(raw), False
    elif kind == "bomb_line":  # one line of up to 4 GiB in a file of a few MB at most
        size = rng.choice((1 << 20, 2 << 20, 64 << 20, 512 << 20, 4 << 30))
        where = rng.choice(("header", "row", "end"))
        prefix = b"" if where == "header" else HEADER + b"0.0,1,2,3\n" * rng.randint(0, 3000)
        piece = rng.choice((b"1", b" ", b"x", b"\xff", b","))
        raw, valid = gzip_bomb(prefix, piece * 65536, size // 65536, b"\n" if where != "end" else b""), False
    elif kind == "bomb_blank":  # blank lines hold no row: a valid file of mostly nothing
        rows = b"".join(b"%d,1,2,3\n" % i for i in range(rng.randint(2, 50)))
        piece = rng.choice((b"\n", b"\r\n", b"\r"))
        copies = rng.choice((1 << 16, 1 << 20, 1 << 24)) // 1024
        raw, valid = gzip_bomb(HEADER + rows, piece * 1024, copies, b""), False
    elif kind == "bomb_padded":  # rows padded with spaces to near the longest line a reader takes
        pad = rng.choice((1000, 100_000, MAX_LINE_BYTES - 20, MAX_LINE_BYTES + 1))
        rows = b"".join(b"%d," % i + b" " * pad + b"1,2,3\n" for i in range(rng.randint(2, 6)))
        raw, valid = gzip_bomb(HEADER, rows, rng.choice((1, 1, 50)), b""), False
    elif kind == "bomb_edge":  # decompressing to just under, at, or just over the bound
        body = _rows_text(rng, rng.choice((2, 3, 1000)), 500.0, 0.0)
        raw = _gzip_member(body, 9, rng)
        filler_n = max(0, _inflate_bound(len(raw) + 64) - len(body) + rng.choice((-4096, -1, 0, 1, 4096)))
        raw = gzip_bomb(body, b"\n" * 1024, filler_n // 1024, b"\n" * (filler_n % 1024))
        valid = False
    elif kind in ("bz2", "xz"):  # formats no reader decompresses: refused as they are, never inflated
        raw = _other_compression(kind, text) if rng.random() < 0.5 else _other_bomb(kind, rng.choice((1 << 20, 16 << 20)))
        name, valid = rng.choice((f"run.csv.{kind}", f"run.csv.{kind}", "run.csv", "run.csv.gz", "run.parquet")), False
    return {"file": raw, "name": name, "valid": valid and kind in ("csv", "big", "members", "trailing", "trailer"),
            "kind": kind, "analyze": rng.random() < 0.25 and kind != "big", "max_block_s": rng.choice((1.0, 1.0, 0.1, 0.02, 7.0))}  # fmt: skip


def _other_compression(kind: str, data: bytes) -> bytes:
    return bz2.compress(data) if kind == "bz2" else lzma.compress(data)


@functools.cache
def _other_bomb(kind: str, size: int) -> bytes:
    """A recording's header and row, then `size` bytes of blank lines, bz2- or xz-compressed (a few KiB)."""
    return _other_compression(kind, HEADER + b"0,1,2,3\n0.002,1,2,3\n" + b"\n" * size)


def _inflate_bound(compressed_bytes: int) -> int:
    """What drivers/files.py lets a gzip stream of that size decompress to (the reference's copy of the bound)."""
    return min(MAX_RECORDING_BYTES, max(MIN_INFLATED_BYTES, int(MAX_INFLATE_RATIO * compressed_bytes)))


# ---- generating: .parquet -----------------------------------------------------------------------


def _samples(rng: random.Random, n: int) -> tuple[np.ndarray, np.ndarray]:
    """n rows at a uniform rate: times and accelerations, some beyond the converter's range."""
    fs_hz = rng.choice(RATES_HZ)
    start_s = rng.choice((0.0, 1.7e9, -50.0, 1e-3, rng.uniform(-1e4, 1e4)))
    time_s = start_s + np.arange(n) / fs_hz
    accel = np.random.default_rng(rng.randrange(2**32)).normal(9.81, rng.choice((0.5, 3.0, 60.0)), (n, 3))
    if rng.random() < 0.1 and n:
        accel[rng.randrange(n), rng.randrange(3)] = rng.choice((math.inf, -math.inf, 1e300, 157.0, -157.0))
    if rng.random() < 0.1:
        accel = np.round(accel / 0.0048) * 0.0048  # a 16-bit converter's steps: what the dictionary is for
    return time_s, accel


def _table(time_s: np.ndarray, accel: np.ndarray, nullable: bool = False) -> pa.Table:
    schema = pa.schema([pa.field(name, pa.float64(), nullable=nullable) for name in COLUMNS])
    return pa.Table.from_arrays([pa.array(time_s), *(pa.array(np.ascontiguousarray(accel[:, i])) for i in range(3))], schema=schema)


def _write(table: pa.Table, rng: random.Random, row_group_rows: int | None = None) -> bytes:
    """The table as pyarrow writes it with options drawn from rng (what other writers do)."""
    sink = pa.BufferOutputStream()
    pq.write_table(
        table, sink,
        # Row groups and pages of a few rows only in small files: a footer and page headers of
        # thousands of entries take seconds to write and to damage, and say nothing more.
        row_group_size=row_group_rows or rng.choice((1, 7, 1000, 65536, max(1, table.num_rows)) if table.num_rows <= 300 else (1000, 65536, table.num_rows)),
        compression=rng.choice(("zstd", "snappy", "gzip", "none", "lz4", "brotli")),
        use_dictionary=rng.random() < 0.6,
        data_page_version=rng.choice(("1.0", "2.0")),
        data_page_size=rng.choice((1 << 20, 8192, 1024, 64) if table.num_rows <= 3000 else (1 << 20, 65536)),
        write_statistics=rng.random() < 0.8,
        use_byte_stream_split=rng.random() < 0.2 and ["time_s"],
        store_schema=rng.random() < 0.9,
    )  # fmt: skip
    return sink.getvalue().to_pybytes()


def _parquet_valid(rng: random.Random, n: int) -> bytes:
    """A valid Parquet recording of n rows: the product's writer's, or pyarrow's with other options."""
    time_s, accel = _samples(rng, n)
    if rng.random() < 0.5:
        return _written(".parquet", time_s, accel)
    return _write(_table(time_s, accel, nullable=rng.random() < 0.3), rng)


def _wrong_schema(rng: random.Random, n: int) -> bytes:
    time_s, accel = _samples(rng, n)
    columns: list[tuple[str, pa.Array]] = [(name, pa.array(values)) for name, values in zip(COLUMNS, [time_s, *accel.T], strict=True)]
    kind = rng.randrange(9)
    if kind == 0:
        rng.shuffle(columns)
    elif kind == 1:
        i = rng.randrange(4)
        columns[i] = (rng.choice(("Time_s", "time", "a4", "", "a1 ", "\u00e91")), columns[i][1])
    elif kind == 2:
        i = rng.randrange(4)
        columns[i] = (columns[i][0], columns[i][1].cast(rng.choice((pa.float32(), pa.float16(), pa.int64(), pa.int32(), pa.decimal128(38, 6))), safe=False))
    elif kind == 3:
        i = rng.randrange(4)
        columns[i] = (columns[i][0], pa.array([repr(v) for v in columns[i][1].to_pylist()]))
    elif kind == 4:
        columns.append((rng.choice(("a4", "speed_kmh", "time_s")), pa.array(time_s)))
    elif kind == 5:
        del columns[rng.randrange(4)]
    elif kind == 6:
        i = rng.randrange(4)
        columns[i] = (columns[i][0], pa.array([[v] for v in columns[i][1].to_pylist()]))
    elif kind == 7:
        i = rng.randrange(4)
        columns[i] = (columns[i][0], columns[i][1].dictionary_encode())
    else:
        i = rng.randrange(4)
        columns[i] = (columns[i][0], pa.array((time_s * 1e6).astype("int64")).cast(pa.timestamp("us")))
    return _write(pa.table(dict(columns)) if len({c[0] for c in columns}) == len(columns) else pa.Table.from_arrays(
        [c[1] for c in columns], names=[c[0] for c in columns]), rng)  # fmt: skip


def _bad_rows(rng: random.Random, n: int) -> bytes:
    """The right schema, wrong values: nulls, NaN, times that go back, jump or are absurd."""
    time_s, accel = _samples(rng, max(n, 2))
    n = time_s.shape[0]
    i = rng.randrange(n)
    kind = rng.randrange(5)
    if kind == 0:
        mask = np.zeros(n, dtype=bool)
        mask[[rng.randrange(n) for _ in range(rng.randint(1, 5))]] = True
        column = rng.randrange(4)
        arrays = [pa.array(time_s), *(pa.array(np.ascontiguousarray(accel[:, j])) for j in range(3))]
        arrays[column] = pa.array(np.asarray(arrays[column]), mask=mask)
        table = pa.Table.from_arrays(arrays, schema=pa.schema([pa.field(c, pa.float64()) for c in COLUMNS]))
        return _write(table, rng)
    if kind == 1:
        accel[i, rng.randrange(3)] = math.nan
    elif kind == 2:
        time_s[i] = rng.choice((math.nan, math.inf, -math.inf, 1e300, time_s[i - 1] if i else -1.0))
    elif kind == 3:
        time_s[i:] += rng.choice((1.0, -1.0, 0.5)) * (time_s[1] - time_s[0]) * rng.choice((1, 5, 1000))
    else:
        time_s = time_s[::-1].copy()
    return _write(_table(time_s, accel, nullable=True), rng)


def _big_group(rng: random.Random) -> bytes:
    """A row group at the bound the reader allows, or one row over it: cheap values, a small file."""
    n = MAX_PARQUET_GROUP_ROWS + rng.choice((0, 0, 1))
    time_s = np.arange(n) / 1000.0
    accel = np.broadcast_to(np.array([9.81, 0.0, -1.0]), (n, 3))
    sink = pa.BufferOutputStream()
    pq.write_table(_table(time_s, accel), sink, row_group_size=n, compression="zstd", use_dictionary=["a1", "a2", "a3"])
    return sink.getvalue().to_pybytes()


INTERESTING_SIZES = (0, 1, -1, 2, 7, 64, 4095, 65535, 65536, 65537, 1 << 20, (1 << 20) + 1, 2**31 - 1, -(2**31), 2**32, 2**40, 2**62, -(2**63))


def _damage_footer(rng: random.Random, raw: bytes) -> bytes:
    parts = split_parquet(raw)
    if parts is None:
        return fuzz_core.Mutator(rng).bytes(raw)
    body, footer = parts
    targeted = rng.random() < 0.6
    fields = int_fields(footer)
    wanted: tuple[tuple[int, ...], ...] = ((3,), (4, -1, 3), (4, -1, 2), (4, -1, 1, -1, 3, 5), (4, -1, 1, -1, 3, 6), (4, -1, 1, -1, 3, 7),
                                           (4, -1, 1, -1, 3, 9), (4, -1, 1, -1, 3, 11), (4, -1, 1, -1, 3, 4), (4, -1, 1, -1, 3, 1),
                                           (2, -1, 1), (2, -1, 3), (2, -1, 5), (2, -1, 6))  # fmt: skip

    def matches(path: tuple[Any, ...], pattern: tuple[int, ...]) -> bool:
        return len(path) == len(pattern) and all(p == -1 or p == q for p, q in zip(pattern, path, strict=True))

    if targeted:
        pattern = rng.choice(wanted)
        fields = [f for f in fields if matches(f[2], pattern)] or fields
    for _ in range(rng.randint(1, 3)):
        if not fields:
            break
        struct_, index, path = rng.choice(fields)
        old = struct_[index][2]
        struct_[index][2] = rng.choice((*INTERESTING_SIZES, old + 1, old - 1, old * 2, old // 2, rng.randint(-8, 8)))
    return join_parquet(body, footer)


def _damage_page(rng: random.Random, raw: bytes) -> bytes:
    """A page header that lies about its sizes or counts (the file's offsets moved to match)."""
    parts = split_parquet(raw)
    if parts is None:
        return fuzz_core.Mutator(rng).bytes(raw)
    body, footer = parts
    headers = page_headers(body, footer)
    if not headers:
        return _damage_footer(rng, raw)
    start, end, header = rng.choice(headers)
    fields = int_fields(header)
    if rng.random() < 0.7:  # the sizes, the counts, the page type
        fields = [f for f in fields if f[2] in ((1,), (2,), (3,), (5, 1), (7, 1), (8, 1), (8, 2), (8, 3), (8, 5), (8, 6), (5, 2))] or fields
    if not fields:
        return raw
    struct_, index, _ = rng.choice(fields)
    old = struct_[index][2]
    struct_[index][2] = rng.choice((*INTERESTING_SIZES, old + 1, old - 1, old * 2, old // 2, old * 1000))
    encoded = encode_struct(header)
    move_offsets(footer, start, len(encoded) - (end - start))
    return join_parquet(body[:start] + encoded + body[end:], footer)


def generate_parquet(rng: random.Random) -> fuzz_core.Input:
    kind = rng.choices(
        ("valid", "schema", "rows", "big_group", "empty", "footer", "page", "footer_length", "magic", "flip", "cut", "bytes", "gzip"),
        weights=(22, 8, 10, 1, 3, 18, 14, 3, 2, 8, 4, 6, 1),
    )[0]  # fmt: skip
    n = rng.choice((2, 3, rng.randint(2, 50), rng.randint(50, 3000), rng.randint(3000, 70_000)))
    raw = _parquet_valid(rng, n)
    valid = kind == "valid"
    if kind == "schema":
        raw = _wrong_schema(rng, n)
    elif kind == "rows":
        raw = _bad_rows(rng, n)
    elif kind == "big_group":
        raw = _big_group(rng)
        valid = pq.ParquetFile(pa.BufferReader(raw)).metadata.row_group(0).num_rows <= MAX_PARQUET_GROUP_ROWS  # one row over it: refused
    elif kind == "empty":
        time_s, accel = _samples(rng, rng.choice((0, 1, 2)))
        sink = pa.BufferOutputStream()
        with pq.ParquetWriter(sink, _table(time_s, accel).schema) as writer:
            for _ in range(rng.randint(0, 3)):
                writer.write_table(_table(time_s[:0], accel[:0]))
            writer.write_table(_table(time_s, accel))
            writer.write_table(_table(time_s[:0], accel[:0]))
        raw = sink.getvalue().to_pybytes()
    elif kind == "footer":
        raw = _damage_footer(rng, raw)
    elif kind == "page":
        raw = _damage_page(rng, raw)
    elif kind == "footer_length":
        out = bytearray(raw)
        out[-8:-4] = struct.pack("<I", rng.choice((0, 1, 8, len(raw) - 8, len(raw), 2**31, 2**32 - 1, struct.unpack("<I", raw[-8:-4])[0] + rng.choice((-1, 1)))))
        raw = bytes(out)
    elif kind == "magic":
        raw = rng.choice((raw[:-4] + b"PAR0", b"XXXX" + raw[4:], raw[:-4], b"PAR1", b"PAR1PAR1", b"PAR1" + bytes(8) + b"PAR1"))
    elif kind == "flip":
        out = bytearray(raw)
        for _ in range(rng.randint(1, 6)):
            i = rng.randrange(len(out))
            out[i] ^= 1 << rng.randrange(8)
        raw = bytes(out)
    elif kind == "cut":
        raw = raw[: rng.randint(0, len(raw) - 1)]
    elif kind == "bytes":
        raw = fuzz_core.Mutator(rng).bytes(raw)
    elif kind == "gzip":
        raw = _gzip_member(raw, 6, rng)
    name = rng.choice(("run.parquet",) * 9 + ("run.csv",))  # Parquet by its name, or by its magic alone
    if kind == "gzip":
        name = rng.choice(("run.parquet", "run.parquet.gz"))
    # Analysed only when short: thousands of windows take longer than the input's time limit, and tell nothing more.
    return {"file": raw, "name": name, "valid": valid, "kind": kind, "analyze": rng.random() < 0.25 and n <= 20_000,
            "max_block_s": rng.choice((1.0, 1.0, 0.1, 0.02, 7.0))}  # fmt: skip


# ---- the references ---------------------------------------------------------------------------

Samples = tuple[np.ndarray, np.ndarray]  # time_s (n,), accel_mps2 (n, 3) clipped


def _inflate(raw: bytes, bound: int) -> bytes | str:
    """The gzip stream decompressed, or why not: past the bound, damaged, or a line longer than
    MAX_LINE_BYTES (where decompressing stops, as a reader that refuses it does: a line of a
    bomb would otherwise be inflated to hundreds of MiB here, beyond an input's time)."""
    chunks: list[bytes] = []
    total = line_n = 0  # line_n: the length of the line still open at the end of what was read
    try:
        with gzip.GzipFile(fileobj=io.BytesIO(raw)) as stream:
            while chunk := stream.read(1 << 20):
                total += len(chunk)
                if total > bound:
                    return f"decompresses to more than {bound} bytes"
                byte = np.frombuffer(chunk, np.uint8)
                breaks = np.flatnonzero((byte == 10) | (byte == 13))  # LF, CR
                if breaks.size:
                    longest = max(line_n + int(breaks[0]), int(np.diff(breaks).max()) - 1 if breaks.size > 1 else 0)
                    line_n = len(chunk) - int(breaks[-1]) - 1
                else:
                    longest = line_n = line_n + len(chunk)
                if max(longest, line_n) > MAX_LINE_BYTES:
                    return "a line longer than 1 MiB"
                chunks.append(chunk)
    except (OSError, EOFError, zlib.error) as exc:
        return f"not a whole gzip stream ({exc})"
    return b"".join(chunks)


def reference_gz(raw: bytes, name: str) -> Samples | str:
    """What Python's gzip module (within files.py's bound) and the csv module read, or why they cannot."""
    gzipped = name.lower().endswith(".gz") or raw[:2] == b"\x1f\x8b"
    data = raw
    if gzipped:
        inflated = _inflate(raw, _inflate_bound(len(raw)))
        if isinstance(inflated, str):
            return inflated
        data = inflated
    if any(len(line.group()) > MAX_LINE_BYTES for line in re.finditer(rb"[^\r\n]+", data)):
        return "a line longer than 1 MiB"
    # Runs of line breaks as one: blank lines hold no row (csv gives them as empty rows, skipped),
    # and a bomb of millions of them would take the csv module's list of rows past the memory limit.
    data = re.sub(rb"[\r\n]+", b"\n", data)
    csv.field_size_limit(sys.maxsize)
    try:
        ref = fuzz_csv.reference(data)
    except csv.Error as exc:
        return f"the csv module cannot read it ({exc})"
    if isinstance(ref, str):
        return ref
    times, accel = ref
    return np.array(times, dtype=np.float64), np.array(accel, dtype=np.float64).reshape(-1, 3)


def reference_parquet(path: Path) -> Samples | str:
    """What pyarrow's whole-file reader reads, or why it cannot (nulls are no readings: refused):
    the columns of the default mapping by name (drivers/columns.py), numbers as float64."""
    try:
        table = pq.read_table(path, use_threads=False)
    except (pa.ArrowException, OSError, ValueError, MemoryError) as exc:
        return f"pyarrow cannot read it ({str(exc)[:100]})"
    names = table.schema.names
    try:
        selected = ColumnMap().select(names)
    except ValueError:
        return f"the schema is {names}"
    if any(names.count(name) != 1 for name in selected):
        return f"the schema is {names}"
    table = table.select(selected)
    if not all(pa.types.is_floating(t) or pa.types.is_integer(t) for t in table.schema.types):
        return f"the schema is {table.schema}"
    table = pa.table([c.cast(pa.float64(), safe=False) for c in table.columns], names=list(COLUMNS))
    if table.num_rows:  # a time column's unit by its name, else its first value's magnitude
        first = table.column(0)[0].as_py()
        to_s = ColumnMap().resolved_time_unit(selected[0], first).to_s
        if to_s != 1.0:
            table = table.set_column(0, "time_s", pc.multiply(table.column(0), to_s))
    if any(column.null_count for column in table.columns):
        return "a value is null"
    time_s = table.column(0).to_numpy()
    accel = np.column_stack([table.column(i).to_numpy() for i in (1, 2, 3)]) if table.num_rows else np.empty((0, 3))
    if np.isnan(time_s).any() or np.isnan(accel).any():
        return "a value is NaN"
    return time_s.astype(np.float64), np.clip(accel.astype(np.float64), MIN_ACCEL_MPS2, MAX_ACCEL_MPS2)


# ---- one input --------------------------------------------------------------------------------


@functools.cache
def analyze_config() -> BogiemonConfig:
    return parse_config(ANALYZE_CONFIG, "fuzz")


def _first_bad_step(blocks: list[tuple[float, int, bool]], fs_hz: float) -> str | None:
    """Blocks (start_s, n, gap_before) that do not follow one another at the rate they claim: n / fs_hz
    apart, but where the next one says a gap comes before it (then later than that)."""
    for (start_s, n, _), (next_s, _, gap) in zip(blocks, blocks[1:], strict=False):
        claimed_s = n / fs_hz
        if gap:
            if not next_s - start_s > claimed_s:
                return f"a block after a gap starts at {next_s!r}, within the block before it ({start_s!r} + {claimed_s:.6g} s)"
            continue
        if not abs((next_s - start_s) - claimed_s) <= STEP_SLACK * claimed_s:
            return f"a block of {n} samples at {fs_hz:.6g} Hz starts at {start_s!r}, the next {next_s - start_s:.6g} s later, not {claimed_s:.6g} s"
    return None


def _replay(path: Path, max_block_s: float, ref: Samples | None) -> tuple[list[tuple[float, int, bool]], float, str | None, RecordingError | None, bool]:
    """Replay the file as `bogiemon replay` reads it, each block checked against the reference as it
    comes: its samples exactly, or, once jittered times were resampled onto the grid, within the
    range of the reference's (an interpolation never leaves it; tests/drivers compares the values
    with a whole-file interpolation). The last value: whether the file was on one grid without a
    gap (its samples exactly the reference's rows)."""
    blocks: list[tuple[float, int, bool]] = []
    wrong: str | None = None
    source = RecordingReplaySource(path, rate=0.0, max_block_s=max_block_s)
    delivered = 0
    try:
        while True:
            try:
                block = source.read(1.0)
            except EndOfStream:
                return blocks, source.fs_hz, wrong, None, _regular(source)
            except RecordingError as exc:
                return blocks, source.fs_hz, wrong, exc, _regular(source)
            if block is None:
                continue
            blocks.append((block.start_s, block.n_samples, block.gap_before))
            if wrong is None and ref is not None and source.counters.extra["resampled_samples"]:
                low, high = ref[1].min(axis=0), ref[1].max(axis=0)
                if not np.all((block.accel_mps2 >= low) & (block.accel_mps2 <= high)):
                    wrong = f"resampled samples {delivered}.. beyond the range of the reference's"
            elif wrong is None and ref is not None:
                time_s, accel = ref
                stop = delivered + block.n_samples
                if stop > time_s.shape[0]:
                    wrong = f"more samples than the reference's {time_s.shape[0]}"
                elif block.start_s != time_s[delivered]:
                    wrong = f"block at {block.start_s!r}, its first sample at {time_s[delivered]!r}"
                elif not np.array_equal(block.accel_mps2, accel[delivered:stop]):
                    wrong = f"samples {delivered}..{stop} differ from the reference's"
            delivered += block.n_samples
    finally:
        source.close()


def _regular(source: RecordingReplaySource) -> bool:
    return not (source.counters.extra["resampled_samples"] or source.counters.extra["recording_gaps"])


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / data["name"]
    path.write_bytes(data["file"])
    parquet = data["name"].lower().endswith(".parquet") or data["file"][:4] == b"PAR1"
    ref = reference_parquet(path) if parquet and not data["name"].lower().endswith(".gz") else reference_gz(data["file"], data["name"])
    samples = ref if not isinstance(ref, str) else None
    target = "recording-parquet" if parquet else "recording-gz"
    with PeakRss() as peak:
        try:
            blocks, fs_hz, wrong, error, regular = _replay(path, data["max_block_s"], samples)
        except RecordingError as exc:  # refused at the open: nothing was delivered
            blocks, fs_hz, wrong, error, regular = [], math.nan, None, exc, True
        windows: list[tuple[float, float]] = []
        analysed: RecordingError | None = None
        if data["analyze"] and error is None:
            try:
                reader = open_recording(path, analyze_config())
                windows = [(w.start_s, w.end_s) for w in analyze_recording(reader, analyze_config())]
            except RecordingError as exc:
                analysed = exc
    if (beyond := memory_verdict(ctx, peak, PEAK_RSS_BOUND_MIB[target])) is not None:
        return beyond
    if wrong is not None:
        return f"replay delivered what the file does not hold: {wrong}"
    if blocks and (step := _first_bad_step(blocks, fs_hz)) is not None:
        return f"blocks at a rate not their samples': {step}"
    if error is not None:
        if data["valid"] and samples is not None:
            return f"rejected a valid recording: {error}"
        raise error
    n = sum(b[1] for b in blocks)
    if samples is None:
        return f"accepted a file the reference cannot read ({ref}): {n} samples at {fs_hz!r} Hz"
    time_s, _ = samples
    if regular and n != time_s.shape[0]:
        return f"delivered {n} samples of the reference's {time_s.shape[0]}"
    # The rate is the file's steps' (drivers/recording_check.py: snapped to the whole hertz within
    # 0.05 %): the median step of a file on one grid, with or without jitter and gaps.
    median_step_s = float(np.median(np.diff(time_s)))
    if not abs(fs_hz * median_step_s - 1.0) <= STEP_SLACK:
        return f"a rate of {fs_hz!r} Hz, the file's median step is {median_step_s!r} s"
    if not regular:
        return None  # the windows of a file with gaps or resampled: tests/daemon checks them
    if analysed is not None:
        raise analysed
    if data["analyze"]:
        return _check_windows(windows, time_s, fs_hz)
    return None


def _check_windows(windows: list[tuple[float, float]], time_s: np.ndarray, fs_hz: float) -> fuzz_core.Verdict:
    """The windows `analyze` gave: as many as the samples hold, each starting at its first sample's time."""
    settings = analyze_config().processing_settings(fs_hz=fs_hz)
    window_n, hop_n = settings.window_n, settings.hop_n
    expected = (time_s.shape[0] - window_n) // hop_n + 1 if time_s.shape[0] >= window_n else 0
    if len(windows) != expected:
        return f"analyze gave {len(windows)} windows of {window_n} samples every {hop_n}, the {time_s.shape[0]} samples hold {expected}"
    step_s = 1.0 / fs_hz
    for k, (start_s, _) in enumerate(windows):
        actual_s = time_s[k * hop_n]
        if not abs(start_s - actual_s) <= STEP_SLACK * abs(actual_s - time_s[0]) + step_s:
            return f"analyze's window {k} starts at {start_s!r}, its first sample at {actual_s!r}"
    return None


TARGETS = [fuzz_core.Target("recording-gz", generate_gz, run), fuzz_core.Target("recording-parquet", generate_parquet, run)]
