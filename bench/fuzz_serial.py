"""Fuzz targets of the serial ADC: the packet parser and the source over a port that fails.

Streams are packets of drivers/serial_protocol.py (with repeated, skipped, reordered and
restarted sequence numbers) damaged by garbage, truncations, flipped bytes, stray sync words and
random bytes, fed in random chunks. The reference is a byte-by-byte parser written from the
packet format alone: at each position, a sync word whose 11 following bytes hold a good
CRC-16/CCITT-FALSE is a packet (skip 13), anything else one byte of garbage (a sync word there
also a CRC error), the last 12 bytes waiting for more.
"""

from __future__ import annotations

import errno
import random
from dataclasses import dataclass
from typing import Any

import numpy as np
import serial

import fuzz_core
from bogiemon.drivers.serial_protocol import PacketParser
from bogiemon.drivers.serial_source import SerialSource

SYNC = b"\xa5\x5a"
PACKET_SIZE = 13
LSB_MPS2 = 16 * 9.80665 / 32768
FULL_SCALE_MPS2 = 32768 * LSB_MPS2
FS_HZ = 500.0


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
        table.append(crc)
    return table


_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final XOR)."""
    crc = 0xFFFF
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


def packet(sequence: int, status: int, raw: tuple[int, int, int]) -> bytes:
    body = (sequence % 65536).to_bytes(2, "little") + bytes([status & 0xFF]) + b"".join(v.to_bytes(2, "little", signed=True) for v in raw)
    return SYNC + body + crc16(body).to_bytes(2, "big")


@dataclass
class RefPacket:
    sequence: int
    status: tuple[int, int, int]
    raw: tuple[int, int, int]
    end_offset: int


def reference_parse(data: bytes, base: int = 0) -> tuple[list[RefPacket], int, int]:
    """(packets, CRC errors, garbage bytes) of a whole stream, byte by byte; the unfinished tail is not counted."""
    packets: list[RefPacket] = []
    crc_errors = garbage = 0
    p, n = 0, len(data)
    while p + PACKET_SIZE <= n:
        if data[p : p + 2] == SYNC:
            if crc16(data[p + 2 : p + PACKET_SIZE]) == 0:
                body = data[p + 2 : p + 11]
                status = body[2]
                packets.append(
                    RefPacket(
                        int.from_bytes(body[0:2], "little"),
                        (status & 3, (status >> 2) & 3, (status >> 4) & 3),
                        tuple(int.from_bytes(body[3 + 2 * c : 5 + 2 * c], "little", signed=True) for c in range(3)),  # type: ignore[arg-type]
                        base + p + PACKET_SIZE,
                    )
                )
                p += PACKET_SIZE
                continue
            crc_errors += 1
        garbage += 1
        p += 1
    return packets, crc_errors, garbage


def generate_stream(rng: random.Random) -> bytes:
    """Packets with sequence anomalies, then damage between and inside them."""
    m = fuzz_core.Mutator(rng)
    n = rng.choice((0, 1, 2, rng.randint(3, 20), rng.randint(20, 40)))
    sequence = rng.choice((0, 65500, rng.randrange(65536)))
    out: list[bytes] = []
    for _ in range(n):
        anomaly = rng.choices(("next", "skip", "repeat", "back", "restart"), (20, 1, 1, 1, 0.5))[0]
        if anomaly == "skip":
            sequence += rng.choice((2, 3, 100, 32768, 40000))
        elif anomaly == "back":
            sequence -= rng.randint(1, 5)
        elif anomaly == "restart":
            sequence = 0
        raw = (sequence % 65536 - 32768, rng.randint(-32768, 32767), rng.choice((-32768, 32767, 0, rng.randint(-32768, 32767))))
        status = rng.choice((0, 0, 0, 0, rng.randrange(64), rng.randrange(256)))
        pkt = packet(sequence, status, raw)
        damage = rng.choices(("none", "garbage", "truncate", "flip", "sync_noise", "double"), (12, 1, 1, 1, 1, 0.5))[0]
        if damage == "garbage":
            out.append(m.random_bytes(40))
        elif damage == "truncate":
            pkt = pkt[: rng.randint(0, PACKET_SIZE - 1)]
        elif damage == "flip":
            i = rng.randrange(PACKET_SIZE)
            pkt = pkt[:i] + bytes([pkt[i] ^ rng.randint(1, 255)]) + pkt[i + 1 :]
        elif damage == "sync_noise":
            out.append(SYNC + rng.randbytes(rng.randint(0, 12)))
        elif damage == "double":
            out.append(pkt)
        out.append(pkt)
        if anomaly != "repeat":
            sequence += 1
    data = b"".join(out)
    kind = rng.random()
    if kind < 0.15:
        data = m.bytes(data)
    elif kind < 0.2:
        data = rng.choice((rng.randbytes(rng.randint(0, 600)), SYNC * rng.randint(1, 60), b"\x00" * rng.randint(0, 300), b"\xa5" * 100))
    return data


def chunks_of(rng: random.Random, n: int) -> list[int]:
    sizes = []
    total = 0
    while total < n:
        size = rng.choice((1, 2, 12, 13, 14, rng.randint(1, 200), 10_000))
        sizes.append(size)
        total += size
    return sizes


# ---- serial-parser -------------------------------------------------------------------------------


def generate_parser(rng: random.Random) -> fuzz_core.Input:
    data = generate_stream(rng)
    sizes = chunks_of(rng, len(data))
    # A reset (the source reopened the port) at a chunk boundary now and then: size 0 stands for it.
    for _ in range(rng.choice((0, 0, 0, 1, 2))):
        if sizes:
            sizes.insert(rng.randrange(len(sizes)), 0)
    return {"stream": data, "chunks": sizes}


def run_parser(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    stream: bytes = data["stream"]
    parser = PacketParser()
    got: list[tuple[int, tuple[int, ...], tuple[int, ...], int]] = []
    crc_errors = garbage = 0
    expected: list[RefPacket] = []
    ref_crc = ref_garbage = 0
    session_start = offset = 0
    for size in [*data["chunks"], 0]:  # the final 0: compare what a reset would drop, session by session
        if size == 0:
            packets, c, g = reference_parse(stream[session_start:offset], session_start)
            expected += packets
            ref_crc += c
            ref_garbage += g
            parser.reset()
            session_start = offset
            continue
        p = parser.feed(stream[offset : offset + size])
        offset += len(stream[offset : offset + size])
        crc_errors += p.crc_errors
        garbage += p.garbage_bytes
        raw = np.rint(p.accel_mps2 / LSB_MPS2).astype(np.int64)
        if not np.isfinite(p.accel_mps2).all() or np.abs(p.accel_mps2).max(initial=0) > FULL_SCALE_MPS2:
            return f"sample beyond full scale: {p.accel_mps2.tolist()[:3]}"
        for k in range(p.sequence.shape[0]):
            got.append((int(p.sequence[k]), tuple(p.status[k].tolist()), tuple(raw[k].tolist()), int(p.end_offset[k])))
    want = [(q.sequence, q.status, q.raw, q.end_offset) for q in expected]
    if got != want:
        first = next((i for i, (a, b) in enumerate(zip(got, want, strict=False)) if a != b), min(len(got), len(want)))
        return f"packets differ from the reference parser: {len(got)} found, {len(want)} expected; first difference at packet {first}"
    if (crc_errors, garbage) != (ref_crc, ref_garbage):
        return f"counts differ from the reference parser: crc_errors {crc_errors} garbage {garbage}, expected {ref_crc} and {ref_garbage}"
    return None


# ---- serial-source -------------------------------------------------------------------------------


class FakeClock:
    """Monotonic time that moves a little at each look and jumps at each sleep: deterministic."""

    def __init__(self) -> None:
        self.now_s = 0.0

    def clock(self) -> float:
        self.now_s += 1e-4
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.now_s += max(0.0, seconds)

    def wall(self) -> float:
        return 1.7e9 + self.now_s


_FAILURES: dict[str, Any] = {
    "eio": lambda: OSError(errno.EIO, "Input/output error"),
    "enodev": lambda: OSError(errno.ENODEV, "No such device"),
    "serial": lambda: serial.SerialException("device reports readiness to read but returned no data"),
    "enoent": lambda: FileNotFoundError(errno.ENOENT, "No such file or directory"),
    "value": lambda: ValueError("Could not configure port"),
}


class ScriptedPort:
    """A pyserial port double: read() returns the script's next chunk or raises its failure.

    With nothing to return it waits out its timeout on the fake clock, as a real port blocks.
    """

    def __init__(self, script: list[Any], clock: FakeClock) -> None:
        self.script = script
        self.clock = clock
        self.timeout = 0.0

    def read(self, size: int) -> bytes:
        if not self.script:
            self.clock.sleep(self.timeout)
            return b""
        item = self.script[0]
        if isinstance(item, bytes):
            self.script.pop(0)
            return item
        if item[0] == "lose":
            self.script.pop(0)
            raise _FAILURES[item[1]]()
        self.clock.sleep(self.timeout)
        return b""  # an open failure waits for the next open

    def reset_input_buffer(self) -> None:
        pass

    def close(self) -> None:
        pass


def generate_source(rng: random.Random) -> fuzz_core.Input:
    data = generate_stream(rng)
    script: list[Any] = []
    offset = 0
    for size in chunks_of(rng, len(data)):
        script.append(data[offset : offset + size])
        offset += size
        event = rng.random()
        if event < 0.03:
            script.append(["lose", rng.choice(("eio", "enodev", "serial"))])
        elif event < 0.04:
            script.append(["lose", "eio"])
            script += [["open_fail", rng.choice(("enoent", "value", "serial"))]] * rng.randint(1, 3)
    return {"script": script, "max_block_s": rng.choice((1.0, 0.1, 0.02)), "start_fails": rng.choice((0, 0, 0, 1))}


def run_source(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    script = [item if isinstance(item, bytes) else list(item) for item in data["script"]]
    script[:0] = [["open_fail", "enoent"]] * data["start_fails"]
    clock = FakeClock()
    opened: list[int] = []

    def opener(port: str, baudrate: int) -> ScriptedPort:
        if script and not isinstance(script[0], bytes) and script[0][0] == "open_fail":
            raise _FAILURES[str(script.pop(0)[1])]()
        opened.append(len(script))
        return ScriptedPort(script, clock)

    source = SerialSource("/dev/fuzz", 115200, FS_HZ, max_block_s=data["max_block_s"], opener=opener,
                          clock=clock.clock, sleep=clock.sleep, wall_clock=clock.wall)  # fmt: skip
    blocks = []
    reads = 0
    # Until the script is read, on the fake clock: open failures back off for seconds at a time.
    while script and clock.now_s < 600.0:
        reads += 1
        block = source.read(0.05)
        if block is not None:
            blocks.append(block)
    while (block := source.read(0.0)) is not None and reads < 100_000:
        reads += 1
        blocks.append(block)
    if script:
        return f"the source stopped reading: {len(script)} script items left after {reads} reads, {clock.now_s:.0f} s"
    source.close()

    # The reference: each port session parsed on its own (a reopened port drops a partial packet).
    sessions: list[bytes] = [b""]
    for item in data["script"]:
        if isinstance(item, bytes):
            sessions[-1] += item
        elif item[0] == "lose":
            sessions.append(b"")
    expected: list[RefPacket] = []
    ref_crc = ref_garbage = 0
    for chunk in sessions:
        packets, c, g = reference_parse(chunk)
        expected += packets
        ref_crc += c
        ref_garbage += g
    extra = source.counters.extra
    if source.counters.frames != len(expected):
        return f"frames counted differ from the reference parser: {source.counters.frames}, expected {len(expected)}"
    if (extra["crc_errors"], extra["garbage_bytes"]) != (ref_crc, ref_garbage):
        return f"counts differ from the reference parser: crc_errors {extra['crc_errors']} garbage {extra['garbage_bytes']}, expected {ref_crc} and {ref_garbage}"
    return check_blocks(blocks, expected)


def check_blocks(blocks: list[Any], expected: list[RefPacket]) -> fuzz_core.Verdict:
    """Samples come from packets of the stream, in order; a block never bridges a jump of the sequence."""
    j = 0
    previous_end_s: float | None = None
    last_sequence: int | None = None
    for block in blocks:
        if fuzz_core.implausible_time(block.start_s):
            return f"implausible block time: start_s {block.start_s!r}"
        if previous_end_s is not None and block.start_s < previous_end_s - fuzz_core.BACKWARD_TOLERANCE_S:
            return f"block time goes back: {block.start_s!r} after a block ending at {previous_end_s!r}"
        previous_end_s = block.end_s
        raw = np.rint(block.accel_mps2 / LSB_MPS2).astype(np.int64).tolist()
        if block.gap_before:
            last_sequence = None
        for row in raw:
            while j < len(expected) and tuple(row) != expected[j].raw:
                j += 1
            if j == len(expected):
                return f"a sample that no packet of the stream holds, or out of order: {row}"
            sequence = expected[j].sequence
            if last_sequence is not None and (sequence - last_sequence) % 65536 != 1:
                return f"a block bridges a sequence jump: {last_sequence} then {sequence} without gap_before"
            last_sequence = sequence
            j += 1
    return None


TARGETS = [
    fuzz_core.Target("serial-parser", generate_parser, run_parser),
    fuzz_core.Target("serial-source", generate_source, run_source),
]
