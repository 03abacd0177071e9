"""drivers/canbus.py: every bus opened with exactly the table's settings, receiver and sender differing only where meant."""

from __future__ import annotations

import errno
import inspect
import socket
from typing import Any

import can
import can.interfaces.socketcan
import pytest
from can.interfaces.virtual import VirtualBus

from bogiemon.drivers.canbus import KINDS, BusRole, UnknownBusKind, bus_arguments, open_bus
from bogiemon.drivers.player import PlayError, open_player_bus
from tests.drivers.frames import channel_name


def af_can_available() -> bool:
    try:
        socket.socket(socket.AF_CAN, socket.SOCK_RAW, socket.CAN_RAW).close()
    except (OSError, AttributeError):
        return False
    return True


SOCKETCAN_SHARED = {"receive_own_messages": False, "local_loopback": True, "fd": False, "can_filters": None}


@pytest.mark.parametrize(
    ("kind", "role", "expected"),
    [
        ("virtual", BusRole.RECEIVER, {"receive_own_messages": False, "rx_queue_size": 0, "preserve_timestamps": False}),
        ("virtual", BusRole.SENDER, {"receive_own_messages": False, "rx_queue_size": 0, "preserve_timestamps": False}),
        ("socketcan", BusRole.RECEIVER, {**SOCKETCAN_SHARED, "ignore_rx_error_frames": False}),
        ("socketcan", BusRole.SENDER, {**SOCKETCAN_SHARED, "ignore_rx_error_frames": True}),
    ],
)  # fmt: skip
def test_each_kind_and_role_gets_every_setting_spelled_out(kind: str, role: BusRole, expected: dict[str, Any]) -> None:
    assert bus_arguments(kind, "ch0", role) == {"channel": "ch0", **expected}


def test_every_setting_is_a_keyword_of_its_interface_class() -> None:
    # A misspelt keyword would reach BusABC's **kwargs and be ignored silently.
    for kind in KINDS.values():
        accepted = inspect.signature(kind.interface_class().__init__).parameters
        for role in BusRole:
            assert set(kind.settings(role)) <= set(accepted), kind.class_name


def test_the_socketcan_kind_calls_socketcans_bus_class_with_the_table_arguments(monkeypatch: pytest.MonkeyPatch) -> None:
    calls: list[dict[str, Any]] = []

    class RecordingSocketcanBus(can.BusABC):
        def __init__(self, **kwargs: Any) -> None:
            calls.append(kwargs)
            super().__init__(channel=kwargs["channel"])

        def send(self, msg: can.Message, timeout: float | None = None) -> None:  # pragma: no cover - never sent on
            pass

        def _recv_internal(self, timeout: float | None) -> tuple[None, bool]:  # pragma: no cover - never read
            return None, False

    monkeypatch.setattr(can.interfaces.socketcan, "SocketcanBus", RecordingSocketcanBus)
    open_bus("socketcan", "can7", BusRole.RECEIVER).shutdown()
    open_player_bus("socketcan", "can7").shutdown()
    assert calls == [bus_arguments("socketcan", "can7", BusRole.RECEIVER), bus_arguments("socketcan", "can7", BusRole.SENDER)]


@pytest.mark.skipif(af_can_available(), reason="this kernel has SocketCAN; the vcan tests cover it")
def test_without_af_can_the_socketcan_kind_raises_eafnosupport_and_the_player_says_so_in_one_line() -> None:
    with pytest.raises(OSError) as info:
        open_bus("socketcan", "vcan0", BusRole.RECEIVER)
    assert info.value.errno == errno.EAFNOSUPPORT
    with pytest.raises(PlayError) as play_info:
        open_player_bus("socketcan", "vcan0")
    assert str(play_info.value) == (
        "CAN interface 'vcan0': this kernel has no SocketCAN (AF_CAN): use a Linux kernel with the can and "
        "vcan modules (`modprobe vcan`), or make a CAN log without a bus: `bogiemon convert FILE -o run.log`"
    )


def test_a_virtual_sender_never_reads_its_own_frames_and_a_receiver_on_the_channel_gets_them() -> None:
    channel = channel_name()
    receiver = open_bus("virtual", channel, BusRole.RECEIVER)
    sender = open_bus("virtual", channel, BusRole.SENDER)
    try:
        assert isinstance(receiver, VirtualBus) and isinstance(sender, VirtualBus)
        sender.send(can.Message(arbitration_id=0x100, is_extended_id=False, data=b"\x01\x02"))
        got = receiver.recv(timeout=1.0)
        assert got is not None and (got.arbitration_id, bytes(got.data)) == (0x100, b"\x01\x02")
        assert sender.recv(timeout=0.05) is None
    finally:
        sender.shutdown()
        receiver.shutdown()


def test_an_unknown_kind_names_the_known_ones() -> None:
    with pytest.raises(UnknownBusKind, match=r"^unknown CAN interface 'pcan': use 'socketcan' or 'virtual'$"):
        open_bus("pcan", "can0", BusRole.SENDER)
    with pytest.raises(PlayError, match=r"^unknown CAN interface 'pcan': use 'socketcan' or 'virtual'$"):
        open_player_bus("pcan", "can0")
