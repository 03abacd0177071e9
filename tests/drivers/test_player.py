"""The player: pacing exactly on schedule, a full transmit queue waited out, and `bogiemon play` as users run it."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import can
import can.interfaces.virtual
import numpy as np
import pytest

from bogiemon.cli import play as play_command
from bogiemon.cli.main import main
from bogiemon.drivers.candb import LAYOUTS
from bogiemon.drivers.can_source import CanBusPort, CanSource
from bogiemon.drivers.player import PlayError, play
from tests.drivers.frames import FS_HZ, HUB, LSB_MPS2, PER_NODE, channel_name, coded_accel, silences_heard, write_recording


class RecordingBus(can.BusABC):
    """A bus double that notes the (fake) time of every send; can refuse sends with ENOBUFS."""

    def __init__(self, clock, refuse: int = 0) -> None:
        super().__init__(channel="rec")
        self.clock = clock
        self.refuse = refuse
        self.sent: list[tuple[float, can.Message]] = []
        self.channel_info = "recording bus"

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if self.refuse:
            self.refuse -= 1
            raise can.CanOperationError("Failed to transmit: No buffer space available", 105)
        self.sent.append((self.clock(), msg))

    def _recv_internal(self, timeout):  # pragma: no cover - never received from
        return None, False


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 0.0

    def __call__(self) -> float:
        return self.now_s

    def sleep(self, seconds: float) -> None:
        self.now_s += seconds


class StallingClock(FakeClock):
    """The wall clock of a player thread that the machine stalls for stall_s after the first send."""

    def __init__(self, stall_s: float) -> None:
        super().__init__()
        self.stall_s = stall_s

    def stall(self) -> None:
        self.now_s += self.stall_s
        self.stall_s = 0.0


def test_a_stamped_hub_stamps_each_frame_on_its_own_clock_through_a_stall() -> None:
    # The simulated hub (daemon/simsource.py) sends on a stamped virtual bus: a player thread the
    # machine stalls for half a second sends late, but its frames keep the hub's pace in their
    # stamps, so the source reads no silence (a silence past 0.254 s starts a new segment).
    clock = StallingClock(0.5)
    receiver = can.interfaces.virtual.VirtualBus(channel="stamped-hub", receive_own_messages=False)
    sender = can.interfaces.virtual.VirtualBus(channel="stamped-hub", preserve_timestamps=True)

    class Stalls(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="stamped-hub")

        def send(self, msg: can.Message, timeout: float | None = None) -> None:
            sender.send(msg)
            clock.stall()

        def _recv_internal(self, timeout):  # pragma: no cover - never received from
            return None, False

    try:
        play(Stalls(), HUB, np.zeros((20, 3)), FS_HZ, rate=10.0, clock=clock, sleep=clock.sleep, stamp_start_s=1000.0)
        stamps = [receiver.recv(1.0).timestamp for _ in range(20)]
    finally:
        receiver.shutdown()
        sender.shutdown()
    assert stamps == pytest.approx([1000.0 + i / FS_HZ / 10.0 for i in range(20)])
    assert clock.now_s >= 0.5  # the sender really stalled


@pytest.mark.parametrize("rate", [1.0, 4.0])
def test_each_instant_is_sent_at_its_time_divided_by_the_rate(rate: float) -> None:
    clock = FakeClock()
    bus = RecordingBus(clock)
    stats = play(bus, PER_NODE, np.zeros((50, 3)), FS_HZ, rate=rate, clock=clock, sleep=clock.sleep)
    assert (stats.instants, stats.frames) == (50, 200)
    times = np.array([t for t, _ in bus.sent]).reshape(50, 4)
    np.testing.assert_allclose(times, np.repeat(np.arange(50)[:, None] / FS_HZ / rate, 4, axis=1), atol=1e-12)
    assert [m.arbitration_id for _, m in bus.sent[:4]] == [0x080, 0x101, 0x102, 0x103]  # Sync first
    bus.shutdown()


def test_rate_zero_never_waits() -> None:
    clock = FakeClock()
    bus = RecordingBus(clock)
    play(bus, HUB, np.zeros((100, 3)), FS_HZ, rate=0, clock=clock, sleep=clock.sleep)
    assert clock.now_s == 0.0 and len(bus.sent) == 100
    bus.shutdown()


def test_a_full_transmit_queue_is_waited_out_then_given_up_on() -> None:
    clock = FakeClock()
    bus = RecordingBus(clock, refuse=5)
    play(bus, HUB, np.zeros((3, 3)), FS_HZ, rate=0, clock=clock, sleep=clock.sleep)
    assert len(bus.sent) == 3
    bus.refuse = 10**6
    with pytest.raises(PlayError, match="transmit queue stayed full for 2 s"):
        play(bus, HUB, np.zeros((3, 3)), FS_HZ, rate=0, clock=clock, sleep=clock.sleep)
    bus.shutdown()


@pytest.mark.parametrize("layout", ["hub", "per-node"])
def test_cli_play_on_the_virtual_bus_feeds_the_can_source(tmp_path: Path, layout: str) -> None:
    accel = write_recording(tmp_path / "run.csv", 800)
    channel = channel_name()
    listener = can.interfaces.virtual.VirtualBus(channel=channel)  # hears the stamps the source gets
    try:
        with CanSource(CanBusPort("virtual", channel), HUB if layout == "hub" else PER_NODE, FS_HZ) as source:
            argv = ["play", str(tmp_path / "run.csv"), "--interface", "virtual", "--channel", channel, "--rate", "0"]
            assert main([*argv, "--layout", layout]) == 0
            blocks = []
            while (block := source.read(0.05)) is not None:
                blocks.append(block)
        silences = silences_heard(listener, source.layout)
    finally:
        listener.shutdown()
    got = np.concatenate([b.accel_mps2 for b in blocks])
    assert got.shape == (800, 3) and np.abs(got - accel).max() <= LSB_MPS2 / 2 + 1e-12
    # The player stamps frames with the wall clock: a stall of this shared machine can pause them.
    assert source.counters.gaps <= silences and source.counters.bad_frames == 0


def test_cli_play_at_real_time_pace_runs_beside_a_reader(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 100)  # 0.2 s
    channel = channel_name()
    with CanSource(CanBusPort("virtual", channel), HUB, FS_HZ) as source:
        player = threading.Thread(target=main, args=(["play", str(tmp_path / "run.csv"), "--interface", "virtual", "--channel", channel],))
        player.start()
        got = 0
        while got < 100 and (block := source.read(0.3)) is not None:
            got += block.n_samples
        player.join()
    assert got == 100


def test_cli_play_writes_its_ready_file_before_the_first_frame(tmp_path: Path) -> None:
    write_recording(tmp_path / "run.csv", 100)  # 0.2 s at real time: the reader gets a block before the end
    channel, ready = channel_name(), tmp_path / "ready"
    argv = ["play", str(tmp_path / "run.csv"), "--interface", "virtual", "--channel", channel, "--ready-file", str(ready)]
    with CanSource(CanBusPort("virtual", channel), HUB, FS_HZ, max_block_s=0.02) as source:
        player = threading.Thread(target=main, args=(argv,))
        player.start()
        try:
            block = source.read(5.0)  # returns at the first 10 samples (max_block_s), 20 ms into the run
            assert block is not None and block.n_samples == 10
            assert ready.read_text() == f"virtual {channel}\n"  # there when the first frame arrived
        finally:
            player.join()


def test_cli_play_on_the_virtual_interface_says_no_other_program_heard_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    write_recording(tmp_path / "run.csv", 100)
    assert main(["play", str(tmp_path / "run.csv"), "--interface", "virtual", "--channel", channel_name(), "--rate", "0"]) == 0
    note = capsys.readouterr().err.splitlines()[-1]
    assert note.startswith("# note: the virtual interface is a bus inside this process: no other program heard these frames.")
    assert "--interface socketcan --channel vcan0" in note and "bogiemon convert" in note


def test_cli_play_sends_a_can_log_decoded_with_its_dbc(tmp_path: Path) -> None:
    from bogiemon.drivers.player import write_can_log

    accel = coded_accel(np.arange(300))
    write_can_log(tmp_path / "run.log", HUB, accel, FS_HZ, start_s=1.7645e9)
    channel = channel_name()
    with CanSource(CanBusPort("virtual", channel), HUB, FS_HZ) as source:
        assert main(["play", str(tmp_path / "run.log"), "--interface", "virtual", "--channel", channel, "--rate", "0"]) == 0
        blocks = []
        while (block := source.read(0.05)) is not None:
            blocks.append(block)
    np.testing.assert_array_equal(np.concatenate([b.accel_mps2 for b in blocks]), accel)


def test_cli_play_offers_the_layouts_of_the_dbc_module() -> None:
    assert play_command.LAYOUT_CHOICES == LAYOUTS


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--interface", "socketcan", "--channel", "nosuchcan9"], "bogiemon: error: CAN interface 'nosuchcan9'"),
        (["--rate", "-1", "--interface", "virtual"], "bogiemon: error: --rate must be 0 (as fast as possible) or positive, got -1"),
        (["--dbc", "missing.dbc", "--interface", "virtual"], "bogiemon: error: missing.dbc: cannot read the DBC file"),
        (["--interface", "virtual", "--ready-file", "no/such/dir/ready"],
         "bogiemon: error: --ready-file no/such/dir/ready: cannot write: No such file or directory"),
    ],
)
def test_cli_play_user_errors_are_one_line_and_exit_2(tmp_path: Path, args: list[str], message: str) -> None:
    write_recording(tmp_path / "run.csv", 10)
    cmd = [sys.executable, "-m", "bogiemon.cli.main", "play", str(tmp_path / "run.csv"), *args]
    result = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path, timeout=60)
    assert result.returncode == 2
    assert result.stderr.startswith(message)
    assert result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
