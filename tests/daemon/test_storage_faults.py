"""Storage faults on real file systems: a full disk (a small tmpfs filled to the last page),
read-only media (a tmpfs remounted read-only), and a store that turns read-only under a running
monitor (SQLite's query_only on its connection: no remount can take open files read-only).

The tmpfs tests need root (mount); elsewhere they are skipped and say so, and the query_only
tests still cover the monitor's hold-and-retry.
"""

from __future__ import annotations

import io
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import parse_config
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.logs import configure_logging
from bogiemon.daemon.monitor import Monitor
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.replay import replay
from bogiemon.daemon.service import EXIT_OK, EXIT_STORE_FAILED, Service
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.store import EventStore, StoreError, StoreWriteError
from bogiemon.drivers.base import MemorySource
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config
from tests.judgement.event_examples import CHILD_EVENT, CHILD_IMPORTS, event_of

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
CONFIG_TEXT = short_windows_config(clear_after_windows=2)
KINDS = ["SUSPECTED", "CONFIRMED", "CLEARED"]  # what the signals below give, with no fault


def signals() -> np.ndarray:
    """A coupled (faulty) stretch, then a healthy one: SUSPECTED, CONFIRMED, CLEARED."""
    return np.concatenate([bogie_accel(20, 3, pitch_roll_coupling=1.0), bogie_accel(40, 4)])


class Disk:
    """A small tmpfs of our own: filled to the last byte, freed, remounted read-only."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.filler = root / "filler"

    def fill(self) -> None:
        fd = os.open(self.filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        try:
            for chunk in (1 << 16, 512, 1):
                try:
                    while True:
                        os.write(fd, b"\0" * chunk)
                except OSError as exc:
                    assert exc.errno == 28  # ENOSPC
        finally:
            os.close(fd)

    @property
    def full(self) -> bool:
        return self.filler.exists()

    def free(self) -> None:
        self.filler.unlink()

    def remount(self, options: str) -> None:
        subprocess.run(["mount", "-o", f"remount,{options}", str(self.root)], check=True, capture_output=True)


@pytest.fixture
def disk(tmp_path: Path) -> Iterator[Disk]:
    root = tmp_path / "disk"
    root.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root (the query_only tests cover the logic)")
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=8m,mode=0755", "tmpfs", str(root)], capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
    try:
        yield Disk(root)
    finally:
        subprocess.run(["umount", "-l", str(root)], capture_output=True)


class Recorder(EventSink):
    """A sink that records what it was given, and may act on the storage after the n-th event."""

    def __init__(self, after_n: int = 0, action: Callable[[], object] | None = None) -> None:
        self.events: list[Event] = []
        self._after_n = after_n
        self._action = action

    def publish(self, event: Event) -> None:
        self.events.append(event)
        if self._action is not None and len(self.events) == self._after_n:
            self._action()


def crit_lines(log: io.StringIO) -> list[dict]:
    """The log lines journald files at crit: a "<2>" prefix on the JSON."""
    return [json.loads(line[3:]) for line in log.getvalue().splitlines() if line.startswith("<2>")]


def stored(state_dir: Path) -> list[Event]:
    store = EventStore(state_dir, readonly=True)
    try:
        return store.events()
    finally:
        store.close()


def feed(monitor: Monitor, accel: np.ndarray) -> None:
    for block in as_blocks(accel):
        monitor.feed(block)


# The monitor: hold what the store refuses, retry at every window, report only what is committed.


def test_a_monitor_holds_what_a_full_disk_refuses_and_commits_and_reports_it_in_order_once_freed(disk: Disk) -> None:
    log = io.StringIO()
    configure_logging(log)
    state = disk.root / "state"
    sink = Recorder(after_n=1, action=disk.fill)  # the disk fills right after the first event
    reported_while_full: list[int] = []

    def free_after_three_failures(report: WindowVerdict) -> None:
        if disk.full:
            reported_while_full.append(len(sink.events))
            if monitor.store_failures == 3:
                disk.free()

    monitor = Monitor(parse_config(CONFIG_TEXT, "t").monitor_settings(), EventStore(state), [sink], [free_after_three_failures], hold_uncommitted=True)
    feed(monitor, signals())
    assert [e.kind.value for e in sink.events] == KINDS
    assert stored(state) == sink.events  # committed late, in order, nothing lost or doubled
    assert set(reported_while_full) == {1}  # nothing reported while it could not be committed
    assert monitor.store_failures == 3 and monitor.held == [] and monitor.store_failure is None
    crit = crit_lines(log)
    assert len(crit) == 3 and all(line["level"] == "critical" and "database or disk is full" in line["error"] for line in crit)
    assert [line["held_kinds"] for line in crit] == [["CONFIRMED"]] * 3


def test_a_monitor_holds_what_a_store_turned_read_only_refuses_and_commits_it_once_writable(tmp_path: Path) -> None:
    log = io.StringIO()
    configure_logging(log)
    store = EventStore(tmp_path)
    sink = Recorder(after_n=1, action=lambda: store.connection.execute("PRAGMA query_only=1"))

    def writable_after_two_failures(report: WindowVerdict) -> None:
        if monitor.store_failures == 2:
            store.connection.execute("PRAGMA query_only=0")

    monitor = Monitor(parse_config(CONFIG_TEXT, "t").monitor_settings(), store, [sink], [writable_after_two_failures], hold_uncommitted=True)
    feed(monitor, signals())
    assert [e.kind.value for e in sink.events] == KINDS
    assert store.events() == sink.events
    assert store.get_state("monitor")["decision"]["mode"] == monitor.mode == "normal"  # committed with CLEARED
    assert [line["level"] for line in crit_lines(log)] == ["critical", "critical"]
    assert "is read-only" in crit_lines(log)[0]["error"]


def test_a_monitor_stops_with_a_store_write_error_once_it_holds_more_than_its_bound(tmp_path: Path) -> None:
    store = EventStore(tmp_path)
    sink = Recorder(after_n=1, action=lambda: store.connection.execute("PRAGMA query_only=1"))
    monitor = Monitor(parse_config(CONFIG_TEXT, "t").monitor_settings(), store, [sink], hold_uncommitted=True, max_held_events=0)
    with pytest.raises(StoreWriteError, match=r"1 events could not be committed, more than the 0 held in memory: stopping"):
        feed(monitor, signals())
    assert store.events() == sink.events and len(sink.events) == 1


# replay: a full disk ends it with one clear error; what was committed before stays.


def test_replay_on_a_disk_that_fills_ends_with_a_store_write_error_keeping_every_event_before(disk: Disk, tmp_path: Path) -> None:
    path = tmp_path / "run.csv"
    accel = signals()
    write_csv_recording(path, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    sink = Recorder(after_n=1, action=disk.fill)
    with pytest.raises(StoreWriteError, match=r"cannot commit to the event store: database or disk is full \(the file system of .+ is full"):
        replay([path], parse_config(CONFIG_TEXT, "t"), state_dir=disk.root / "state", sinks=[sink])
    disk.free()
    assert [e.kind.value for e in sink.events] == ["SUSPECTED"]
    assert stored(disk.root / "state") == sink.events


def test_the_replay_command_on_a_full_disk_says_so_in_one_line_with_status_2(disk: Disk, tmp_path: Path) -> None:
    accel = signals()
    write_csv_recording(tmp_path / "run.csv", 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    (tmp_path / "cfg.toml").write_text(CONFIG_TEXT)
    before = event_of(EventKind.SUSPECTED, 1.6e9, config_hash="old")
    holder = EventStore(disk.root / "state")  # held open, so its -wal and -shm files stay in place
    holder.append([before])
    disk.fill()
    proc = subprocess.run(
        [*BOGIEMON, "replay", str(tmp_path / "run.csv"), "--config", str(tmp_path / "cfg.toml"), "--state-dir", str(disk.root / "state")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    holder.close()
    assert proc.returncode == 2, proc.stderr
    assert proc.stdout == ""  # no event reported: none was committed
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("bogiemon: error: ") and "database or disk is full" in lines[0]
    disk.free()
    assert stored(disk.root / "state") == [before]


# run: the service holds, logs at crit, tells systemd; it exits 3 only when it cannot keep what it holds.


class FiniteMemorySource(MemorySource):
    finite = True  # a recording: the ring waits instead of dropping


class NotifySocket:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(path))
        self.sock.settimeout(0)
        self.messages: list[str] = []

    def drain(self) -> list[str]:
        while True:
            try:
                self.messages.append(self.sock.recv(4096).decode())
            except BlockingIOError:
                return self.messages


def service_config(tmp_path: Path, state: Path) -> Path:
    path = tmp_path / "bogiemon.toml"
    path.write_text(short_windows_config(clear_after_windows=2, state_dir=state))
    return path


def test_the_service_on_a_disk_that_fills_logs_crit_tells_systemd_and_loses_nothing_once_freed(disk: Disk, tmp_path: Path) -> None:
    log = io.StringIO()
    configure_logging(log)
    notify = NotifySocket(tmp_path / "notify")
    state = disk.root / "state"
    sink = Recorder(after_n=1, action=disk.fill)

    def free_once_systemd_was_told(report: WindowVerdict) -> None:
        # The disk stays full until STATUS said so (the main thread tells it within a tick).
        deadline = time.monotonic() + 20
        while disk.full and crit_lines(log) and time.monotonic() < deadline:
            if any("EVENT STORE FAILING, 1 events held uncommitted" in m for m in notify.drain()):
                disk.free()
            else:
                time.sleep(0.05)

    notifier = Notifier({"NOTIFY_SOCKET": str(notify.path), "WATCHDOG_USEC": "2000000"})
    blocks = as_blocks(signals())
    service = Service(service_config(tmp_path, state), lambda config: FiniteMemorySource(blocks), notifier=notifier, sinks=[sink], observers=[free_once_systemd_was_told])
    assert service.run() == EXIT_OK
    assert [e.kind.value for e in sink.events] == KINDS
    assert stored(state) == sink.events
    crit = crit_lines(log)
    assert len(crit) >= 1 and all("database or disk is full" in line["error"] and line["held_kinds"] == ["CONFIRMED"] for line in crit)
    status = [m for m in notify.drain() if "EVENT STORE FAILING" in m]
    assert status and status[0].startswith("STATUS=EVENT STORE FAILING, 1 events held uncommitted (") and "database or disk is full" in status[0]


def test_the_service_whose_disk_stays_full_exits_3_without_a_traceback_keeping_the_events_before(disk: Disk, tmp_path: Path) -> None:
    log = io.StringIO()
    configure_logging(log)
    state = disk.root / "state"
    sink = Recorder(after_n=1, action=disk.fill)
    blocks = as_blocks(signals())
    service = Service(service_config(tmp_path, state), lambda config: FiniteMemorySource(blocks), sinks=[sink])
    assert service.run() == EXIT_STORE_FAILED  # the final save_state() is refused too: logged, not raised
    last = crit_lines(log)[-1]
    assert last["event"].startswith("stopped after the event store refused commits") and last["lost_kinds"] == ["CONFIRMED", "CLEARED"]
    disk.free()
    assert [e.kind.value for e in sink.events] == ["SUSPECTED"]
    assert stored(state) == sink.events


def test_the_run_command_on_a_full_disk_exits_3_with_crit_lines_and_no_traceback(disk: Disk, tmp_path: Path) -> None:
    accel = signals()
    write_csv_recording(tmp_path / "run.csv", 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    state = disk.root / "state"
    config = service_config(tmp_path, state)
    config.write_text(config.read_text() + f'[source]\nkind = "replay"\npath = "{tmp_path / "run.csv"}"\nrealtime = false\n')
    before = event_of(EventKind.CONFIRMED, 1.6e9, config_hash="old")
    holder = EventStore(state)
    holder.append([before])
    disk.fill()
    proc = subprocess.run([*BOGIEMON, "run", "--config", str(config)], capture_output=True, text=True, timeout=120)
    holder.close()
    assert proc.returncode == EXIT_STORE_FAILED, proc.stderr
    assert "Traceback" not in proc.stderr and proc.stderr == ""
    crit = [json.loads(line[3:]) for line in proc.stdout.splitlines() if line.startswith("<2>")]
    assert crit and crit[-1]["event"].startswith("stopped after the event store refused commits")
    disk.free()
    assert stored(state) == [before]


# Refused at start: read-only state directory, damaged store; `events` reads read-only media.


def test_run_refuses_a_read_only_state_directory_in_one_line_with_a_crit_log(disk: Disk, tmp_path: Path) -> None:
    state = disk.root / "state"
    EventStore(state).close()
    disk.remount("ro")
    proc = subprocess.run([*BOGIEMON, "run", "--config", str(service_config(tmp_path, state))], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith("bogiemon: error: ") and len(proc.stderr.splitlines()) == 1
    assert "is read-only: the daemon must be able to write there" in proc.stderr
    crit = [json.loads(line[3:]) for line in proc.stdout.splitlines() if line.startswith("<2>")]
    assert [line["event"] for line in crit] == ["cannot open the event store, not starting"]


@pytest.mark.parametrize("existing", [False, True], ids=["new-store", "closed-store"])
def test_a_store_that_cannot_open_on_a_full_disk_says_the_disk_is_full(disk: Disk, existing: bool) -> None:
    state = disk.root / "state"
    if existing:
        EventStore(state).close()
    else:
        state.mkdir()
    disk.fill()
    with pytest.raises(StoreError, match=r"cannot open the event store: .+ \(the file system of .+ is full, 0 KiB free: make room there\)"):
        EventStore(state)
    disk.free()
    if not existing:
        assert list(state.iterdir()) == []  # no half-made store, no scratch file
    assert EventStore(state).events() == []  # once there is room, it opens (or is made) as usual


@pytest.mark.parametrize("writer", ["closed", "killed", "killed-no-shm"], ids=["closed-store", "store-with-a-wal", "wal-without-shm"])
def test_events_lists_a_store_on_read_only_media(disk: Disk, writer: str) -> None:
    state = disk.root / "state"
    code = (
        "import os, sys\n"
        "from bogiemon.daemon.store import EventStore\n"
        f"{CHILD_IMPORTS}"
        "s = EventStore(sys.argv[1])\n"
        "for i in range(5):\n"
        f"    s.append([{CHILD_EVENT.format(t='1.7e9 + i')}])\n"
        + ("s.close()\n" if writer == "closed" else "os.kill(os.getpid(), 9)\n")
    )
    subprocess.run([sys.executable, "-c", code, str(state)], check=writer == "closed")
    assert Path(f"{state}/events.sqlite3-wal").exists() is (writer != "closed")
    if writer == "killed-no-shm":  # a copy of the state directory that left the index behind
        Path(f"{state}/events.sqlite3-shm").unlink()
    disk.remount("ro")
    proc = subprocess.run([*BOGIEMON, "events", "--state-dir", str(state), "--json"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert [json.loads(line)["event_id"] for line in proc.stdout.splitlines()] == ["0", "1", "2", "3", "4"]


def test_run_and_replay_and_events_refuse_a_store_with_a_zeroed_page_in_one_line(tmp_path: Path) -> None:
    state = tmp_path / "state"
    store = EventStore(state)
    for i in range(100):
        store.append([event_of(EventKind.NOT_JUDGED, 1.7e9 + i, config_hash="x", text="x" * 300)])
    store.close()
    path = state / "events.sqlite3"
    data = bytearray(path.read_bytes())
    data[2 * 4096 : 3 * 4096] = bytes(4096)
    path.write_bytes(bytes(data))
    accel = signals()
    write_csv_recording(tmp_path / "run.csv", 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    config = service_config(tmp_path, state)
    for command in (["run", "--config", str(config)], ["replay", str(tmp_path / "run.csv"), "--config", str(config), "--state-dir", str(state)], ["events", "--state-dir", str(state)]):
        proc = subprocess.run([*BOGIEMON, *command], capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, (command, proc.stderr)
        assert proc.stderr.startswith(f"bogiemon: error: {path}: the event store is damaged (") and len(proc.stderr.splitlines()) == 1, command
    assert path.read_bytes() == bytes(data)


def test_the_service_unit_lets_journald_read_the_priority_prefix() -> None:
    unit = (Path(__file__).parents[2] / "systemd" / "bogiemon.service").read_text()
    settings = [line.split("=", 1)[0] for line in unit.splitlines() if "=" in line and not line.startswith("#")]
    # journald reads "<2>" as crit only with SyslogLevelPrefix=yes (the default) on the journal.
    assert "SyslogLevelPrefix" not in settings and "StandardOutput" not in settings


def test_a_zero_length_store_stops_run_with_one_line_and_is_left_as_it_is(tmp_path: Path) -> None:
    state = tmp_path / "state"
    state.mkdir()
    (state / "events.sqlite3").write_bytes(b"")
    proc = subprocess.run([*BOGIEMON, "run", "--config", str(service_config(tmp_path, state))], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"bogiemon: error: {state / 'events.sqlite3'}: the event store is an empty file") and len(proc.stderr.splitlines()) == 1
    assert (state / "events.sqlite3").stat().st_size == 0
    with pytest.raises(StoreError, match="empty file"):
        EventStore(state)
