"""The serial ADC protocol: fixed 13-byte packets, one per sampling instant (docs/drivers.md).

    offset  size  field
    0       2     sync word A5 5A
    2       2     sequence counter, uint16 little-endian, +1 per instant, wraps 65535 -> 0
    4       1     status: bit 2c = over-range of channel c, bit 2c+1 = sensor fault (c = 0, 1, 2)
    5       6     a1, a2, a3: int16 little-endian, 1 LSB = 16 g / 32768 (full scale +/-16 g)
    11      2     CRC-16/CCITT-FALSE of bytes 2..10, big-endian (most significant byte first)

CRC-16/CCITT-FALSE: polynomial 0x1021, initial value 0xFFFF, no reflection, no final XOR;
check value 0x29B1 for b"123456789". Sent most significant byte first, the CRC of bytes 2..12
(counter through CRC) is 0, which is how a receiver may check it too.

PacketParser finds packets in any byte stream: it checks every sync-word candidate's CRC in one
numpy batch, keeps the earliest non-overlapping valid packets, counts the bytes between them
as garbage and the candidates with a bad CRC, and carries an incomplete tail to the next feed.
"""

from __future__ import annotations

import binascii
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

SYNC = b"\xa5\x5a"
PACKET_SIZE = 13
CRC_START, CRC_END = 2, 11  # the CRC covers packet[2:11]
ACCEL_LSB_MPS2 = 16 * 9.80665 / 32768  # same scale as the CAN layouts
SEQUENCE_MODULUS = 1 << 16


def _crc_table() -> NDArray[np.uint16]:
    table = np.zeros(256, dtype=np.uint16)
    for byte in range(256):
        table[byte] = binascii.crc_hqx(bytes([byte]), 0)  # one byte through a register of 0
    return table


def crc16_ccitt_false(data: bytes) -> int:
    """CRC-16/CCITT-FALSE of data: the standard library's CRC-CCITT (binascii.crc_hqx, in C) from 0xFFFF."""
    return binascii.crc_hqx(data, 0xFFFF)


# The table of the batch CRC below: entry b is the CRC contribution of the byte b shifted out.
CRC_TABLE = _crc_table()


def crc16_ccitt_false_rows(rows: NDArray[np.uint8]) -> NDArray[np.uint16]:
    """CRC-16/CCITT-FALSE of every row of an (m, k) byte array: k table steps over all m rows.

    The parser checks every sync-word candidate of a feed at once: above a few dozen rows this
    is faster than one binascii.crc_hqx call per row (5000 rows of 11 bytes: 0.5 ms against 2 ms
    here), and equal to it row by row (tests/drivers/test_serial.py).
    """
    crc = np.full(rows.shape[0], 0xFFFF, dtype=np.uint16)
    for j in range(rows.shape[1]):
        crc = (crc << np.uint16(8)) ^ CRC_TABLE[(crc >> np.uint16(8)) ^ rows[:, j]]
    return crc


def encode_packets(
    accel_mps2: NDArray[np.float64], first_sequence: int = 0, status: NDArray[np.uint8] | None = None
) -> bytes:
    """Packets for n instants (n, 3) m/s^2: what the ADC board sends. Beyond full scale: clipped, OVER_RANGE."""
    accel = np.asarray(accel_mps2, dtype=np.float64)
    n = accel.shape[0]
    raw = np.rint(accel / ACCEL_LSB_MPS2)
    clipped = (raw < -32768) | (raw > 32767)
    raw = np.clip(raw, -32768, 32767).astype("<i2")
    bits = np.zeros((n, 3), np.uint8) if status is None else np.asarray(status, np.uint8).copy()
    bits[clipped] |= 1
    status_byte = (bits[:, 0] & 3) | ((bits[:, 1] & 3) << 2) | ((bits[:, 2] & 3) << 4)
    packets = np.zeros((n, PACKET_SIZE), dtype=np.uint8)
    packets[:, 0:2] = np.frombuffer(SYNC, np.uint8)
    packets[:, 2:4] = ((first_sequence + np.arange(n)) % SEQUENCE_MODULUS).astype("<u2").view(np.uint8).reshape(n, 2)
    packets[:, 4] = status_byte
    packets[:, 5:11] = raw.view(np.uint8).reshape(n, 6)
    crc = crc16_ccitt_false_rows(packets[:, CRC_START:CRC_END])
    packets[:, 11] = crc >> 8
    packets[:, 12] = crc & 0xFF
    return packets.tobytes()


@dataclass(frozen=True)
class Packets:
    """The packets found by one PacketParser.feed."""

    sequence: NDArray[np.int64]  # (k,)
    status: NDArray[np.uint8]  # (k, 3) SensorStatus bits per channel
    accel_mps2: NDArray[np.float64]  # (k, 3)
    end_offset: NDArray[np.int64]  # (k,) bytes fed so far (over all feeds) up to each packet's end
    crc_errors: int  # sync-word candidates whose CRC failed, outside any valid packet
    garbage_bytes: int  # bytes dropped between packets


class PacketParser:
    """Packets from a byte stream cut anywhere; resynchronises on the sync word and the CRC."""

    def __init__(self) -> None:
        self._buffer = b""
        self._fed = 0  # bytes fed so far, for end_offset

    def reset(self) -> None:
        """Forget a partial packet (after the device was reopened)."""
        self._buffer = b""

    def feed(self, data: bytes) -> Packets:
        buf = self._buffer + data
        self._fed += len(data)
        base = self._fed - len(buf)  # stream offset of buf[0]
        arr = np.frombuffer(buf, dtype=np.uint8)
        n = arr.shape[0]
        last_start = n - PACKET_SIZE  # a packet may start at 0..last_start
        if last_start < 0:
            self._buffer = buf
            return _empty()
        head = arr[: last_start + 2]
        cand = np.flatnonzero((head[:-1] == SYNC[0]) & (head[1:] == SYNC[1]))
        valid = np.zeros(cand.shape[0], bool)
        if cand.size:
            rows = arr[cand[:, None] + np.arange(CRC_START, PACKET_SIZE)]
            # The CRC over the covered bytes and the CRC itself (MSB first) is 0 for a good packet.
            valid = crc16_ccitt_false_rows(rows) == 0
        starts = _earliest_non_overlapping(cand[valid])
        covered_end = int(starts[-1]) + PACKET_SIZE if starts.size else 0
        # Candidates with a bad CRC count once, unless a valid packet covers them (a sample that
        # happens to read A5 5A is not an error).
        bad = cand[~valid]
        if bad.size and starts.size:
            inside = np.searchsorted(starts, bad, side="right") - 1
            bad = bad[(inside < 0) | (bad >= starts[np.maximum(inside, 0)] + PACKET_SIZE)]
        # Keep the tail that could still begin a packet: everything after the last valid packet
        # from the first position whose packet would run past the end.
        keep_from = max(covered_end, last_start + 1)
        bad = bad[bad < keep_from]
        garbage = keep_from - starts.size * PACKET_SIZE  # every chosen packet lies before keep_from
        self._buffer = buf[keep_from:]
        if starts.size == 0:
            return _empty(int(bad.size), int(garbage))
        packets = arr[starts[:, None] + np.arange(PACKET_SIZE)]
        sequence = packets[:, 2].astype(np.int64) | (packets[:, 3].astype(np.int64) << 8)
        status_byte = packets[:, 4]
        status = np.column_stack([(status_byte >> (2 * c)) & 3 for c in range(3)]).astype(np.uint8)
        raw = np.ascontiguousarray(packets[:, 5:11]).view("<i2").reshape(-1, 3)
        return Packets(
            sequence=sequence,
            status=status,
            accel_mps2=raw.astype(np.float64) * ACCEL_LSB_MPS2,
            end_offset=base + starts.astype(np.int64) + PACKET_SIZE,
            crc_errors=int(bad.size),
            garbage_bytes=int(garbage),
        )


def _earliest_non_overlapping(starts: NDArray[np.intp]) -> NDArray[np.intp]:
    """Greedy choice of packets from sorted valid starts: the earliest, then the next past its end."""
    if starts.size == 0 or bool((np.diff(starts) >= PACKET_SIZE).all()):
        return starts  # the usual case: no two valid candidates overlap
    chosen = []
    next_free = -1
    for s in starts.tolist():
        if s >= next_free:
            chosen.append(s)
            next_free = s + PACKET_SIZE
    return np.array(chosen, dtype=np.intp)


def _empty(crc_errors: int = 0, garbage_bytes: int = 0) -> Packets:
    return Packets(
        sequence=np.zeros(0, np.int64),
        status=np.zeros((0, 3), np.uint8),
        accel_mps2=np.zeros((0, 3)),
        end_offset=np.zeros(0, np.int64),
        crc_errors=crc_errors,
        garbage_bytes=garbage_bytes,
    )
