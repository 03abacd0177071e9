"""The serial ADC: CRC-16/CCITT-FALSE, resynchronisation after any damage, and a real pseudo-terminal unplugged and back."""

from __future__ import annotations

import binascii
import os
import time
import tty
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bogiemon.drivers.base import SensorStatus
from bogiemon.drivers.serial_protocol import (
    PACKET_SIZE,
    SYNC,
    PacketParser,
    crc16_ccitt_false,
    crc16_ccitt_false_rows,
    encode_packets,
)
from bogiemon.drivers.serial_source import SerialSource, open_serial_port
from tests.drivers.frames import FS_HZ, LSB_MPS2, check_blocks, coded_accel


def crc_bitwise(data: bytes) -> int:
    """CRC-16/CCITT-FALSE straight from its definition, one bit at a time: the reference."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def test_crc_is_ccitt_false_by_its_check_value() -> None:
    assert crc16_ccitt_false(b"123456789") == 0x29B1 == crc_bitwise(b"123456789")


@settings(max_examples=100, deadline=None)
@given(rows=st.lists(st.binary(min_size=11, max_size=11), min_size=1, max_size=20))
def test_batch_crc_equals_the_bitwise_reference(rows: list[bytes]) -> None:
    batch = crc16_ccitt_false_rows(np.frombuffer(b"".join(rows), np.uint8).reshape(len(rows), 11))
    assert batch.tolist() == [crc_bitwise(r) for r in rows]


def test_batch_crc_equals_binascii_on_random_packets() -> None:
    rows = np.random.default_rng(35).integers(0, 256, size=(1000, 11), dtype=np.uint8)
    expected = [binascii.crc_hqx(row.tobytes(), 0xFFFF) for row in rows]
    assert crc16_ccitt_false_rows(rows).tolist() == expected
    assert [crc16_ccitt_false(row.tobytes()) for row in rows] == expected


def test_a_packet_is_laid_out_byte_by_byte_as_documented() -> None:
    packet = encode_packets(np.array([[1.0, -1.0, 200.0]]), first_sequence=0x1234, status=np.array([[0, 2, 0]]))
    assert len(packet) == PACKET_SIZE
    assert packet[0:2] == SYNC
    assert packet[2:4] == b"\x34\x12"  # little-endian sequence
    assert packet[4] == 0b011000  # a2 sensor fault (bit 3), a3 over-range (bit 4): 200 m/s^2 > 16 g
    raw = np.frombuffer(packet[5:11], "<i2")
    assert raw.tolist() == [round(1.0 / LSB_MPS2), round(-1.0 / LSB_MPS2), 32767]
    assert int.from_bytes(packet[11:13], "big") == crc_bitwise(packet[2:11])


def parse_all(data: bytes, chunk: int) -> tuple[np.ndarray, np.ndarray, int, int]:
    parser = PacketParser()
    # Start with empty arrays: a stream damaged down to nothing parses to nothing.
    seqs, accels, crc_errors, garbage = [np.zeros(0, dtype=np.int64)], [np.zeros((0, 3))], 0, 0
    for i in range(0, len(data), chunk):
        p = parser.feed(data[i : i + chunk])
        seqs.append(p.sequence)
        accels.append(p.accel_mps2)
        crc_errors += p.crc_errors
        garbage += p.garbage_bytes
    return np.concatenate(seqs), np.concatenate(accels), crc_errors, garbage


@settings(max_examples=60, deadline=None)
@given(n=st.integers(1, 80), chunk=st.integers(1, 200))
def test_packets_cut_anywhere_parse_back_exactly(n: int, chunk: int) -> None:
    k = np.arange(n)
    seq, accel, crc_errors, garbage = parse_all(encode_packets(coded_accel(k), first_sequence=65500), chunk)
    np.testing.assert_array_equal(seq, (65500 + k) % 65536)
    np.testing.assert_array_equal(accel, coded_accel(k))
    assert crc_errors == garbage == 0


@st.composite
def damaged_bytes(draw: st.DrawFn) -> tuple[bytes, set[int], int]:
    """Packets 0..n-1 with garbage, truncations, flipped bytes and repeats between and inside them.

    Returns the stream, the packets left intact (which must all come back), and a chunk size.
    """
    n = draw(st.integers(1, 60))
    packets = [encode_packets(coded_accel(np.array([k])), first_sequence=k) for k in range(n)]
    out, intact = [], set()
    for k, packet in enumerate(packets):
        event = draw(st.sampled_from(["ok"] * 4 + ["garbage", "truncate", "flip", "repeat", "sync_noise"]))
        if event == "garbage":
            out.append(draw(st.binary(min_size=1, max_size=40)))
        if event == "truncate":
            out.append(packet[: draw(st.integers(0, PACKET_SIZE - 1))])
            continue
        if event == "flip":
            i = draw(st.integers(0, PACKET_SIZE - 1))
            out.append(packet[:i] + bytes([packet[i] ^ draw(st.integers(1, 255))]) + packet[i + 1 :])
            continue
        if event == "sync_noise":
            out.append(SYNC + draw(st.binary(max_size=11)))
        out.append(packet)
        if event == "repeat":
            out.append(packet)
        intact.add(k)
    return b"".join(out), intact, draw(st.integers(1, 300))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stream=damaged_bytes())
def test_every_intact_packet_survives_any_damage_around_it(stream: tuple[bytes, set[int], int]) -> None:
    data, intact, chunk = stream
    seq, accel, crc_errors, garbage = parse_all(data, chunk)
    np.testing.assert_array_equal(accel, coded_accel(seq))  # nothing corrupted is delivered
    # A packet is lost only if damage overlaps it; a garbage run may by chance form a valid
    # packet (one in 65536): allow only sequences that were sent.
    assert intact <= set(seq.tolist())
    assert set(seq.tolist()) <= set(range(60))


def test_a_bad_crc_and_garbage_are_counted() -> None:
    good = encode_packets(coded_accel(np.arange(3)))
    bad = bytearray(good[PACKET_SIZE : 2 * PACKET_SIZE])
    bad[7] ^= 0x40
    seq, _, crc_errors, garbage = parse_all(good[:PACKET_SIZE] + b"\x00\x11\x22" + bytes(bad) + good[2 * PACKET_SIZE :], 1000)
    assert seq.tolist() == [0, 2]
    assert crc_errors == 1 and garbage == 3 + PACKET_SIZE


# ---- the source ---------------------------------------------------------------------------------


class ScriptedPort:
    """A port double that returns scripted chunks from read() (the pty tests use the real thing)."""

    def __init__(self, chunks: list[bytes]) -> None:
        self.chunks = list(chunks)
        self.timeout = 0.0

    def read(self, size: int) -> bytes:
        return self.chunks.pop(0) if self.chunks else b""

    def reset_input_buffer(self) -> None:
        pass

    def close(self) -> None:
        pass


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(stream=damaged_bytes())
def test_serial_source_counts_damage_and_never_bridges_a_gap(stream: tuple[bytes, set[int], int]) -> None:
    data, intact, chunk = stream
    chunks = [data[i : i + chunk] for i in range(0, len(data), chunk)]
    port = ScriptedPort(chunks)
    source = SerialSource("scripted", 115200, FS_HZ, opener=lambda name, baud: port)
    blocks = []
    while port.chunks:  # a read hands on a queued block before it reads the port again
        block = source.read(0.0001)
        if block is not None:
            blocks.append(block)
    while (block := source.read(0)) is not None:
        blocks.append(block)
    segments = check_blocks(blocks)  # consecutive, uniform, intact, never bridged
    delivered = set(np.concatenate(segments).tolist()) if segments else set()
    assert delivered <= set(range(60))
    damaged = len(intact) < max(intact | {0}) + 1 or len(data) != PACKET_SIZE * len(intact)
    if not damaged:
        assert delivered == intact and source.counters.gaps == 0
    counters = source.counters
    assert counters.frames >= len(intact)
    assert counters.gaps == max(0, len(segments) - 1)


def test_sequence_anomalies_are_counted() -> None:
    packets = [encode_packets(coded_accel(np.array([k])), first_sequence=k) for k in range(10)]
    data = b"".join(packets[:4] + [packets[3]] + packets[6:8] + [packets[5]] + packets[8:])
    source = SerialSource("scripted", 115200, FS_HZ, opener=lambda port, baud: ScriptedPort([data]))
    blocks = [block for block in (source.read(0.01), source.read(0.01)) if block is not None]
    assert [s.tolist() for s in check_blocks(blocks)] == [[0, 1, 2, 3], [6, 7, 8, 9]]
    extra = source.counters.extra
    assert (extra["duplicates"], extra["out_of_order"], extra["lost_samples"]) == (1, 1, 2)
    assert source.counters.gaps == 1


def test_packets_read_at_a_clock_that_gives_no_finite_time_are_counted_and_never_passed_on() -> None:
    data = b"".join(encode_packets(coded_accel(np.array([k])), first_sequence=k) for k in range(5))
    source = SerialSource("scripted", 115200, FS_HZ, opener=lambda port, baud: ScriptedPort([data]), wall_clock=lambda: float("nan"))
    assert source.read(0.01) is None
    assert source.counters.frames == 0
    assert source.counters.bad_frames == 5 and source.counters.extra["bad_timestamps"] == 5


# ---- a real pseudo-terminal, unplugged and back ------------------------------------------------


class Adapter:
    """A USB serial adapter played by a pty pair behind a stable symlink (like /dev/serial/by-id)."""

    def __init__(self, link: Path) -> None:
        self.link = link
        self.master = self.slave = -1

    def plug(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)  # no line discipline between the board and pyserial
        if self.link.is_symlink():
            self.link.unlink()
        self.link.symlink_to(os.ttyname(self.slave))

    def unplug(self) -> None:
        os.close(self.master)
        os.close(self.slave)
        self.link.unlink()

    def send(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.master, view) :]


def read_samples(source: SerialSource, n: int, timeout_s: float = 5.0) -> list:
    blocks, got, end = [], 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        block = source.read(0.05)
        if block is not None:
            blocks.append(block)
            got += block.n_samples
    return blocks


def test_pty_round_trip_reproduces_the_samples_within_one_lsb(tmp_path: Path) -> None:
    adapter = Adapter(tmp_path / "ttyADC")
    adapter.plug()
    rng = np.random.default_rng(11)
    accel = rng.standard_normal((400, 3)) * 3 + 9.81
    status = np.zeros((400, 3), np.uint8)
    status[123, 2] = SensorStatus.SENSOR_FAULT
    try:
        with SerialSource(str(adapter.link), 115200, FS_HZ) as source:
            adapter.send(encode_packets(accel, status=status))
            blocks = read_samples(source, 400)
    finally:
        adapter.unplug()
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (400, 3) and np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    assert blocks[0].gap_before and not any(b.gap_before for b in blocks[1:])
    assert any(b.status[2] == SensorStatus.SENSOR_FAULT for b in blocks)
    assert source.counters.frames == 400 and source.counters.bad_frames == 0


def test_pty_unplugged_and_replugged_is_reopened_and_starts_a_segment(tmp_path: Path) -> None:
    adapter = Adapter(tmp_path / "ttyADC")
    adapter.plug()
    source = SerialSource(str(adapter.link), 115200, FS_HZ, backoff_min_s=0.01, backoff_max_s=0.05)
    try:
        adapter.send(encode_packets(coded_accel(np.arange(100))) + b"\xde\xad")  # a torn packet at the unplug
        first = read_samples(source, 100)
        adapter.unplug()
        for _ in range(5):  # reads while the adapter is away: no exception, nothing delivered
            assert source.read(0.02) is None
        assert not source.connected
        assert source.counters.extra["disconnects"] == 1 and source.counters.extra["open_failures"] >= 1
        assert str(adapter.link) in (source.last_error or "")
        adapter.plug()
        deadline = time.monotonic() + 3.0
        while not source.connected and time.monotonic() < deadline:
            source.read(0.02)
        assert source.connected and source.counters.reconnects == 1
        adapter.send(encode_packets(coded_accel(np.arange(100, 200)), first_sequence=100))
        second = read_samples(source, 100)
    finally:
        source.close()
        adapter.unplug()
    assert [s.tolist() for s in check_blocks(first + second)] == [list(range(100)), list(range(100, 200))]
    assert source.counters.gaps == 1


def test_a_port_that_never_existed_is_retried_without_raising(tmp_path: Path) -> None:
    source = SerialSource(str(tmp_path / "ttyNOPE"), 115200, FS_HZ, backoff_min_s=0.01, backoff_max_s=0.02)
    assert source.read(0.05) is None
    assert source.counters.extra["open_failures"] >= 2
    assert source.last_error.startswith(f"serial port {tmp_path / 'ttyNOPE'}: cannot open")
    assert source.counters.timeouts == 1
    source.close()


@pytest.mark.parametrize("garbage", [b"", b"\xa5\x5a\xa5", bytes(range(256))])
def test_garbage_before_the_stream_is_skipped_and_counted(tmp_path: Path, garbage: bytes) -> None:
    adapter = Adapter(tmp_path / "ttyADC")
    adapter.plug()
    try:
        with SerialSource(str(adapter.link), 115200, FS_HZ) as source:
            adapter.send(garbage + encode_packets(coded_accel(np.arange(50))))
            blocks = read_samples(source, 50)
            assert [s.tolist() for s in check_blocks(blocks)] == [list(range(50))]
            assert source.counters.extra["garbage_bytes"] == len(garbage)
    finally:
        adapter.unplug()


class CountingPort:
    """A real pyserial port that counts its reads that came back short: those waited out their timeout."""

    def __init__(self, port: Any) -> None:
        self.port = port
        self.short_reads = 0

    @property
    def timeout(self) -> float:
        return float(self.port.timeout)

    @timeout.setter
    def timeout(self, value: float) -> None:
        self.port.timeout = value

    @property
    def in_waiting(self) -> int:
        return int(self.port.in_waiting)

    def read(self, size: int) -> bytes:
        data = self.port.read(size)
        self.short_reads += len(data) < size
        return bytes(data)

    def reset_input_buffer(self) -> None:
        self.port.reset_input_buffer()

    def close(self) -> None:
        self.port.close()


def test_after_a_burst_of_bit_errors_the_source_hands_on_what_it_holds_without_waiting_on_the_port(tmp_path: Path) -> None:
    # The finding: after bit errors every segment waited out a read's timeout before it went on
    # (one segment per 0.5 s), so the source fell behind real time and stayed there. Here the port
    # holds 1.2 s of packets, a flipped bit in every tenth of the first second (50 segments), before
    # the first read (a pty holds 11 to 13 kB): every read until the last sample must go on without
    # the port's timeout.
    n, damaged = 600, range(5, 500, 10)
    packets = [bytearray(encode_packets(coded_accel(np.array([k])), first_sequence=k)) for k in range(n)]
    for k in damaged:
        packets[k][7] ^= 0x40  # a bit error: the CRC fails, the sample is lost, a new segment starts
    adapter = Adapter(tmp_path / "ttyADC")
    adapter.plug()
    ports: list[CountingPort] = []

    def opener(port: str, baudrate: int) -> CountingPort:
        ports.append(CountingPort(open_serial_port(port, baudrate)))
        return ports[-1]

    try:
        with SerialSource(str(adapter.link), 115200, FS_HZ, max_block_s=0.1, opener=opener) as source:
            os.set_blocking(adapter.master, False)
            assert os.write(adapter.master, b"".join(packets)) == n * PACKET_SIZE  # all of it buffered before the first read
            blocks, got, reads = [], 0, 0
            while got < n - len(damaged) and reads < 2 * n:
                block = source.read(0.5)
                reads += 1
                if block is not None:
                    blocks.append(block)
                    got += block.n_samples
            behind_s = source.behind_s()
    finally:
        adapter.unplug()
    segments = check_blocks(blocks)
    assert np.concatenate(segments).tolist() == sorted(set(range(n)) - set(damaged))
    assert len(segments) == len(damaged) + 1 and source.counters.extra["crc_errors"] == len(damaged)
    # The last read alone may wait: for the samples the open segment lacked, which never came.
    assert ports[0].short_reads <= 1 and behind_s == 0.0
