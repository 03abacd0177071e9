"""The CAN path over a real kernel's vcan0: play -> SocketCAN source, and can-utils both ways.

Run where vcan0 is up (docs/drivers.md, "The vcan bench"); skipped elsewhere, as on a kernel
without SocketCAN. The player runs as `bogiemon play` in its own process, as on a bench.
"""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bogiemon.drivers.can_source import CanSource, SocketcanBusPort
from bogiemon.drivers.player import encode_instants
from bogiemon.drivers.replay import CanLogReplaySource
from tests.drivers.frames import FS_HZ, HUB, LSB_MPS2, PER_NODE, write_recording

CHANNEL = "vcan0"
BOGIEMON = [sys.executable, "-m", "bogiemon.daemon.cli.main"]


def vcan0_up() -> bool:
    try:
        flags = int(Path(f"/sys/class/net/{CHANNEL}/flags").read_text().strip(), 16)
    except (OSError, ValueError):
        return False
    if not flags & 0x1:  # IFF_UP
        return False
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except OSError:
        return False
    return True


pytestmark = [
    pytest.mark.vcan,
    pytest.mark.skipif(
        not vcan0_up(),
        reason="needs a SocketCAN vcan0 interface that is up "
        "(ip link add dev vcan0 type vcan && ip link set up vcan0); this kernel has none",
    ),
]


def needs(tool: str) -> None:
    if shutil.which(tool) is None:
        pytest.skip(f"needs can-utils' {tool} on PATH (apt-get install can-utils)")


def read_samples(source: CanSource, n: int, timeout_s: float = 30.0) -> list:
    blocks, got, end = [], 0, time.monotonic() + timeout_s
    while got < n and time.monotonic() < end:
        block = source.read(0.2)
        if block is not None:
            blocks.append(block)
            got += block.n_samples
    return blocks


@pytest.mark.parametrize("layout", ["hub", "per-node"])
def test_play_over_vcan0_into_the_socketcan_source_reproduces_the_recording(tmp_path: Path, layout: str) -> None:
    accel = write_recording(tmp_path / "run.csv", 1000, seed=5)  # a synthesised run, 2 s at 500 Hz
    port = SocketcanBusPort(CHANNEL, receive_buffer_bytes=1 << 20)
    with CanSource(port, HUB if layout == "hub" else PER_NODE, FS_HZ) as source:
        assert source.connected, source.last_error
        # Read while the player sends: a reader that waits for the sender to finish would depend
        # on the socket buffer holding every frame (4000 of them in the per-node layout).
        player = subprocess.Popen(
            [*BOGIEMON, "play", str(tmp_path / "run.csv"), "--interface", "socketcan", "--channel", CHANNEL,
             "--rate", "5", "--layout", layout],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        blocks = read_samples(source, 1000)
        _, stderr = player.communicate(timeout=60)
        assert player.returncode == 0, stderr
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (1000, 3)
    assert np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    counters = source.counters
    assert counters.gaps == 0 and counters.bad_frames == 0
    assert counters.extra["dropped_by_kernel"] == 0 and counters.extra["lost_samples"] == 0
    assert port.effective_receive_buffer_bytes is not None and port.effective_receive_buffer_bytes > 0


def test_a_candump_log_of_play_replays_through_the_replay_source(tmp_path: Path) -> None:
    needs("candump")
    accel = write_recording(tmp_path / "run.csv", 600, seed=6)
    log = tmp_path / "play.log"
    with log.open("w") as out:
        candump = subprocess.Popen(["candump", "-L", CHANNEL], stdout=out, stderr=subprocess.PIPE)
        try:
            time.sleep(0.5)  # candump has bound its socket
            player = subprocess.run(
                [*BOGIEMON, "play", str(tmp_path / "run.csv"), "--interface", "socketcan", "--channel", CHANNEL, "--rate", "5"],
                capture_output=True, text=True, timeout=60,
            )  # fmt: skip
            assert player.returncode == 0, player.stderr
            time.sleep(0.5)  # candump has written the last frames
        finally:
            candump.send_signal(signal.SIGINT)
            candump.wait(timeout=10)
    source = CanLogReplaySource(log, HUB, FS_HZ, rate=0)
    blocks = []
    try:
        while True:
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    except Exception as exc:  # EndOfStream ends the loop; anything else fails below
        assert type(exc).__name__ == "EndOfStream", repr(exc)
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (600, 3) and np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    assert source.counters.gaps == 0 and source.counters.bad_frames == 0


def test_canplayer_feeds_the_socketcan_source(tmp_path: Path) -> None:
    needs("canplayer")
    n = 500
    accel = np.random.default_rng(8).standard_normal((n, 3)) * 2 + 9.81
    # The log in candump -L's classic form, written here so nothing of bogiemon's player is used.
    lines = []
    for k, frames in enumerate(encode_instants(HUB, accel)):
        for frame_id, _, payload in frames:
            lines.append(f"({1000 + k / FS_HZ:.6f}) {CHANNEL} {frame_id:03X}#{payload.hex().upper()}\n")
    (tmp_path / "hub.log").write_text("".join(lines))
    with CanSource(SocketcanBusPort(CHANNEL, 1 << 20), HUB, FS_HZ) as source:
        assert source.connected, source.last_error
        # canplayer keeps the log's time gaps (real time, 1 s here) and sends on the interface
        # named in each line.
        player = subprocess.Popen(["canplayer", "-I", str(tmp_path / "hub.log")], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        blocks = read_samples(source, n)
        _, stderr = player.communicate(timeout=60)
        assert player.returncode == 0, stderr
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (n, 3) and np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    assert source.counters.gaps == 0 and source.counters.extra["dropped_by_kernel"] == 0
