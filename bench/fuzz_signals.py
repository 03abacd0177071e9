"""Fuzz target of signals: a real `bogiemon run` process (a healthy bogie replayed at real time, a
notify socket with a watchdog) sent seeded random floods of SIGHUP, up to 10 000, at a random stage:
while it starts (from the moment its handlers are in place), while it runs, or while it stops
(after SIGTERM or SIGINT, the flood going on into the interpreter's exit), some with more stop
signals among them.

Wrong results: an exit status other than 0 (signal 1: a SIGHUP's default action); no READY=1, or
no WATCHDOG=1 after a flood while it runs (a main thread that hangs); no exit after the stop
signal; a traceback or an "ignored" signal on stderr; no `stopped` line last in its log. "No" is
judged as tests/waiting.py waits: while the process still uses the CPU it is getting there (a busy
machine slows it), so only a process whose CPU time stands still has failed.
"""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

import fuzz_core
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import FS_HZ, bogie_accel, short_windows_config
from tests.waiting import Progress

BOGIEMON = [sys.executable, "-m", "bogiemon.cli.main"]
WATCHDOG_USEC = 4_000_000  # a ping every second while blocks of a second flow
STAGES = ("start", "run", "stop")


def generate(rng: random.Random) -> fuzz_core.Input:
    return {
        "stage": rng.choice(STAGES),
        "hups": rng.choice((1, 3, 30, 300, 3000, 10_000)),
        "spread_s": rng.choice((0.0, 0.0, 0.2, 1.0)),  # 0: as fast as they go, else over this long
        "stop_signal": rng.choice(("SIGTERM", "SIGTERM", "SIGINT")),
        "more_stops": rng.choice((0, 0, 1, 5)),  # more stop signals among the SIGHUPs
    }


def _recording(ctx: fuzz_core.Context) -> Path:
    """Ten minutes of a healthy bogie, written once per worker: the daemon runs on it at real time."""
    if "recording" not in ctx.cache:
        path = ctx.root / "healthy.csv"
        accel = bogie_accel(600, seed=3)
        write_csv_recording(path, 1.7e9 + np.arange(accel.shape[0]) / FS_HZ, accel)
        ctx.cache["recording"] = path
    recording = ctx.cache["recording"]
    assert isinstance(recording, Path)
    return recording


def handles_sighup(pid: int) -> bool:
    """Whether the process has a handler of its own for SIGHUP (SigCgt of /proc/<pid>/status)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return False
    for line in text.splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) >> (signal.SIGHUP - 1) & 1)
    return False


class Daemon:
    """The process, its notify socket and what it sent there."""

    def __init__(self, folder: Path, config: str) -> None:
        config_path = folder / "bogiemon.toml"
        config_path.write_text(config)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind(str(folder / "notify.sock"))
        env = {**os.environ, "NOTIFY_SOCKET": str(folder / "notify.sock"), "WATCHDOG_USEC": str(WATCHDOG_USEC)}
        self.proc = subprocess.Popen([*BOGIEMON, "run", "--config", str(config_path)], stdout=subprocess.PIPE,
                                     stderr=subprocess.PIPE, text=True, env=env)  # fmt: skip
        self.out: list[str] = []
        self.err: list[str] = []
        self._readers = [threading.Thread(target=self._read, args=(stream, lines), daemon=True)
                         for stream, lines in ((self.proc.stdout, self.out), (self.proc.stderr, self.err))]  # fmt: skip
        for reader in self._readers:
            reader.start()

    @staticmethod
    def _read(stream: Any, lines: list[str]) -> None:
        for line in stream:
            lines.append(line)

    def drain(self) -> None:
        """Forget what it sent so far."""
        self.sock.setblocking(False)
        try:
            while True:
                self.sock.recv(4096)
        except BlockingIOError:
            pass

    def wait_for(self, prefix: str) -> bool:
        self.sock.settimeout(0.2)
        progress = Progress(self.proc.pid)
        while progress.working():
            try:
                if self.sock.recv(4096).decode().startswith(prefix):
                    return True
            except TimeoutError:
                pass
        return False

    def send(self, signum: int, n: int, spread_s: float = 0.0, until_gone: bool = False) -> None:
        pause_s = spread_s / n if spread_s > 0 else 0.0
        sent = 0
        try:
            while sent < n or (until_gone and self.proc.poll() is None):
                os.kill(self.proc.pid, signum)
                sent += 1
                if pause_s:
                    time.sleep(pause_s)
        except ProcessLookupError:
            pass  # gone (until_gone: the exit came)

    def close(self) -> int | None:
        """Its exit status, once it has ended; None if it stopped working towards its end (then killed)."""
        progress = Progress(self.proc.pid)
        while self.proc.poll() is None and progress.working():
            time.sleep(0.05)
        status = self.proc.poll()
        if status is None:
            self.proc.kill()
            self.proc.wait()
        for reader in self._readers:
            reader.join(10)
        self.sock.close()
        return status


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    recording = _recording(ctx)
    folder = ctx.fresh_dir()
    config = short_windows_config(state_dir=folder / "state") + f'[source]\nkind = "replay"\npath = "{recording}"\nrealtime = true\n'
    daemon = Daemon(folder, config)
    stop_signal = signal.Signals[data["stop_signal"]]
    stops = threading.Thread(target=daemon.send, args=(stop_signal, data["more_stops"], data["spread_s"]))
    verdict: str | None = None
    try:
        if data["stage"] == "start":
            while not handles_sighup(daemon.proc.pid):
                if daemon.proc.poll() is not None:
                    break
            daemon.send(signal.SIGHUP, data["hups"], data["spread_s"])
            if not daemon.wait_for("READY=1"):
                verdict = f"no READY=1 after {data['hups']} SIGHUPs while it started"
        elif not daemon.wait_for("READY=1"):
            verdict = "no READY=1"
        elif data["stage"] == "run":
            daemon.send(signal.SIGHUP, data["hups"], data["spread_s"])
            daemon.drain()
            if not daemon.wait_for("WATCHDOG=1"):
                verdict = f"no WATCHDOG=1 after {data['hups']} SIGHUPs while it ran"
        else:
            daemon.proc.send_signal(stop_signal)
            stops.start()
            daemon.send(signal.SIGHUP, data["hups"], data["spread_s"], until_gone=True)
    finally:
        if daemon.proc.poll() is None:
            daemon.proc.send_signal(stop_signal)
        status = daemon.close()
        if stops.is_alive() or stops.ident is not None:
            stops.join()
    if verdict is not None:
        return verdict
    if status is None:
        return f"no exit after {data['stop_signal']}: its CPU time stood still (last log line: {daemon.out[-1:]})"
    if status != 0:
        return f"exit status {status} ({'killed by ' + signal.Signals(-status).name if status < 0 else 'an error'})"
    err = "".join(daemon.err)
    if "Traceback" in err or "ignored" in err:
        return f"stderr: {' '.join(err.split())[:300]}"
    if not daemon.out or '"stopped"' not in daemon.out[-1]:
        return f"its log does not end with 'stopped': {daemon.out[-1:] if daemon.out else 'nothing'}"
    return None


TARGETS = [fuzz_core.Target("signals", generate, run)]
