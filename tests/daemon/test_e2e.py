"""`bogiemon run` as a process: the simulator's sensor hub on a virtual CAN bus inside it, a
notify socket of ours, real signals, the real SQLite event store."""

from __future__ import annotations

import json
import os
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from typing import Any
from importlib import resources
from pathlib import Path

import pytest

from tests.waiting import Progress

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]


# The simulated wagon's commissioning, as the demo ships it (`make demo-calibration`).
CALIBRATION = Path(str(resources.files("bogiemon.config").joinpath("demo_calibration.toml")))


def config_text(state_dir: Path, faults: list[str], duration_s: float, rate: float, extra: str = "") -> str:
    return f"""allow_absolute_includes = true
include = ["{CALIBRATION}"]

[source]
kind = "simulated"
load = "full"
speed_kmh = 80.0
track = "erri-low"
duration_s = {duration_s}
seed = 2
faults = {json.dumps(faults)}
rate = {rate}
channel = "e2e-{os.getpid()}-{len(faults)}"

[decision]
load = "full"

[state]
directory = "{state_dir}"
{extra}
"""


class Daemon:
    """A `bogiemon run` process with a notify socket, its stdout (JSON log lines) collected."""

    def __init__(self, tmp_path: Path, config: str, watchdog_usec: int | None = None) -> None:
        self.config_path = tmp_path / "bogiemon.toml"
        self.config_path.write_text(config)
        self.notify_path = tmp_path / "notify.sock"
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(self.notify_path))
        self.sock.settimeout(0.2)
        env = {**os.environ, "NOTIFY_SOCKET": str(self.notify_path)}
        if watchdog_usec:
            env["WATCHDOG_USEC"] = str(watchdog_usec)
        self.proc = subprocess.Popen(
            [*BOGIEMON, "run", "--config", str(self.config_path)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        self.messages: list[str] = []

    def wait_for(self, prefix: str) -> str:
        """The next message that starts with prefix; waits while the process works towards it (tests/waiting.py)."""
        progress = Progress(self.proc.pid)
        while progress.working():
            try:
                message = self.sock.recv(4096).decode()
            except TimeoutError:
                continue
            self.messages.append(message)
            if message.startswith(prefix):
                return message
        stderr = self.proc.stderr.read() if self.proc.poll() is not None else progress.why_not()
        raise AssertionError(f"no '{prefix}' from the daemon; got {self.messages}; {stderr}")

    def finish(self) -> tuple[int, str, str]:
        """Its exit status, stdout and stderr once it ends; waits while it works towards its end."""
        progress = Progress(self.proc.pid)
        while True:
            try:
                out, err = self.proc.communicate(timeout=1.0)  # reads its pipes meanwhile, keeps what it read
                break
            except subprocess.TimeoutExpired:
                if not progress.working():
                    self.proc.kill()
                    self.proc.communicate()
                    raise AssertionError(f"the daemon did not end: {progress.why_not()}") from None
        if self.sock.fileno() != -1:  # a caller that did not listen closed it
            self.sock.setblocking(False)
            while True:  # what the daemon sent after the last wait_for
                try:
                    self.messages.append(self.sock.recv(4096).decode())
                except BlockingIOError:
                    break
            self.sock.close()
        return self.proc.returncode, out, err


def stored_events(state_dir: Path) -> list[tuple[str, str]]:
    with sqlite3.connect(state_dir / "events.sqlite3") as db:
        return db.execute("SELECT event_id, kind FROM events ORDER BY seq").fetchall()


def logged_events(stdout: str) -> list[dict]:
    records = [json.loads(line[3:]) for line in stdout.splitlines() if line.startswith("<") and '"event_id"' in line]
    return records


# 180 s of bogie at ten times real time, through a ring that holds all of it: a process starved of
# CPU on a busy machine (the tests run side by side) lags and catches up instead of dropping
# samples; at 60 times real time with the default 60 s ring (1 s of wall time) it dropped, and the
# 120 s windows were never filled.
LIVE_RUN: dict[str, Any] = {"duration_s": 180.0, "rate": 10.0, "extra": "[pipeline]\nring_capacity_s = 600.0\n"}


def stopped_counters(stdout: str) -> dict:
    """The daemon's last log line: its monitor's and its ring's counters."""
    (stopped,) = [json.loads(line[3:]) for line in stdout.splitlines() if line.startswith("<") and '"event": "stopped"' in line]
    return {"monitor": stopped["counters"], "ring": stopped["ring"]}


@pytest.mark.parametrize(("faults", "expect_alarm"), [(["type_a:rear_outer:0.0@leading-left"], True), ([], False)], ids=["broken-spring", "healthy"])
def test_run_confirms_a_broken_spring_and_stays_quiet_on_a_healthy_wagon(tmp_path: Path, faults, expect_alarm) -> None:
    state = tmp_path / "state"
    daemon = Daemon(tmp_path, config_text(state, faults, **LIVE_RUN))
    daemon.wait_for("READY=1")
    status, out, err = daemon.finish()
    assert status == 0, err
    counters = stopped_counters(out)
    # Quiet or alarmed on windows it judged, every sample of the run in one stretch.
    assert counters["monitor"]["judged"] == counters["monitor"]["windows"] > 0 and counters["ring"]["samples_dropped"] == 0, counters
    kinds = [kind for _, kind in stored_events(state)]
    assert ("CONFIRMED" in kinds) is expect_alarm, counters
    assert [e["event_id"] for e in logged_events(out)] == [event_id for event_id, _ in stored_events(state)]
    assert daemon.messages[-1] == "STOPPING=1"


def test_sighup_with_a_bad_config_keeps_it_running_and_sigterm_ends_it_cleanly(tmp_path: Path) -> None:
    state = tmp_path / "state"
    good = config_text(state, [], duration_s=600.0, rate=5.0)
    daemon = Daemon(tmp_path, good)
    daemon.wait_for("READY=1")
    daemon.config_path.write_text(good.replace('load = "full"\n\n[state]', 'load = "empty"\n\n[state]'))
    daemon.proc.send_signal(signal.SIGHUP)
    daemon.wait_for("RELOADING=1")
    rejected = daemon.wait_for("READY=1")
    assert "reload rejected" in rejected and "decision.load" in rejected
    time.sleep(1.0)
    assert daemon.proc.poll() is None  # still running on the old config
    daemon.config_path.write_text(good.replace("confirm_k", "confirm_k") + "\n[health]\nnoise_ratio = 5.0\n")
    daemon.proc.send_signal(signal.SIGHUP)
    daemon.wait_for("RELOADING=1")
    assert "reloaded" in daemon.wait_for("READY=1")
    daemon.proc.send_signal(signal.SIGTERM)
    status, out, err = daemon.finish()
    assert status == 0, err
    # Stopped by SIGTERM, not by the end of the run: far fewer samples than its 600 s at 500 Hz.
    assert stopped_counters(out)["monitor"]["samples"] < 600 * 500 // 2
    assert "STOPPING=1" in daemon.messages
    assert any('"reload rejected' in line for line in out.splitlines())


def test_kill_9_in_a_burst_of_events_loses_no_event_reported_committed(tmp_path: Path) -> None:
    state = tmp_path / "state"
    # A hair trigger: every window is judged against a threshold inside the healthy spread, and
    # one window confirms or clears, so events come in a burst, several per second.
    burst = """
[processing]
window_s = 10.0
hop_s = 1.0
max_lag_s = 2.0
[decision]
load = "full"
method = "thresholds"
confirm_k = 1
confirm_n = 1
clear_after_windows = 1
[decision.thresholds.full.i4_norm]
center = 0.0
warning = 0.02
alarm = 0.02
"""
    text = config_text(state, [], duration_s=600.0, rate=20.0).replace('[decision]\nload = "full"\n', "") + burst
    daemon = Daemon(tmp_path, text)
    daemon.wait_for("READY=1")
    reported: list[str] = []
    progress = Progress(daemon.proc.pid)
    while len(reported) < 20 and progress.working():
        line = daemon.proc.stdout.readline()
        if '"event_id"' in line:
            reported.append(json.loads(line[3:])["event_id"])
    daemon.proc.send_signal(signal.SIGKILL)
    daemon.proc.wait(timeout=10)
    assert daemon.proc.returncode == -signal.SIGKILL
    assert len(reported) >= 20, "the burst never came"
    stored = {event_id for event_id, _ in stored_events(state)}
    assert set(reported) <= stored
