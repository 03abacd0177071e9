"""The service in-process over a finite source: READY after data, STATUS, events, clean exit."""

import socket
from pathlib import Path

from bogiemon.daemon.config import parse_config
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.service import Service
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import MemorySource
from tests.daemon.synthetic import as_blocks, bogie_accel


class FiniteMemorySource(MemorySource):
    finite = True  # a recording: the ring waits instead of dropping


def test_service_runs_a_finite_source_to_its_end_and_reports_to_systemd(tmp_path: Path, short_config: Path) -> None:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(0)
    notifier = Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify"), "WATCHDOG_USEC": "2000000"})
    blocks = as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0))
    sink = MemorySink()
    service = Service(short_config, lambda config: FiniteMemorySource(blocks), notifier=notifier, sinks=[sink])
    assert service.run() == 0
    messages = []
    while True:
        try:
            messages.append(listener.recv(4096).decode())
        except BlockingIOError:
            break
    assert any(m.startswith("READY=1") for m in messages)
    assert messages[-1] == "STOPPING=1"
    assert [e.kind.value for e in sink.events] == ["SUSPECTED", "CONFIRMED"]
    stored = EventStore(parse_config(short_config.read_text(), "t").state.directory, readonly=True).events()
    assert stored == sink.events
