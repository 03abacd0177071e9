"""The CAN player: a recording encoded with the DBC and sent on a bus at real-time pace.

For the bench and the tests: `bogiemon play FILE --interface socketcan --channel vcan0` puts a
recording (or a simulated run) on a CAN bus exactly as the sensor hub or the sensor nodes
would, so a gateway (or can-utils) downstream cannot tell the difference. Encoding is batched
with the compiled DBC (encode_instants); pacing keeps each instant's frames at
start + (instant time) / rate on the wall clock, so the pace does not drift over a long file.
"""

from __future__ import annotations

import errno
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import SensorStatus
from bogiemon.drivers.candb import CanLayout
from bogiemon.drivers.canbus import BusRole, UnknownBusKind, open_bus

# How long a full transmit queue may refuse frames before playing gives up (a bus nobody
# acknowledges never drains).
SEND_RETRY_S = 2.0
CHUNK_N = 500  # instants encoded per numpy batch


class PlayError(Exception):
    """The player cannot go on (no such interface, interface down, nobody acknowledging)."""


@dataclass(frozen=True)
class PlayStats:
    instants: int
    frames: int
    wall_s: float


def encode_instants(
    layout: CanLayout,
    accel_mps2: NDArray[np.float64],
    first_counter: int = 0,
    status: NDArray[np.uint8] | None = None,
) -> list[list[tuple[int, bool, bytes]]]:
    """The frames of each instant, in sending order: [(identifier, extended, payload), ...].

    Values beyond the +/-16 g full scale are clipped and flagged OVER_RANGE, as the sensor would;
    status (n, 3) adds other bits (SENSOR_FAULT) per sample.
    """
    accel = np.asarray(accel_mps2, dtype=np.float64)
    n = accel.shape[0]
    bits = np.zeros((n, 3), np.uint8) if status is None else np.asarray(status, np.uint8).copy()
    modulus = layout.counter_modulus
    counter = (first_counter + np.arange(n)) % modulus
    payloads: list[NDArray[np.uint8]] = []
    order = list(layout.data_messages)
    if layout.hub is not None:
        sig = layout.hub.signals
        raw: dict[str, NDArray[np.int64]] = {"Counter": counter}
        for c in range(3):
            raw[f"Accel{c + 1}"], clipped = sig[f"Accel{c + 1}"].to_raw(accel[:, c])
            bits[clipped, c] |= np.uint8(SensorStatus.OVER_RANGE)
        for c in range(3):
            raw[f"OverRange{c + 1}"] = (bits[:, c] & SensorStatus.OVER_RANGE != 0).astype(np.int64)
            raw[f"SensorFault{c + 1}"] = (bits[:, c] & SensorStatus.SENSOR_FAULT != 0).astype(np.int64)
        payloads.append(layout.hub.encode_raw(raw, n))
    else:
        if layout.sync is not None:  # the trigger goes first, the nodes answer it
            payloads.append(layout.sync.encode_raw({"Counter": counter}, n))
            order.insert(0, layout.sync)
        for c, codec in enumerate(layout.nodes):
            value, clipped = codec.signals["Accel"].to_raw(accel[:, c])
            bits[clipped, c] |= np.uint8(SensorStatus.OVER_RANGE)
            node_raw = {
                "Counter": counter,
                "Accel": value,
                "OverRange": (bits[:, c] & SensorStatus.OVER_RANGE != 0).astype(np.int64),
                "SensorFault": (bits[:, c] & SensorStatus.SENSOR_FAULT != 0).astype(np.int64),
            }
            payloads.append(codec.encode_raw(node_raw, n))
    heads = [(m.frame_id, m.is_extended) for m in order]
    as_bytes = [[bytes(row) for row in p] for p in payloads]
    return [[(fid, ext, frames[i]) for (fid, ext), frames in zip(heads, as_bytes, strict=True)] for i in range(n)]


def iter_messages(
    layout: CanLayout, accel_mps2: NDArray[np.float64], fs_hz: float, start_s: float = 0.0
) -> Iterator[tuple[float, can.Message]]:
    """(time of the instant in seconds, frame) for a whole recording, encoded CHUNK_N instants at a time."""
    n = accel_mps2.shape[0]
    for lo in range(0, n, CHUNK_N):
        instants = encode_instants(layout, accel_mps2[lo : lo + CHUNK_N], first_counter=lo)
        for k, frames in enumerate(instants):
            time_s = start_s + (lo + k) / fs_hz
            for frame_id, extended, payload in frames:
                yield time_s, can.Message(
                    timestamp=time_s, arbitration_id=frame_id, is_extended_id=extended, data=payload, is_rx=False
                )


def play(
    bus: can.BusABC,
    layout: CanLayout,
    accel_mps2: NDArray[np.float64],
    fs_hz: float,
    rate: float = 1.0,
    stop: threading.Event | None = None,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    stamp_start_s: float | None = None,
) -> PlayStats:
    """Send a recording's frames on bus; rate 1 is real time, N is N times faster, 0 as fast as possible.

    Raises PlayError when the bus refuses frames for SEND_RETRY_S or fails; stop ends it early.
    stamp_start_s: each frame is stamped stamp_start_s + (its instant's time) / rate, the clock
    of a hub sending at that pace (a bus opened as BusRole.STAMPED_SENDER keeps the stamp).
    """
    if rate < 0:
        raise PlayError(f"--rate must be 0 (as fast as possible) or positive, got {rate:g}")
    start_wall_s = clock()
    frames = instants = 0
    last_time_s = None
    for time_s, message in iter_messages(layout, accel_mps2, fs_hz):
        if stop is not None and stop.is_set():
            break
        if time_s != last_time_s:
            instants += 1
            last_time_s = time_s
            if rate > 0:
                ahead_s = start_wall_s + time_s / rate - clock()
                if ahead_s > 0:
                    sleep(ahead_s)
        if stamp_start_s is not None:
            message.timestamp = stamp_start_s + (time_s / rate if rate > 0 else time_s)
        _send(bus, message, clock, sleep)
        frames += 1
    return PlayStats(instants=instants, frames=frames, wall_s=clock() - start_wall_s)


def _send(bus: can.BusABC, message: can.Message, clock: Callable[[], float], sleep: Callable[[float], None]) -> None:
    give_up_s = None
    while True:
        try:
            bus.send(message)
            return
        except can.CanOperationError as exc:
            # A full transmit queue (ENOBUFS) drains as the controller sends: wait and retry.
            full = exc.error_code == errno.ENOBUFS or "buffer full" in str(exc).lower()
            if not full:
                raise PlayError(f"{bus.channel_info}: sending failed: {exc}") from None
            now_s = clock()
            give_up_s = now_s + SEND_RETRY_S if give_up_s is None else give_up_s
            if now_s >= give_up_s:
                raise PlayError(
                    f"{bus.channel_info}: the transmit queue stayed full for {SEND_RETRY_S:g} s: "
                    "is another node on the bus acknowledging frames?"
                ) from None
            sleep(0.001)


def open_player_bus(interface: str, channel: str, stamped: bool = False) -> can.BusABC:
    """A bus to send on (drivers/canbus.py, role SENDER, or STAMPED_SENDER: the frames keep the
    stamps play() gives them); PlayError in one line if the interface is missing."""
    try:
        return open_bus(interface, channel, BusRole.STAMPED_SENDER if stamped else BusRole.SENDER)
    except UnknownBusKind as exc:
        raise PlayError(str(exc)) from None
    except OSError as exc:
        if exc.errno == errno.EAFNOSUPPORT:
            raise PlayError(
                f"CAN interface '{channel}': this kernel has no SocketCAN (AF_CAN): use a Linux kernel with the can and "
                "vcan modules (`modprobe vcan`), or make a CAN log without a bus: `bogiemon convert FILE -o run.log`"
            ) from None
        if exc.errno == errno.ENODEV:
            raise PlayError(
                f"CAN interface '{channel}' does not exist: plug the adapter in, or for a bench "
                f"`ip link add dev {channel} type vcan && ip link set {channel} up` (docs/drivers.md)"
            ) from None
        raise PlayError(f"CAN interface '{channel}': {exc.strerror or exc}") from None


@dataclass(frozen=True)
class PlayedSamples:
    """A file's samples as the player sends them: uniform at fs_hz, its gaps closed up (counted)."""

    accel_mps2: NDArray[np.float64]
    fs_hz: float
    gaps: int


def read_samples(path: str | Path, layout: CanLayout, fs_hz: float) -> PlayedSamples:
    """Every sample of a recording or a CAN log (decoded with layout at fs_hz), in memory."""
    from bogiemon.drivers.base import EndOfStream
    from bogiemon.drivers.replay import open_replay

    source = open_replay(path, rate=0, layout=layout, fs_hz=fs_hz, max_block_s=10.0)
    blocks = []
    try:
        while True:
            block = source.read(1.0)
            if block is not None and block.n_samples:
                blocks.append(block)
    except EndOfStream:
        pass
    finally:
        source.close()
    if not blocks:
        raise PlayError(f"{path}: no samples to play (for a CAN log: are --dbc and --layout those it was recorded with?)")
    return PlayedSamples(np.concatenate([b.accel_mps2 for b in blocks]), blocks[0].fs_hz, sum(b.gap_before for b in blocks[1:]))


def write_can_log(
    path: str | Path,
    layout: CanLayout,
    accel_mps2: NDArray[np.float64],
    fs_hz: float,
    start_s: float,
    channel: str = "can0",
) -> int:
    """Write a recording as a CAN log python-can reads back (.log as candump -L, .asc, .blf, .trc,
    python-can's .csv and .db, .mf4 with asammdf); returns frames.

    channel names the interface in a .log (what canplayer sends on); the others number channels.
    """
    n = 0
    with can.Logger(str(path)) as writer:  # dispatches on the suffix; reads no config
        for _, message in iter_messages(layout, accel_mps2, fs_hz, start_s=start_s):
            message.channel = channel if str(path).endswith(".log") else 0 if not str(path).endswith(".trc") else 1
            writer.on_message_received(message)
            n += 1
    return n
