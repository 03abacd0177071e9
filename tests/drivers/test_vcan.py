"""The CAN path as on a bench: `bogiemon play` into the CAN source, and can-utils both ways over vcan0.

The play test runs on two kinds of bus with the same logic: 'socketcan' over a real kernel's vcan0,
the player `bogiemon play` in its own process as on a bench, and 'virtual', the same CLI in a
thread of this process (python-can's virtual bus does not cross processes), so the waiting below
runs everywhere. The vcan0 cases are marked `vcan`; they run where vcan0 is up (docs/drivers.md,
"The vcan bench") and are skipped elsewhere, as on a kernel without SocketCAN.

Nothing waits a fixed time: a test waits for the player's ready file (its bus is open, the first
frame comes next), then for the samples, and for the player's exit, all within PATIENCE_S. On a
small emulated VM starting Python alone takes a minute; a slow machine only waits longer, and a
player that ends early fails the test with its stderr.
"""

from __future__ import annotations

import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Protocol

import can
import numpy as np
import pytest

from bogiemon.cli.main import main
from bogiemon.drivers.base import Block
from bogiemon.drivers.can_source import CanBusPort, CanSource
from bogiemon.drivers.canbus import BusRole, open_bus
from bogiemon.drivers.player import encode_instants
from bogiemon.drivers.replay_can import CanLogReplaySource
from tests.drivers.frames import FS_HZ, HUB, LSB_MPS2, PER_NODE, channel_name, silences_heard, write_recording

CHANNEL = "vcan0"
BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
PATIENCE_S = 600.0  # the bound on one test's waiting: generous, a pass never comes near it
POLL_S = 0.05
# The ready file is polled often: the frames come right after it, and until the test reads them
# they wait in the socket's receive buffer (the per-node layout at --rate 5: 100 frames in 10 ms).
READY_POLL_S = 0.01
# How long a source waits for more once the player has ended: a frame it sent is already queued
# for the source (within microseconds on vcan0); this is for a machine busy elsewhere.
DRAIN_S = 2.0
PROBE_ID = 0x7FF  # an identifier no message of the DBC uses


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


needs_vcan0 = pytest.mark.skipif(
    not vcan0_up(),
    reason="needs a SocketCAN vcan0 interface that is up "
    "(ip link add dev vcan0 type vcan && ip link set up vcan0); this kernel has none",
)
ON_VCAN0 = [pytest.mark.vcan, needs_vcan0]
KINDS = [pytest.param("virtual"), pytest.param("socketcan", marks=ON_VCAN0)]


def needs(tool: str) -> None:
    if shutil.which(tool) is None:
        pytest.skip(f"needs can-utils' {tool} on PATH (apt-get install can-utils)")


# ---- players and waiting ---------------------------------------------------------------------


class Player(Protocol):
    name: str

    def finished(self) -> bool: ...

    def returncode(self) -> int | None: ...

    def stderr(self) -> str: ...

    def stop(self) -> None: ...


class PlayerProcess:
    """A sender run as its own process (`bogiemon play`, canplayer); its stderr goes to a file."""

    def __init__(self, name: str, argv: list[str], stderr_path: Path) -> None:
        self.name = name
        self._stderr_path = stderr_path
        with stderr_path.open("w") as err:  # the child keeps its own copy of the descriptor
            self._process = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)

    def finished(self) -> bool:
        return self._process.poll() is not None

    def returncode(self) -> int | None:
        return self._process.poll()

    def stderr(self) -> str:
        return self._stderr_path.read_text(errors="replace")

    def stop(self) -> None:
        if self._process.poll() is None:
            self._process.kill()
        self._process.wait()


class PlayerThread:
    """`bogiemon play` on the virtual bus: the CLI's main() in a thread of this process."""

    def __init__(self, argv: list[str]) -> None:
        self.name = "bogiemon play (in-process)"
        self._returncode: int | None = None
        self._error = ""
        self._thread = threading.Thread(target=self._run, args=(argv,), name="test-player", daemon=True)
        self._thread.start()

    def _run(self, argv: list[str]) -> None:
        try:
            self._returncode = main(argv)
        except BaseException:  # SystemExit from argparse too: reported as the player's failure
            self._error = traceback.format_exc()
            self._returncode = 1

    def finished(self) -> bool:
        return not self._thread.is_alive()

    def returncode(self) -> int | None:
        return self._returncode if self.finished() else None

    def stderr(self) -> str:
        return self._error or "(main() wrote to this process's stderr: see the captured output)"

    def stop(self) -> None:
        self._thread.join(timeout=10)


@contextmanager
def start_play(kind: str, argv: list[str], tmp_path: Path) -> Iterator[Player]:
    """`bogiemon play argv`: its own process on SocketCAN, a thread here on the virtual bus."""
    player = PlayerThread(argv) if kind == "virtual" else PlayerProcess("bogiemon play", [*BOGIEMON, *argv], tmp_path / "play.stderr")
    try:
        yield player
    finally:
        player.stop()


@contextmanager
def start_process(name: str, argv: list[str], stderr_path: Path) -> Iterator[PlayerProcess]:
    player = PlayerProcess(name, argv, stderr_path)
    try:
        yield player
    finally:
        player.stop()


def wait_until_ready(player: Player, ready_file: Path, deadline_s: float) -> None:
    """Until the player has written its ready file: its bus is open and its first frame comes next."""
    while not ready_file.exists():
        if player.finished() and not ready_file.exists():  # checked again: it may have written it, then ended
            pytest.fail(f"{player.name} ended (exit status {player.returncode()}) before it was ready:\n{player.stderr()}")
        if time.monotonic() > deadline_s:
            pytest.fail(f"{player.name} was not ready after {PATIENCE_S:g} s:\n{player.stderr()}")
        time.sleep(READY_POLL_S)


def read_while_playing(source: CanSource, player: Player, n: int, deadline_s: float) -> list[Block]:
    """Blocks from source until n samples are in, or the player has ended and the bus is drained.

    Reads while the player sends: a reader that waited for the sender to finish would depend on
    the socket buffer holding every frame (4000 of them in the per-node layout).
    """
    blocks: list[Block] = []
    got = 0
    while got < n:
        ended = player.finished()  # before the read: all it sent is then queued for the source
        block = source.read(DRAIN_S if ended else 0.2)
        if block is not None:
            blocks.append(block)
            got += block.n_samples
        elif ended:
            break  # the caller's checks say what is missing; the exit status says why
        if time.monotonic() > deadline_s:
            pytest.fail(f"{got} of {n} samples after {PATIENCE_S:g} s from {player.name}:\n{player.stderr()}")
    return blocks


def wait_until_ended(player: Player, deadline_s: float) -> int:
    """The player's exit status, once it has ended."""
    while not player.finished():
        if time.monotonic() > deadline_s:
            pytest.fail(f"{player.name} had not ended after {PATIENCE_S:g} s:\n{player.stderr()}")
        time.sleep(POLL_S)
    status = player.returncode()
    assert status is not None
    return status


# ---- the waiting itself, with real processes (runs everywhere) --------------------------------


def test_a_bogiemon_play_process_is_waited_for_until_ready_then_until_it_ends(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 50)
    argv = ["play", str(tmp_path / "run.csv"), "--interface", "virtual", "--channel", channel_name(), "--rate", "0"]
    deadline_s = time.monotonic() + PATIENCE_S
    with start_process("bogiemon play", [*BOGIEMON, *argv, "--ready-file", str(tmp_path / "ready")], tmp_path / "err") as player:
        wait_until_ready(player, tmp_path / "ready", deadline_s)
        assert wait_until_ended(player, deadline_s) == 0, player.stderr()
    assert "50 samples at 500 Hz as 50 hub frames" in player.stderr()


def test_a_player_process_that_ends_before_it_is_ready_fails_the_wait_with_its_stderr(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 10)
    argv = ["play", str(tmp_path / "run.csv"), "--interface", "socketcan", "--channel", "nosuchcan9"]
    with start_process("bogiemon play", [*BOGIEMON, *argv, "--ready-file", str(tmp_path / "ready")], tmp_path / "err") as player:
        with pytest.raises(pytest.fail.Exception) as info:
            wait_until_ready(player, tmp_path / "ready", time.monotonic() + PATIENCE_S)
    assert "bogiemon play ended (exit status 2) before it was ready:\nbogiemon: error: CAN interface 'nosuchcan9'" in str(info.value)


# ---- play into the CAN source: the virtual bus here, vcan0 where it is up ----------------------


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("layout", ["hub", "per-node"])
def test_bogiemon_play_into_the_can_source_reproduces_the_recording(tmp_path: Path, layout: str, kind: str) -> None:
    accel = write_recording(tmp_path / "run.csv", 1000, seed=5)  # a synthesised run, 2 s at 500 Hz
    channel = CHANNEL if kind == "socketcan" else channel_name()
    ready = tmp_path / "ready"
    argv = ["play", str(tmp_path / "run.csv"), "--interface", kind, "--channel", channel, "--rate", "5",
            "--layout", layout, "--ready-file", str(ready)]  # fmt: skip
    port = CanBusPort(kind, channel, receive_buffer_bytes=1 << 20)
    deadline_s = time.monotonic() + PATIENCE_S
    # Hears the receive stamps the source gets (its buffer holds all 4000 per-node frames).
    listener = CanBusPort(kind, channel, receive_buffer_bytes=1 << 23).open()
    try:
        with CanSource(port, HUB if layout == "hub" else PER_NODE, FS_HZ) as source:
            assert source.connected, source.last_error  # open before the player: no frame is missed
            with start_play(kind, argv, tmp_path) as player:
                wait_until_ready(player, ready, deadline_s)
                blocks = read_while_playing(source, player, 1000, deadline_s)
                assert wait_until_ended(player, deadline_s) == 0, player.stderr()
        silences = silences_heard(listener, source.layout)
    finally:
        listener.shutdown()
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (1000, 3)
    assert np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    counters = source.counters
    assert counters.bad_frames == 0 and counters.extra["lost_samples"] == 0 and counters.extra["duplicates"] == 0
    assert counters.extra["dropped_by_kernel"] == 0 and counters.extra["out_of_order"] == 0
    # A player held off longer than the sequence counter's silence bound (half a wrap, 0.25 s) by
    # a loaded machine or a slow VM pauses the receive stamps: the source then rightly starts a new
    # segment. Every sample is still there and in order (above), so only there are gaps allowed.
    assert counters.gaps <= silences
    granted = port.effective_receive_buffer_bytes  # a socket's buffer: SocketCAN only
    assert (granted is not None and granted > 0) if kind == "socketcan" else granted is None


# ---- can-utils on vcan0 ------------------------------------------------------------------------


def wait_until_candump_logs(candump: subprocess.Popen[bytes], log: Path, deadline_s: float) -> None:
    """Send probe frames until candump has logged one: it has bound its socket (it flushes every frame)."""
    probe = can.Message(arbitration_id=PROBE_ID, is_extended_id=False, data=b"\x00")
    bus = open_bus("socketcan", CHANNEL, BusRole.SENDER)
    try:
        while f" {PROBE_ID:03X}#" not in log.read_text():
            if candump.poll() is not None:
                pytest.fail(f"candump ended (exit status {candump.returncode}): {candump.communicate()[1].decode(errors='replace')}")
            if time.monotonic() > deadline_s:
                pytest.fail(f"candump logged no probe frame in {PATIENCE_S:g} s")
            bus.send(probe)
            time.sleep(0.1)
    finally:
        bus.shutdown()


def logged_frames(log: Path, frame_id: int) -> int:
    """Lines of a candump -L log, `(time) vcan0 ID#DATA`, with frame_id (a line being written is not one yet)."""
    fields = (line.split() for line in log.read_text().splitlines())
    return sum(len(f) == 3 and f[2].startswith(f"{frame_id:03X}#") for f in fields)


@pytest.mark.vcan
@needs_vcan0
def test_a_candump_log_of_play_replays_through_the_replay_source(tmp_path: Path) -> None:
    needs("candump")
    accel = write_recording(tmp_path / "run.csv", 600, seed=6)
    log = tmp_path / "candump.log"
    deadline_s = time.monotonic() + PATIENCE_S
    with log.open("w") as out:
        candump = subprocess.Popen(["candump", "-L", CHANNEL], stdout=out, stderr=subprocess.PIPE)
        try:
            wait_until_candump_logs(candump, log, deadline_s)
            argv = [*BOGIEMON, "play", str(tmp_path / "run.csv"), "--interface", "socketcan", "--channel", CHANNEL, "--rate", "5"]
            with start_process("bogiemon play", argv, tmp_path / "play.stderr") as player:
                assert wait_until_ended(player, deadline_s) == 0, player.stderr()
            # Every frame is in candump's socket by now; wait until it has written them all.
            (hub_id,) = {m.frame_id for m in HUB.data_messages}
            while logged_frames(log, hub_id) < 600 and time.monotonic() < deadline_s:
                time.sleep(POLL_S)
        finally:
            candump.send_signal(signal.SIGINT)
            candump.wait(timeout=10)
    # The log of play's frames: without the probe frames sent before the player started.
    played = tmp_path / "play.log"
    played.write_text("".join(line for line in log.read_text().splitlines(True) if f" {PROBE_ID:03X}#" not in line))
    source = CanLogReplaySource(played, HUB, FS_HZ, rate=0)
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


@pytest.mark.vcan
@needs_vcan0
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
    deadline_s = time.monotonic() + PATIENCE_S
    with CanSource(CanBusPort("socketcan", CHANNEL, 1 << 20), HUB, FS_HZ) as source:
        assert source.connected, source.last_error
        # canplayer keeps the log's time gaps (real time, 1 s here) and sends on the interface
        # named in each line.
        with start_process("canplayer", ["canplayer", "-I", str(tmp_path / "hub.log")], tmp_path / "canplayer.stderr") as player:
            blocks = read_while_playing(source, player, n, deadline_s)
            assert wait_until_ended(player, deadline_s) == 0, player.stderr()
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (n, 3) and np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    assert source.counters.gaps == 0 and source.counters.extra["dropped_by_kernel"] == 0


# ---- the recvmmsg reader on a real AF_CAN socket ------------------------------------------------


def mixed_frames() -> list[can.Message]:
    """The hub's frames with what else a bus carries: a 29-bit identifier, a remote frame, short and empty data."""
    frames = [can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes([k, 1, 2, 3, 4, 5, 6, 7])) for k in range(40)]
    frames[5:5] = [
        can.Message(arbitration_id=0x1ABCDEF, is_extended_id=True, data=b"\x01\x02\x03"),
        can.Message(arbitration_id=0x123, is_extended_id=False, is_remote_frame=True, dlc=4),
        can.Message(arbitration_id=0x7FF, is_extended_id=False, data=b""),
        can.Message(arbitration_id=0x80, is_extended_id=True, data=b"\xff" * 8),
    ]
    return frames


@pytest.mark.vcan
@needs_vcan0
def test_on_vcan0_the_socket_reader_reads_what_python_can_reads() -> None:
    from bogiemon.drivers.can_frames import FrameBatch, SocketFrameReader

    ours = open_bus("socketcan", CHANNEL, BusRole.RECEIVER)
    theirs = open_bus("socketcan", CHANNEL, BusRole.RECEIVER)
    sender = open_bus("socketcan", CHANNEL, BusRole.SENDER)
    try:
        sent = mixed_frames()
        for message in sent:
            sender.send(message)
        reader = SocketFrameReader(ours.socket, capacity=128)  # type: ignore[attr-defined]
        got_n = 0
        deadline_s = time.monotonic() + PATIENCE_S
        while got_n < len(sent) and time.monotonic() < deadline_s:
            got_n += reader.receive(128 - got_n, 1.0)
        python_can = [m for m in (theirs.recv(timeout=10.0) for _ in sent) if m is not None]
        assert got_n == len(python_can) == len(sent)
        got, expected = reader.take(), FrameBatch.from_messages(python_can)
        np.testing.assert_array_equal(got.key, expected.key)
        np.testing.assert_array_equal(got.length, expected.length)
        np.testing.assert_array_equal(got.data, expected.data)
        np.testing.assert_array_equal(got.flags, expected.flags)
        # Each socket gets the kernel's one receive stamp of the frame, read by either reader.
        np.testing.assert_allclose(got.time_s, expected.time_s, rtol=0, atol=1e-6)
    finally:
        for bus in (ours, theirs, sender):
            bus.shutdown()


@pytest.mark.vcan
@needs_vcan0
def test_on_vcan0_the_kernels_drop_count_is_what_a_full_receive_buffer_lost() -> None:
    from bogiemon.drivers.can_frames import SocketFrameReader
    from bogiemon.drivers.can_source import set_receive_buffer, socket_drops

    receiver = open_bus("socketcan", CHANNEL, BusRole.RECEIVER)
    sender = open_bus("socketcan", CHANNEL, BusRole.SENDER)
    try:
        sock = receiver.socket  # type: ignore[attr-defined]
        set_receive_buffer(sock, 4096)  # a few frames' worth: the kernel's minimum
        assert socket_drops(sock) == 0
        n = 300
        for k in range(n):  # nobody reads meanwhile
            sender.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=bytes([k % 256] * 8)))
        reader = SocketFrameReader(sock, capacity=n)
        received = 0
        while reader.receive(n, 0.5):
            received += reader.take().n
        dropped = socket_drops(sock)
        assert 0 < received < n and dropped == n - received
    finally:
        receiver.shutdown()
        sender.shutdown()
