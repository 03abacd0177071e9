"""sd_notify over a real datagram socket of our own, as systemd would receive it."""

import os
import socket
from pathlib import Path

from bogiemon.daemon.notify import Notifier


def listen(path: Path) -> socket.socket:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.settimeout(2)
    return sock


def test_ready_status_and_watchdog_arrive_as_systemd_expects(tmp_path: Path) -> None:
    sock = listen(tmp_path / "notify")
    n = Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify")})
    assert n.ready(status="running")
    assert sock.recv(4096) == b"READY=1\nSTATUS=running"
    n.watchdog()
    assert sock.recv(4096) == b"WATCHDOG=1"
    n.reloading()
    lines = sock.recv(4096).decode().split("\n")
    assert lines[0] == "RELOADING=1" and lines[1].startswith("MONOTONIC_USEC=") and int(lines[1].split("=")[1]) > 0


def test_abstract_socket_names_start_with_a_nul(tmp_path: Path) -> None:
    name = f"bogiemon-test-{os.getpid()}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind("\0" + name)
    sock.settimeout(2)
    assert Notifier({"NOTIFY_SOCKET": "@" + name}).notify(stopping=1)
    assert sock.recv(100) == b"STOPPING=1"


def test_without_notify_socket_everything_is_a_no_op() -> None:
    n = Notifier({})
    assert not n.enabled and n.ready() is False and n.watchdog_interval_s is None


def test_watchdog_interval_is_read_only_for_this_process() -> None:
    assert Notifier({"WATCHDOG_USEC": "3000000"}).watchdog_interval_s == 3.0
    assert Notifier({"WATCHDOG_USEC": "3000000", "WATCHDOG_PID": str(os.getpid())}).watchdog_interval_s == 3.0
    assert Notifier({"WATCHDOG_USEC": "3000000", "WATCHDOG_PID": "1"}).watchdog_interval_s is None


def test_a_vanished_manager_is_not_an_error(tmp_path: Path) -> None:
    assert Notifier({"NOTIFY_SOCKET": str(tmp_path / "gone")}).ready() is False
