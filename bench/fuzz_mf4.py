"""Fuzz target of MF4 files through open_replay, as `replay` reads them: bus logs (CAN frames of the
CAN targets, written by python-can's MF4 writer) and signals (a1, a2, a3 and their time master,
written by asammdf), then damaged: cut anywhere, bytes flipped, a block's declared length or one
of its links replaced (zero, past the end, itself, huge), a channel group's record count or
record size made huge, and a data block's declared size. Each input must end in RecordingError or
a correct read: a valid bus log's frames all decoded as the reference places them, a valid
recording's samples all delivered; blocks at plausible, finite times; the peak RSS bounded.
"""

from __future__ import annotations

import functools
import os
import random
import struct
from pathlib import Path

import numpy as np

import fuzz_can
import fuzz_core
from fuzz_memory import PeakRss, memory_verdict
from bogiemon.drivers.replay import open_replay

# What one input's reading may add to the worker's resident memory (the unit's 200 MiB, less the process's own).
PEAK_RSS_BOUND_MIB = 128.0
START_S = 1.7645e9
HUGE = (0, 1, 7, 2**31, 2**32 - 1, 2**40, 2**63 - 1, 2**64 - 1)


@functools.cache
def _writer_dir() -> Path:
    return fuzz_core.scratch_root(f"bogiemon-fuzz-{os.getpid()}-mf4-")  # removed with the worker's scratch


def _bus_log(frames: list[fuzz_can.Frame]) -> bytes:
    import can

    path = _writer_dir() / "bus.mf4"
    with can.Logger(str(path)) as writer:
        for f in frames:
            msg = fuzz_can.message(f)
            msg.channel = 0
            writer.on_message_received(msg)
    raw = path.read_bytes()
    path.unlink()
    return raw


def _signals(rng: random.Random, n: int) -> bytes:
    from asammdf import MDF, Signal

    fs_hz = rng.choice((500.0, 1000.0, 200.0))
    time_s = np.arange(n) / fs_hz
    values = np.random.default_rng(rng.randrange(2**32)).normal(9.81, 2.0, (n, 3))
    mdf = MDF(version="4.10")
    mdf.append([Signal(values[:, i], time_s, name=name, unit="m/s^2") for i, name in enumerate(("a1", "a2", "a3"))])
    path = _writer_dir() / "signals.mf4"
    mdf.save(path, overwrite=True, compression=rng.choice((0, 0, 2)))
    mdf.close()
    raw = path.read_bytes()
    path.unlink()
    return raw


def _blocks(raw: bytes) -> list[int]:
    """Where the file's blocks start ('##' ids at 8-byte boundaries)."""
    return [i for i in range(64, len(raw) - 24, 8) if raw[i : i + 2] == b"##" and raw[i + 2 : i + 4].isalpha()]


def _damage(rng: random.Random, raw: bytes) -> bytes:
    out = bytearray(raw)
    blocks = _blocks(raw) or [64]
    kind = rng.choice(("cut", "flip", "length", "link", "cycles", "record_size", "bytes"))
    at = rng.choice(blocks)
    if kind == "cut":
        return bytes(out[: rng.randint(0, len(out) - 1)])
    if kind == "flip":
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
    elif kind == "length" and at + 16 <= len(out):
        out[at + 8 : at + 16] = struct.pack("<Q", rng.choice((*HUGE, len(raw), struct.unpack_from("<Q", out, at + 8)[0] + 8)))
    elif kind == "link" and at + 24 <= len(out):
        links = struct.unpack_from("<Q", out, at + 16)[0]
        if links and at + 24 + 8 * min(links, 8) <= len(out):
            i = rng.randrange(min(links, 8))
            out[at + 24 + 8 * i : at + 32 + 8 * i] = struct.pack("<Q", rng.choice((0, at, 8, len(raw), 2**62, rng.choice(blocks))))
    elif kind in ("cycles", "record_size"):
        groups = [b for b in blocks if raw[b : b + 4] == b"##CG"]
        if groups:
            cg = rng.choice(groups)
            links = struct.unpack_from("<Q", out, cg + 16)[0]
            data = cg + 24 + 8 * links + (8 if kind == "cycles" else 24)  # cycle_count, then flags, path sep, reserved, data bytes
            if data + 8 <= len(out):
                out[data : data + (8 if kind == "cycles" else 4)] = struct.pack("<Q", rng.choice(HUGE))[: 8 if kind == "cycles" else 4]
    else:
        return fuzz_core.Mutator(rng).bytes(raw)
    return bytes(out)


def generate(rng: random.Random) -> fuzz_core.Input:
    bus = rng.random() < 0.5
    frames: list[fuzz_can.Frame] = []
    layout_name = rng.choice(("hub", "per-node"))
    if bus:
        frames = [f for f in fuzz_can.clean_frames(rng, layout_name) if 0 <= f[0] < 4e9]
        raw = _bus_log(frames)
        n = len(frames)
    else:
        n = rng.choice((2, 10, rng.randint(10, 3000)))
        raw = _signals(rng, n)
    valid = rng.random() < 0.2
    if not valid:
        raw = _damage(rng, raw)
    return {"file": raw, "layout": layout_name, "bus": bus, "n": n if valid else None, "max_block_s": rng.choice((1.0, 0.1))}


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / "run.mf4"
    path.write_bytes(data["file"])
    with PeakRss() as peak:
        source = open_replay(path, 0.0, fuzz_can.layout(data["layout"]), fuzz_can.FS_HZ, max_block_s=data["max_block_s"])
        blocks = fuzz_can.drain(source)
    if isinstance(blocks, str):
        return blocks
    if (beyond := memory_verdict(ctx, peak, PEAK_RSS_BOUND_MIB)) is not None:
        return beyond
    if data["bus"]:
        verdict = fuzz_can.check_blocks(blocks, source.counters)
        if verdict is None and data["n"] is not None and source.counters.frames + source.counters.bad_frames < data["n"]:
            verdict = f"frames dropped without being counted: {data['n']} written, {source.counters.frames} decoded, {source.counters.bad_frames} bad"
        return verdict
    delivered = sum(b.n_samples for b in blocks)
    if data["n"] is not None and delivered != data["n"]:
        return f"delivered {delivered} samples of the {data['n']} written"
    return None


TARGETS = [fuzz_core.Target("mf4", generate, run)]
