"""The service in-process over a finite source: READY after data, STATUS, events, clean exit."""

import json
import os
import signal
import socket
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import structlog

from bogiemon.daemon.config import BogiemonConfig, load_config, parse_config
from bogiemon.daemon.notify import Notifier
from bogiemon.daemon.service import Service
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, MemorySource, Source
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel
from tests.daemon.test_e2e import Daemon


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


# --- reload (issue 17): any failure rejects it, and the running config stays ---------------------


@pytest.fixture
def own_signal_handlers() -> Iterator[None]:
    """The service installs its SIGTERM, SIGINT and SIGHUP handlers in this process: put pytest's back."""
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGTERM, signal.SIGINT, signal.SIGHUP)}
    yield
    for signum, handler in saved.items():
        signal.signal(signum, handler)


class Feed:
    """One stream of blocks for every source the factory opens, so that a source opened again goes
    on where the last one stopped. At block hup_at it writes the config file anew and sends this
    process a real SIGHUP, then holds until released."""

    def __init__(self, blocks: list[Block], hup_at: int, config_path: Path, new_text: str) -> None:
        self.blocks, self.hup_at, self.config_path, self.new_text = blocks, hup_at, config_path, new_text
        self.next = 0
        self.released = threading.Event()

    def read(self, timeout_s: float) -> Block | None:
        if self.next == self.hup_at and not self.released.is_set():
            if self.config_path.read_text() != self.new_text:
                self.config_path.write_text(self.new_text)
                os.kill(os.getpid(), signal.SIGHUP)
            self.released.wait(timeout_s)
            return None
        if self.next >= len(self.blocks):
            raise EndOfStream
        self.next += 1
        return self.blocks[self.next - 1]


class FeedSource(Source):
    finite = True

    def __init__(self, feed: "Feed | ReloadingFeed") -> None:
        self.fs_hz = FS_HZ
        self.counters = HealthCounters()
        self.feed = feed

    def read(self, timeout_s: float) -> Block | None:
        return self.feed.read(timeout_s)


def notify_messages(sock: socket.socket) -> list[str]:
    messages = []
    while True:
        try:
            messages.append(sock.recv(4096).decode())
        except BlockingIOError:
            return messages


def test_a_reload_whose_new_source_raises_is_rejected_and_the_old_source_and_config_go_on(
    tmp_path: Path, short_config: Path, own_signal_handlers: None
) -> None:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(0)
    old_text = short_config.read_text()
    old_digest = load_config(short_config).digest()
    # A valid config whose [source] changed: the service stops the source and opens the new one, which fails.
    feed = Feed(as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0)), 10, short_config, old_text + "[source]\nmax_block_s = 0.5\n")
    opened: list[float] = []

    def open_source(config: BogiemonConfig) -> Source:
        opened.append(config.source.max_block_s)
        if config.source.max_block_s == 0.5:
            raise RuntimeError("the new bus exploded")
        if len(opened) > 1:
            feed.released.set()  # the old source, opened again: the stream goes on
        return FeedSource(feed)

    sink = MemorySink()
    service = Service(short_config, open_source, notifier=Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify")}), sinks=[sink])
    service.install_signal_handlers()
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    assert opened == [1.0, 0.5, 1.0]
    assert "READY=1\nSTATUS=reload rejected: RuntimeError: the new bus exploded" in notify_messages(listener)
    rejected = [entry for entry in logs if entry["event"] == "reload rejected, keeping the running config"]
    assert [(r["log_level"], r["stage"], r["reason"]) for r in rejected] == [("error", "apply", "RuntimeError: the new bus exploded")]
    assert service.config.digest() == old_digest
    assert [(e.kind.value, e.config_hash) for e in sink.events] == [("SUSPECTED", old_digest), ("CONFIRMED", old_digest)]
    assert feed.next == len(feed.blocks)  # every block went through, none twice


@pytest.mark.slow  # a recording replayed at real time: about 20 s
def test_sighup_after_include_5_and_after_window_s_inf_keeps_the_daemon_on_its_old_config(tmp_path: Path, short_config: Path) -> None:
    # 6 s of a healthy bogie, then 14 s with pitch coupled to roll: replayed at real time, the
    # alarm comes well after both reloads, from whatever config is running then.
    accel = np.vstack([bogie_accel(6, seed=1), bogie_accel(14, seed=2, pitch_roll_coupling=1.0)])
    recording = tmp_path / "run.csv"
    write_csv_recording(recording, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    good = short_config.read_text() + f'[source]\nkind = "replay"\npath = "{recording}"\nrealtime = true\n'
    short_config.write_text(good)
    old_digest = load_config(short_config).digest()
    daemon = Daemon(tmp_path, good)
    assert daemon.config_path == short_config
    daemon.wait_for("READY=1")
    bad_configs = [("include = 5\n" + good, "include: expected a list of file names"),
                   (good.replace("window_s = 6.0", "window_s = inf"), "processing.window_s: Input should be a finite number")]  # fmt: skip
    for text, named in bad_configs:
        daemon.config_path.write_text(text)
        daemon.proc.send_signal(signal.SIGHUP)
        daemon.wait_for("RELOADING=1")
        rejected = daemon.wait_for("READY=1")
        assert rejected.startswith("READY=1\nSTATUS=reload rejected: ") and named in rejected
        assert daemon.proc.poll() is None
    status, out, err = daemon.finish()  # the recording ends: the service stops by itself
    assert status == 0, err
    assert "Traceback" not in err
    logged = [json.loads(line[3:]) for line in out.splitlines() if line.startswith("<")]
    rejections = [r for r in logged if r["event"] == "reload rejected, keeping the running config"]
    assert [(r["stage"], named in r["reason"]) for r, (_, named) in zip(rejections, bad_configs, strict=True)] == [("load", True), ("load", True)]
    assert not any(r["event"] == "reloaded" for r in logged)
    stored = EventStore(tmp_path / "state", readonly=True).events()
    assert [(e.kind.value, e.config_hash) for e in stored] == [("SUSPECTED", old_digest), ("CONFIRMED", old_digest)]


# --- reloads never blind the monitor (issue 27) ----------------------------------------------------


class ReloadingFeed:
    """Blocks for the service, and a real SIGHUP every `every` blocks: the config file written
    anew (the same text, or `changed` with another decision setting, in turn), then held until the
    service told systemd the reload is done, so that reloads keep pace with the data. With
    `may_reload` (the monitor has taken every block before this one), the SIGHUP waits for it: the
    source thread reads ahead into the ring, and a reload lands where the monitor is, not where the
    source is."""

    def __init__(self, blocks: list[Block], every: int, config_path: Path, changed: str, notify: socket.socket) -> None:
        self.blocks, self.every, self.config_path, self.notify = blocks, every, config_path, notify
        self.texts = [config_path.read_text(), changed]
        self.next = self.reloads = 0
        self.statuses: list[str] = []
        self.may_reload: Callable[[], bool] = lambda: True

    def read(self, timeout_s: float) -> Block | None:
        if self.next >= len(self.blocks):
            raise EndOfStream
        if self.next and self.next % self.every == 0 and self.reloads < self.next // self.every:
            if not self.may_reload():
                return None
            self.reloads += 1
            self.config_path.write_text(self.texts[(self.reloads // 2) % 2])  # same, same, changed, changed, ...
            os.kill(os.getpid(), signal.SIGHUP)
            while True:  # the service's answer to systemd ends the reload
                message = self.notify.recv(4096).decode()
                if message.startswith("READY=1\nSTATUS=reload"):  # not the first READY's "receiving data"
                    self.statuses.append(message.removeprefix("READY=1\nSTATUS="))
                    break
        self.next += 1
        return self.blocks[self.next - 1]


def test_a_reload_every_four_seconds_of_data_loses_no_window_and_the_fault_is_found(
    tmp_path: Path, short_config: Path, own_signal_handlers: None
) -> None:
    # Two minutes of a healthy bogie, then two with pitch coupled to roll; 6 s windows every 2 s. A
    # reload every 4 s of data used to restart the windows each time: none was ever judged.
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(30.0)
    accel = np.vstack([bogie_accel(120, seed=1), bogie_accel(120, seed=2, pitch_roll_coupling=1.0)])
    blocks = as_blocks(accel)  # 0.5 s each
    changed = short_config.read_text().replace("[decision]\n", "[decision]\nclear_after_windows = 9\n")
    feed = ReloadingFeed(blocks, 8, short_config, changed, listener)
    sink = MemorySink()
    windows: list[object] = []
    service = Service(short_config, lambda config: FeedSource(feed), notifier=Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify")}),
                      sinks=[sink], observers=[windows.append])  # fmt: skip
    service.install_signal_handlers()
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    reloads = [entry for entry in logs if entry["event"] == "reloaded"]
    assert feed.reloads == len(reloads) == len(blocks) // 8 - 1 == 59
    assert sum(1 for r in reloads if r.get("unchanged")) == 30 and not any(r["windows_restart"] for r in reloads)
    assert set(feed.statuses) == {"reloaded", "reloaded: the config is unchanged"}
    assert len(windows) == (240 - 6) // 2 + 1  # every window of the four minutes, none lost to a reload
    kinds = [e.kind.value for e in sink.events]
    assert kinds[:2] == ["SUSPECTED", "CONFIRMED"] and 120 < sink.events[1].time_s - 1.7e9 < 140


def test_a_reload_that_changes_the_processing_restarts_the_windows_and_says_so(
    tmp_path: Path, short_config: Path, own_signal_handlers: None
) -> None:
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(30.0)
    blocks = as_blocks(bogie_accel(60, seed=1))
    changed = short_config.read_text().replace("hop_s = 2.0", "hop_s = 3.0")
    feed = ReloadingFeed(blocks, 60, short_config, changed, listener)
    feed.texts = [changed, changed]  # the first reload changes the hop
    windows: list[object] = []
    # The reload lands before block 60, once the monitor has judged the first 30 s (the last of those
    # windows ends with block 59). Sent as soon as the source thread came to block 60, it landed
    # wherever the monitor was: the service's one-second tick used to give it time to get there.
    feed.may_reload = lambda: len(windows) >= (30 - 6) // 2 + 1
    service = Service(short_config, lambda config: FeedSource(feed), notifier=Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify")}),
                      observers=[windows.append])  # fmt: skip
    service.install_signal_handlers()
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    reloads = [entry for entry in logs if entry["event"] == "reloaded"]
    assert [r["windows_restart"] for r in reloads] == [True]
    assert feed.statuses == ["reloaded: the windows restart, the next is judged 6 s of data from now"]
    # 30 s at a 2 s hop, then the windows restart: 30 s at a 3 s hop.
    assert len(windows) == ((30 - 6) // 2 + 1) + ((30 - 6) // 3 + 1)


def test_service_keeps_blas_to_one_thread_while_it_runs_and_restores_it_after(short_config: Path) -> None:
    from bogiemon.daemon.blas import blas_thread_counts

    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=2, user_api="blas"):  # the tests' workers may run with one thread
        before = blas_thread_counts()
        assert before and all(n == 2 for n in before.values())
        seen: list[dict[str, int]] = []
        blocks = as_blocks(bogie_accel(30, seed=2))
        service = Service(short_config, lambda config: FiniteMemorySource(blocks), sinks=[],
                          observers=[lambda report: seen.append(blas_thread_counts())])  # fmt: skip
        assert service.run() == 0
        assert seen and all(counts == dict.fromkeys(before, 1) for counts in seen)
        assert blas_thread_counts() == before


def test_a_state_dir_given_to_the_service_holds_its_events_and_a_reload_keeps_it(
    tmp_path: Path, short_config: Path, own_signal_handlers: None
) -> None:
    # `bogiemon run --state-dir D`: the events go to D, not to the config's [state] directory, and
    # a reload of the file (which names its own directory) neither moves nor questions it.
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(str(tmp_path / "notify"))
    listener.settimeout(30.0)
    accel = np.vstack([bogie_accel(20, seed=1), bogie_accel(20, seed=2, pitch_roll_coupling=1.0)])
    blocks = as_blocks(accel)
    changed = short_config.read_text().replace("[decision]\n", "[decision]\nclear_after_windows = 9\n")
    feed = ReloadingFeed(blocks, 20, short_config, changed, listener)
    elsewhere = tmp_path / "elsewhere"
    sink = MemorySink()
    service = Service(short_config, lambda config: FeedSource(feed), notifier=Notifier({"NOTIFY_SOCKET": str(tmp_path / "notify")}),
                      sinks=[sink], state_dir=elsewhere)  # fmt: skip
    service.install_signal_handlers()
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    assert feed.reloads == 3 and sum(1 for entry in logs if entry["event"] == "reloaded") == 3
    assert not any("state.directory" in entry["event"] for entry in logs)
    assert service.config.state.directory == elsewhere
    assert [e.kind.value for e in sink.events][:2] == ["SUSPECTED", "CONFIRMED"]
    assert EventStore(elsewhere, readonly=True).events() == sink.events
    assert not (tmp_path / "state").exists()


def test_bogiemon_run_state_dir_puts_the_event_store_there(tmp_path: Path, short_config: Path) -> None:
    import subprocess
    import sys

    accel = np.vstack([bogie_accel(6, seed=1), bogie_accel(14, seed=2, pitch_roll_coupling=1.0)])
    recording = tmp_path / "run.csv"
    write_csv_recording(recording, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
    short_config.write_text(short_config.read_text() + f'[source]\nkind = "replay"\npath = "{recording}"\nrealtime = false\n')
    elsewhere = tmp_path / "elsewhere"
    proc = subprocess.run([sys.executable, "-m", "bogiemon", "run", "--config", str(short_config), "--state-dir", str(elsewhere)],
                          capture_output=True, text=True, timeout=120)  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert [e.kind.value for e in EventStore(elsewhere, readonly=True).events()][:2] == ["SUSPECTED", "CONFIRMED"]
    assert not (tmp_path / "state").exists()
