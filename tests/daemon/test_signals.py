"""Signals by the book (daemon/signals.py): a handler sets a flag and writes a byte to a pipe, nothing
else; a flood of 10 000 SIGHUPs at any stage of a real `bogiemon run` (starting, running, stopping)
never hangs it, the watchdog goes on being pinged, and SIGTERM ends it with exit status 0."""

from __future__ import annotations

import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np
import pytest
import structlog

from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.service import Service
from bogiemon.daemon.signals import Requests
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config
from tests.daemon.test_e2e import Daemon
from tests.daemon.test_service import Feed, FeedSource, own_signal_handlers  # noqa: F401 - a fixture

FLOOD = 10_000
WATCHDOG_USEC = 4_000_000  # a ping each second while blocks of a second flow


def handles_sighup(pid: int) -> bool:
    """Whether the process has a handler of its own for SIGHUP (SigCgt of /proc/<pid>/status)."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGHUP - 1) & 1)
    return False


def flood(pid: int, n: int = FLOOD) -> None:
    for _ in range(n):
        os.kill(pid, signal.SIGHUP)


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Ten minutes of a healthy bogie, replayed at real time: a source that keeps the daemon running."""
    path = tmp_path_factory.mktemp("signals") / "healthy.csv"
    accel = bogie_accel(600, seed=3)
    write_csv_recording(path, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    return path


def start(tmp_path: Path, recording: Path) -> Daemon:
    config = short_windows_config(state_dir=tmp_path / "state") + f'[source]\nkind = "replay"\npath = "{recording}"\nrealtime = true\n'
    return Daemon(tmp_path, config, watchdog_usec=WATCHDOG_USEC)


def watchdog_after(daemon: Daemon) -> None:
    """A WATCHDOG=1 sent after everything the daemon sent so far: its main loop goes on."""
    daemon.sock.setblocking(False)
    try:
        while True:
            daemon.sock.recv(4096)
    except BlockingIOError:
        pass
    daemon.sock.settimeout(0.2)
    daemon.messages.clear()
    daemon.wait_for("WATCHDOG=1")


def stop(daemon: Daemon) -> tuple[int, str, str]:
    daemon.proc.send_signal(signal.SIGTERM)
    return daemon.finish()


def test_a_flood_of_sighups_while_it_starts_is_taken_as_reloads(tmp_path: Path, recording: Path) -> None:
    daemon = start(tmp_path, recording)
    while not handles_sighup(daemon.proc.pid):  # from its first line: before the config is read
        assert daemon.proc.poll() is None
    flood(daemon.proc.pid)
    daemon.wait_for("READY=1")
    watchdog_after(daemon)
    status, out, err = stop(daemon)
    assert status == 0, err
    assert '"stopped"' in out and '"reloaded"' in out


def test_a_flood_of_sighups_while_it_runs_neither_hangs_it_nor_stops_the_watchdog(tmp_path: Path, recording: Path) -> None:
    daemon = start(tmp_path, recording)
    daemon.wait_for("READY=1")
    flood(daemon.proc.pid)
    watchdog_after(daemon)
    flood(daemon.proc.pid)
    status, out, err = stop(daemon)
    assert status == 0, err
    reloads = [line for line in out.splitlines() if '"reloaded"' in line]
    assert reloads and all('"unchanged": true' in line for line in reloads)  # coalesced: far fewer than 20 000


def test_a_flood_of_sighups_while_it_stops_is_ignored_and_it_exits_0(tmp_path: Path, recording: Path) -> None:
    # The finding: SIGHUPs arriving while the daemon stopped killed it with signal 1 after `stopped`
    # (Python's exit puts back the default action of every signal with a handler of its own).
    daemon = start(tmp_path, recording)
    daemon.wait_for("READY=1")
    daemon.proc.send_signal(signal.SIGTERM)

    def flood_until_gone() -> None:  # at least FLOOD, and into the interpreter's exit
        sent = 0
        try:
            while sent < FLOOD or daemon.proc.poll() is None:
                flood(daemon.proc.pid, 100)
                sent += 100
        except ProcessLookupError:
            pass

    flooding = threading.Thread(target=flood_until_gone)
    flooding.start()
    status, out, err = daemon.finish()
    flooding.join()
    assert status == 0, err
    assert '"stopped"' in out.splitlines()[-1]


def test_sigterm_while_it_starts_ends_it_with_exit_status_0(tmp_path: Path, recording: Path) -> None:
    daemon = start(tmp_path, recording)
    while not handles_sighup(daemon.proc.pid):
        assert daemon.proc.poll() is None
    daemon.proc.send_signal(signal.SIGTERM)
    status, _, err = daemon.finish()
    assert status == 0, err


# --- in this process: the handler never waits on a lock -------------------------------------------


def lock_calls(handler: object, signum: int) -> list[str]:
    """The lock methods a signal handler calls (a lock's acquire or __enter__, seen by the profiler)."""
    calls: list[str] = []

    def profile(frame: object, event: str, arg: object) -> None:
        owner = getattr(arg, "__self__", None)
        if event == "c_call" and type(owner).__name__ in ("lock", "RLock"):
            calls.append(f"{type(owner).__name__}.{getattr(arg, '__name__', '?')}")

    assert callable(handler)
    sys.setprofile(profile)
    try:
        handler(signum, None)
    finally:
        sys.setprofile(None)
    return calls


@pytest.mark.parametrize("signum", [signal.SIGHUP, signal.SIGTERM, signal.SIGINT], ids=["SIGHUP", "SIGTERM", "SIGINT"])
def test_the_service_s_signal_handlers_take_no_lock(tmp_path: Path, signum: int, own_signal_handlers: None) -> None:  # noqa: F811
    # The finding: the handler called threading.Event.set(), which takes the event's lock; run between
    # two bytecodes of Event.wait() in the main thread while that held the lock, it waited for itself
    # forever (2 of 5 floods of the attack). A handler that takes no lock cannot.
    config = tmp_path / "bogiemon.toml"
    config.write_text(short_windows_config(state_dir=tmp_path / "state"))
    service = Service(config, lambda _c: FeedSource(Feed([], hup_at=-1, config_path=config, new_text="")), sinks=[])
    service.install_signal_handlers()
    assert lock_calls(signal.getsignal(signum), signum) == []


def test_the_handler_only_sets_a_flag_and_writes_a_byte_even_when_it_interrupts_the_wait() -> None:
    requests = Requests()
    try:
        requests._on_signal(signal.SIGHUP, None)  # as if run inside wait(), between two bytecodes
        requests._on_signal(signal.SIGHUP, None)
        requests.wait(10.0)  # returns at once: the pipe holds the wake-ups
        assert requests.take_reload() and not requests.take_reload() and not requests.stop
        requests._on_signal(signal.SIGTERM, None)
        requests.wait(10.0)
        assert requests.stop and requests.signals_received == 3
    finally:
        requests.close()


def test_sighups_sent_from_another_thread_throughout_a_service_run_never_block_its_main_thread(
    tmp_path: Path, own_signal_handlers: None  # noqa: F811 - the fixture imported above
) -> None:
    # The finding: the handler called threading.Event.set(), which takes the event's lock; run
    # between two bytecodes of Event.wait() in the main thread, which held that lock, it waited
    # for itself forever. Here a thread floods this process while the service runs in the main thread.
    config = tmp_path / "bogiemon.toml"
    config.write_text(short_windows_config(state_dir=tmp_path / "state"))
    feed = Feed(as_blocks(bogie_accel(30, seed=1)), hup_at=-1, config_path=config, new_text="")
    service = Service(config, lambda _c: FeedSource(feed), notifier=Notifier({"WATCHDOG_USEC": "200000"}), sinks=[])
    service.install_signal_handlers()
    done = threading.Event()

    def flood_until_done() -> None:
        while not done.is_set():
            flood(os.getpid(), 100)

    flooding = threading.Thread(target=flood_until_done)
    flooding.start()
    try:
        with structlog.testing.capture_logs() as logs:
            assert service.run() == 0  # the feed ends: the service stops by itself
    finally:
        done.set()
        flooding.join()
    assert service.requests.signals_received > 0 and any(e["event"] == "reloaded" for e in logs)
