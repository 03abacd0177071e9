"""Fuzz targets of CAN: the frame decoder (both layouts) and the CAN log readers of `replay`.

Frames are packed by hand from the shipped DBC's layout (a Counter byte, status bits, int16
accelerations), with lost, repeated, reordered and restarted counters, then damaged: payload bits,
lengths, identifiers (foreign, extended, of the DBC's other messages, beyond 29 bits and beyond
64), remote and error frames, and time stamps that are NaN, infinite, negative, tiny, huge or
going back, fed in random batches. The reference classifies and decodes every frame on its own
with cantools' decode_message: the decoder's counters must equal its counts, every delivered
sample must be one it decoded, in order, and a block never bridges a counter jump (hub).

The log targets write such frames with python-can's own writers (.log as candump -L, .asc,
.blf, PEAK .trc, python-can's .csv), damage the files (lines, fields, bytes) and replay them through open_replay as `replay`
does; every intact frame line of a .log, .asc, .trc or .csv must be decoded or counted as bad, never
silently dropped, and the blocks must carry plausible, finite times.
"""

from __future__ import annotations

import functools
import math
import os
import random
import struct
from collections import Counter
from pathlib import Path
from typing import Any

import can
import cantools
import numpy as np

import fuzz_core
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.can_decode import CanFrameDecoder
from bogiemon.drivers.candb import CanLayout, load_layout, shipped_dbc_text
from bogiemon.drivers.replay import open_replay
from bogiemon.drivers.segments import SampleQueue

FS_HZ = 500.0
BLOCK_N = 50
FULL_SCALE_MPS2 = 32768 * 16 * 9.80665 / 32768
CAN_ERR_CRTL, CAN_ERR_BUSOFF = 0x004, 0x040
SYNC_ID, HUB_ID, NODE_IDS = 0x80, 0x100, (0x101, 0x102, 0x103)
ODD_IDS = (0x000, 0x7FF, 0x300, 0x301, 0x80, 0x100, 0x104, 0x1FFFFFFF, 0x80000100, 2**31, 2**32 + 0x100, 2**63, 2**64 + 0x100, 2**70, -1)
ODD_TIMES = (math.nan, math.inf, -math.inf, 0.0, -1.0, -1e9, 5e-324, 1e300, 1e18, 253_402_300_800.0, 1.7e9)


@functools.cache
def db() -> Any:
    return cantools.database.load_string(shipped_dbc_text(), database_format="dbc")


@functools.cache
def layout(name: str) -> CanLayout:
    return load_layout(None, name)


@functools.cache
def dbc_messages() -> dict[tuple[int, bool], Any]:
    return {(m.frame_id, bool(m.is_extended_frame)): m for m in db().messages}


@functools.lru_cache(maxsize=65536)
def cantools_decode(frame_id: int, data: bytes) -> dict[str, float]:
    return dict(db().decode_message(frame_id, data, decode_choices=False, scaling=True))


# A frame as inputs hold it: [timestamp, arbitration id, extended, remote, error frame, data].
Frame = list[Any]


def clean_frames(rng: random.Random, layout_name: str) -> list[Frame]:
    """Frames of consecutive instants, as the sensor hub or the nodes send them, with bus-like anomalies."""
    n = rng.choice((1, 2, 4, rng.randint(5, 20), rng.randint(20, 50)))
    t_s = rng.choice((1000.0, 1.7e9 + rng.uniform(0, 1e6), 0.0, 12.5))
    counter = rng.randrange(256)
    frames: list[Frame] = []
    for k in range(n):
        anomaly = rng.choices(("next", "skip", "repeat", "back", "restart", "pause"), (30, 1, 1, 1, 0.3, 0.3))[0]
        if anomaly == "skip":
            counter += rng.choice((2, 5, 127, 128, 200))
            t_s += 0.002 * rng.randint(1, 5)
        elif anomaly == "back":
            counter -= rng.randint(1, 5)
        elif anomaly == "restart":
            counter = 0
        elif anomaly == "pause":
            t_s += rng.choice((0.3, 1.0, 10.0))
        c = counter % 256
        values = [(k * 37 + 11 * ch + rng.randrange(8)) % 65536 - 32768 for ch in range(3)]
        status = [rng.choice((0, 0, 0, 0, 0, 1, 2, 3)) for _ in range(3)]
        if layout_name == "hub":
            bits = sum(s << (2 * ch) for ch, s in enumerate(status))
            frames.append([t_s, HUB_ID, False, False, False, bytes([c, bits]) + struct.pack("<3h", *values)])
        else:
            if rng.random() < 0.95:
                frames.append([t_s, SYNC_ID, False, False, False, bytes([c])])
            order = [0, 1, 2] if rng.random() < 0.7 else rng.sample([0, 1, 2], 3)
            for position, ch in enumerate(order):
                frames.append([t_s + 1e-4 * (position + 1), NODE_IDS[ch], False, False, False, bytes([c, status[ch]]) + struct.pack("<h", values[ch])])
        if anomaly != "repeat":
            counter += 1
        t_s += 0.002 + rng.choice((0.0, 0.0, 0.0, 1e-5, -1e-5))
    return frames


def mutate_frames(rng: random.Random, frames: list[Frame], n_mutations: int | None = None) -> list[Frame]:
    out = [list(f) for f in frames]
    m = fuzz_core.Mutator(rng)
    for _ in range(n_mutations or rng.randint(1, 5)):
        kind = rng.choice(("drop", "duplicate", "swap", "reverse", "data", "length", "id", "extended", "time", "time",
                           "remote", "error", "foreign", "splice_time"))  # fmt: skip
        if not out:
            out.append([rng.choice(ODD_TIMES), rng.choice(ODD_IDS), rng.random() < 0.5, False, False, m.random_bytes(8)])
            continue
        i = rng.randrange(len(out))
        f = out[i]
        if kind == "drop":
            del out[i : i + rng.randint(1, 8)]
        elif kind == "duplicate":
            out[i:i] = [list(f) for _ in range(rng.randint(1, 3))]
        elif kind == "swap" and i + 1 < len(out):
            out[i], out[i + 1] = out[i + 1], out[i]
        elif kind == "reverse":
            j = min(len(out), i + rng.randint(2, 20))
            out[i:j] = out[i:j][::-1]
        elif kind == "data":
            f[5] = m.bytes(f[5], 1) if f[5] else m.random_bytes(8)
        elif kind == "length":
            f[5] = f[5][: rng.randint(0, 7)] if rng.random() < 0.5 else f[5] + m.random_bytes(rng.choice((1, 4, 56)))
        elif kind == "id":
            f[1] = rng.choice(ODD_IDS) if rng.random() < 0.6 else rng.randrange(2048)
        elif kind == "extended":
            f[2] = not f[2]
        elif kind == "time":
            f[0] = rng.choice(ODD_TIMES) if rng.random() < 0.7 else f[0] + rng.choice((-10.0, -0.5, 1e6, 0.0))
        elif kind == "splice_time":  # every later frame shifted: a clock jump
            shift = rng.choice((-3600.0, -1.0, 1e9, math.nan))
            for g in out[i:]:
                g[0] = g[0] + shift
        elif kind == "remote":
            f[3] = True
        elif kind == "error":
            out.insert(i, [f[0], rng.choice((CAN_ERR_BUSOFF, CAN_ERR_CRTL, 0x20000080, rng.randrange(2**29))), False, False, True,
                           bytes([0, rng.choice((0, 1)), 0, 0, 0, 0, 0, 0])[: rng.randint(0, 8)]])  # fmt: skip
        elif kind == "foreign":
            out.insert(i, [f[0], rng.randrange(2**29) if rng.random() < 0.5 else rng.randrange(2048), rng.random() < 0.3,
                           False, False, m.random_bytes(8)])  # fmt: skip
    return out


def message(frame: Frame) -> can.Message:
    t_s, frame_id, extended, remote, error, data = frame
    return can.Message(timestamp=t_s, arbitration_id=frame_id, is_extended_id=extended, is_remote_frame=remote,
                       is_error_frame=error, data=data, dlc=len(data))  # fmt: skip


# ---- the reference --------------------------------------------------------------------------


def reference(layout_name: str, frames: list[Frame]) -> tuple[Counter[str], list[tuple[int, dict[str, float]]]]:
    """Counts per category, and the well-formed frames of the layout decoded by cantools: (position, signals)."""
    lay = layout(layout_name)
    mine = {(m.frame_id, m.is_extended): m for m in lay.messages}
    counts: Counter[str] = Counter()
    decoded: list[tuple[int, dict[str, float]]] = []
    for i, (_, frame_id, extended, remote, error, data) in enumerate(frames):
        if error:
            counts["error_frames"] += 1
            if frame_id & CAN_ERR_BUSOFF:
                counts["bus_off"] += 1
            continue
        if remote:
            counts["remote_frames"] += 1
            counts["bad_frames"] += 1
            continue
        key = (frame_id, bool(extended))
        if key in mine:
            if len(data) == mine[key].length:
                counts["frames"] += 1
                decoded.append((i, {"id": frame_id, **cantools_decode(frame_id, bytes(data))}))
            else:
                counts["wrong_length"] += 1
                counts["bad_frames"] += 1
        elif key in dbc_messages():
            counts["other_dbc_frames"] += 1
        else:
            counts["unknown_ids"] += 1
            counts["bad_frames"] += 1
    return counts, decoded


COUNTED = ("frames", "bad_frames", "unknown_ids", "wrong_length", "remote_frames", "other_dbc_frames", "error_frames", "bus_off")
# Time stamps no design of the time-stamp check may refuse: Unix time up to 2096, never going back.
SURE_TIME_S = (0.0, 4e9)


def check_counts(counters: HealthCounters, counts: Counter[str], frames: list[Frame]) -> fuzz_core.Verdict:
    """Every frame lands in exactly one place; with sure time stamps, each in the reference's place.

    A frame with a time stamp that is not finite, not plausible or going back may be refused as a
    bad frame (how far back is the source's choice): then only the sums are checked, and that the
    decoder accepted no more than the reference.
    """
    got = {"frames": counters.frames, "bad_frames": counters.bad_frames, **counters.extra}
    sure = True
    latest_s = -math.inf
    for f in frames:
        if not f[4]:
            sure = sure and SURE_TIME_S[0] <= f[0] <= SURE_TIME_S[1] and f[0] >= latest_s
            latest_s = max(latest_s, f[0]) if f[0] == f[0] else latest_s
    if sure:
        for name in COUNTED:
            if got.get(name, 0) != counts.get(name, 0):
                return f"counter {name} differs from the reference: {got.get(name, 0)}, expected {counts.get(name, 0)}"
        return None
    received = sum(1 for f in frames if not f[4])
    placed = got["frames"] + got["bad_frames"] + got.get("other_dbc_frames", 0)
    if placed != received:
        return f"frames not accounted for: {received} received, {got['frames']} accepted + {got['bad_frames']} bad + {got.get('other_dbc_frames', 0)} other"
    if got.get("error_frames", 0) != counts.get("error_frames", 0):
        return f"counter error_frames differs from the reference: {got.get('error_frames', 0)}, expected {counts.get('error_frames', 0)}"
    for name in ("frames", "other_dbc_frames"):
        if got.get(name, 0) > counts.get(name, 0):
            return f"counter {name} above the reference: {got.get(name, 0)}, at most {counts.get(name, 0)}"
    return None


def check_blocks(blocks: list[Any], counters: HealthCounters) -> fuzz_core.Verdict:
    """Plausible times, going back only where the source counted its clock stepping back; samples in range."""
    previous_end_s: float | None = None
    steps_back = 0
    for block in blocks:
        if fuzz_core.implausible_time(block.start_s):
            return f"implausible block time: start_s {block.start_s!r}"
        if previous_end_s is not None and block.start_s < previous_end_s - fuzz_core.BACKWARD_TOLERANCE_S:
            steps_back += 1
            if steps_back > counters.extra.get("clock_steps", 0):
                return f"block time goes back without a counted clock step: {block.start_s!r} after a block ending at {previous_end_s!r}"
        previous_end_s = block.end_s
        if block.fs_hz != FS_HZ:
            return f"block rate {block.fs_hz!r} Hz, configured {FS_HZ}"
        if not np.isfinite(block.accel_mps2).all() or np.abs(block.accel_mps2).max(initial=0) > FULL_SCALE_MPS2:
            return "sample beyond full scale or not finite"
    return None


def check_samples(layout_name: str, blocks: list[Any], decoded: list[tuple[int, dict[str, float]]]) -> fuzz_core.Verdict:
    if layout_name == "hub":
        rows = [(tuple(s[f"Accel{c}"] for c in (1, 2, 3)), int(s["Counter"])) for _, s in decoded]
        j = 0
        last_counter: int | None = None
        for block in blocks:
            if block.gap_before:
                last_counter = None
            for sample in block.accel_mps2.tolist():
                while j < len(rows) and tuple(sample) != rows[j][0]:
                    j += 1
                if j == len(rows):
                    return f"a sample no frame decodes to, or out of order: {sample}"
                counter = rows[j][1]
                if last_counter is not None and (counter - last_counter) % 256 != 1:
                    return f"a block bridges a counter jump: {last_counter} then {counter} without gap_before"
                last_counter = counter
                j += 1
        return None
    values: list[set[float]] = [set(), set(), set()]
    for _, s in decoded:
        if s["id"] in NODE_IDS:
            values[NODE_IDS.index(s["id"])].add(s["Accel"])
    for block in blocks:
        for sample in block.accel_mps2.tolist():
            for ch in range(3):
                if sample[ch] not in values[ch]:
                    return f"a sample of a{ch + 1} that no SensorNode{ch + 1} frame decodes to: {sample[ch]}"
    return None


# ---- can-hub, can-per-node -------------------------------------------------------------------------


def generate_decoder(layout_name: str) -> Any:
    def generate(rng: random.Random) -> fuzz_core.Input:
        frames = clean_frames(rng, layout_name)
        if rng.random() < 0.8:
            frames = mutate_frames(rng, frames)
        sizes = []
        total = 0
        while total < len(frames):
            size = rng.choice((0, 1, 2, 3, 4, rng.randint(1, 64), 1000))
            sizes.append(size)
            total += size
        return {"frames": frames, "batches": sizes}

    return generate


def run_decoder(layout_name: str) -> Any:
    def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
        frames = data["frames"]
        messages = [message(f) for f in frames]
        counters = HealthCounters()
        queue = SampleQueue(FS_HZ)
        decoder = CanFrameDecoder(layout(layout_name), FS_HZ, counters, queue)
        blocks = []
        at = 0
        for size in data["batches"]:
            decoder.feed(messages[at : at + size])  # as the source does after each read: take what is ready
            at += size
            while queue.full_block_ready(BLOCK_N):
                blocks.append(queue.take(BLOCK_N))
        while (block := queue.take(BLOCK_N)) is not None:
            blocks.append(block)
        counts, decoded = reference(layout_name, frames)
        return check_counts(counters, counts, frames) or check_blocks(blocks, counters) or check_samples(layout_name, blocks, decoded)

    return run


# ---- canlog-log, canlog-asc, canlog-blf ----------------------------------------------------------------


@functools.cache
def _writer_dir() -> Path:
    return fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-writer-")  # removed with the worker's scratch


def write_log(frames: list[Frame], suffix: str) -> bytes:
    """A log as python-can's writer for the suffix writes it (the .asc date line made fixed: reproducible)."""
    path = _writer_dir() / f"log{suffix}"
    with can.Logger(str(path)) as writer:
        for f in frames:
            msg = message(f)
            msg.channel = "can0" if suffix == ".log" else 0
            writer.on_message_received(msg)
    raw = path.read_bytes()
    if suffix == ".trc":  # its header names the file written: the worker's scratch folder
        raw = raw.replace(str(path).encode(), b"run.trc")
    if suffix == ".asc":
        lines = raw.split(b"\n")
        lines[0] = b"date Tue Dec 01 12:00:00.000 2026"
        raw = b"\n".join(lines)
    return raw


def generate_log(suffix: str) -> Any:
    def generate(rng: random.Random) -> fuzz_core.Input:
        layout_name = rng.choice(("hub", "hub", "per-node"))
        frames = clean_frames(rng, layout_name)
        if rng.random() < 0.3:
            frames = mutate_frames(rng, frames, rng.randint(1, 2))
        frames = [f for f in frames if 0 <= f[1] < 2**29 and 0 <= f[0] < 4e9]  # what the writers can write
        try:
            raw = write_log(frames, suffix)
        except Exception:  # noqa: BLE001 - a frame this writer cannot write (a BLF of 64 bytes): write the rest
            frames = [f for f in frames if len(f[5]) <= 8 and not f[4]]
            raw = write_log(frames, suffix)
        text = raw.decode("utf-8", "surrogateescape")
        clean = [line.strip() for line in text.splitlines()]
        ids = {m.frame_id for m in layout(layout_name).messages}
        # The lines of well-formed frames of the layout, as written: each must be accounted for.
        wanted = [clean[i] for i in _frame_lines(clean, suffix, frames) if frames_ok(frames, i, clean, suffix, ids, layout_name)]
        header = clean[: _first_frame_line(clean, suffix)]
        m = fuzz_core.Mutator(rng)
        kind = rng.random()
        if kind < 0.15:
            pass
        elif suffix == ".blf" or kind < 0.35:
            raw = m.bytes(raw, donors=(raw,))
        else:
            text = m.lines(text, tokens=lambda line: _mutate_line(m, line, suffix))
            raw = text.encode("utf-8", "surrogateescape")
        return {"layout": layout_name, "file": raw, "suffix": suffix, "intact_lines": wanted if suffix != ".blf" else [],
                "header": header if suffix in (".asc", ".trc", ".csv") else [], "max_block_s": rng.choice((1.0, 0.1))}  # fmt: skip

    return generate


def _first_frame_line(lines: list[str], suffix: str) -> int:
    if suffix == ".asc":
        return next((i + 1 for i, line in enumerate(lines) if "Start of measurement" in line), len(lines))
    if suffix == ".trc":  # a header of ';' comment lines (the file version, start time, columns)
        return next((i for i, line in enumerate(lines) if not line.startswith(";")), len(lines))
    return 1 if suffix == ".csv" else 0  # python-can's CSV: one header line


def _frame_lines(lines: list[str], suffix: str, frames: list[Frame]) -> range:
    first = _first_frame_line(lines, suffix)
    return range(first, min(len(lines), first + len(frames)))


def frames_ok(frames: list[Frame], line_index: int, lines: list[str], suffix: str, ids: set[int], layout_name: str) -> bool:
    f = frames[line_index - _first_frame_line(lines, suffix)]
    lengths = {m.frame_id: m.length for m in layout(layout_name).messages}
    return not f[4] and not f[3] and not f[2] and f[1] in ids and len(f[5]) == lengths[f[1]]


def _mutate_line(m: fuzz_core.Mutator, line: str, suffix: str) -> str:
    rng = m.rng
    fields = line.split()
    if not fields:
        return m.garbage_line()
    if suffix == ".log" and len(fields) >= 3 and "#" in fields[2]:
        which = rng.choice(("time", "id", "data", "channel", "extra"))
        can_id, _, payload = fields[2].partition("#")
        if which == "time":
            fields[0] = f"({m.number_text()})"
        elif which == "id":
            fields[2] = rng.choice(("FFFFFFFFFFFFFFFFFFFF", "1" * 40, "-1", "", "xyz", "80000100", "20000080", format(rng.randrange(2**64), "X"))) + "#" + payload
        elif which == "data":
            fields[2] = can_id + "#" + rng.choice(("", "0", "ZZ", "R", "R99", "##1", "#", payload + "0", "00" * 65, payload[::-1]))
        elif which == "channel":
            fields[1] = rng.choice(("", "1", "can0can0", "\x00"))
        else:
            fields.append(rng.choice(("R", "T", "x", "R T")))
        return " ".join(fields)
    i = rng.randrange(len(fields))
    fields[i] = rng.choice((m.number_text(), "FFFFFFFFFFFFFFFFFFFFx", "1FFFFFFFFFFx", "d", "r", "99", "CANFD", "Rx", ""))
    return " ".join(fields)


def drain(source: Source) -> list[Block] | str:
    """Every block a replay source gives until its EndOfStream, or why it never ends; it is closed after."""
    blocks: list[Block] = []
    try:
        for _ in range(100_000):
            try:
                block = source.read(0.05)
            except EndOfStream:
                return blocks
            if block is not None:
                blocks.append(block)
        return "the replay never ends: 100 000 reads without EndOfStream"
    finally:
        source.close()


def run_log(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / f"run{data['suffix']}"
    path.write_bytes(data["file"])
    source = open_replay(path, 0.0, layout(data["layout"]), FS_HZ, max_block_s=data["max_block_s"])
    blocks = drain(source)
    if isinstance(blocks, str):
        return blocks
    verdict = check_blocks(blocks, source.counters)
    if verdict is not None:
        return verdict
    wanted = data["intact_lines"]
    if not wanted:
        return None
    text = data["file"].decode("utf-8", "surrogateescape")
    lines = [line.strip() for line in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]
    if lines[: len(data["header"])] != data["header"]:
        return None  # a damaged header changes how every line reads
    wanted_set = set(wanted)
    intact = sum(1 for line in lines if line in wanted_set)
    accounted = source.counters.frames + source.counters.bad_frames
    if accounted < intact:
        return (f"intact frames dropped without being counted: {intact} intact frame lines, {source.counters.frames} decoded, "
                f"{source.counters.bad_frames} counted bad ({source.last_error or 'no error'})")  # fmt: skip
    return None


TARGETS = [
    fuzz_core.Target("can-hub", generate_decoder("hub"), run_decoder("hub")),
    fuzz_core.Target("can-per-node", generate_decoder("per-node"), run_decoder("per-node")),
    fuzz_core.Target("canlog-log", generate_log(".log"), run_log),
    fuzz_core.Target("canlog-asc", generate_log(".asc"), run_log),
    fuzz_core.Target("canlog-blf", generate_log(".blf"), run_log),
    fuzz_core.Target("canlog-trc", generate_log(".trc"), run_log),
    fuzz_core.Target("canlog-pycsv", generate_log(".csv"), run_log),
]
