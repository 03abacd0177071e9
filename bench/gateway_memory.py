"""The peak memory of `bogiemon run` on CAN as a gateway installs it, measured on this host (bench_gateway's part memory).

The host bundle (`make bundle`, build/bundle/) is installed by its install.sh into a temporary
prefix, so the daemon runs with the gateway's packages only (the development venv's extras would
load more: python-can imports asammdf and pandas at its top when the mf4 extra is there). That
install's python runs `bogiemon run` on the shipped unit's Environment= (systemd/bogiemon.service)
with a config for the hub's CAN layout on `socketcan`, whose socket here is a UDP one carrying
the kernel's struct can_frame datagrams with their receive stamps (this kernel has no AF_CAN; the
stand-in is bench_gateway's, a few lines, defined in the daemon's process before it starts). A
sender in a process of its own plays a healthy run's hub frames at 500 Hz. After `seconds` of
them (several windows judged), the daemon's VmHWM is read from /proc and it is stopped with
SIGTERM; it must exit 0 having read every frame sent until then.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# The daemon's process: the SocketCAN kind opens the datagram stand-in, then the command line runs.
DAEMON = r"""
import socket, sys
import can
from can.interfaces import socketcan

SO_TIMESTAMPNS = 35
port = int(sys.argv[2])

class DatagramBus(can.BusABC):
    def __init__(self, channel="", **settings):
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.socket.bind(("127.0.0.1", port))
        self.socket.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
        self.channel = channel
        super().__init__(channel=channel)

    def send(self, msg, timeout=None):
        raise NotImplementedError

    def _recv_internal(self, timeout):
        return None, False

    def shutdown(self):
        self.socket.close()
        super().shutdown()

socketcan.SocketcanBus = DatagramBus
from bogiemon.cli.main import main
import bogiemon
print("bogiemon from", bogiemon.__file__, flush=True)
sys.exit(main(["run", "--config", sys.argv[1]]))
"""


class MemoryBenchError(RuntimeError):
    """The measurement could not be made (bench_gateway reports it as its BenchError)."""


def unit_environment(unit: Path) -> dict[str, str]:
    """The variables of the unit's Environment= lines (systemd's KEY=VALUE words, unquoted)."""
    env: dict[str, str] = {}
    for line in unit.read_text(encoding="utf-8").splitlines():
        if line.startswith("Environment="):
            for word in line.removeprefix("Environment=").split():
                key, _, value = word.partition("=")
                env[key] = value.strip('"')
    return env


def vm_hwm_kib(pid: int) -> int:
    found = re.search(r"^VmHWM:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text(), re.M)
    if found is None:
        raise MemoryBenchError("no VmHWM in /proc/PID/status")
    return int(found.group(1))


def free_udp_port() -> int:
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = int(probe.getsockname()[1])
    probe.close()
    return port


def run_peak_rss_mib(python: Path, frames_npy: Path, sender: str, unit: Path, seconds: float, fs_hz: float, start_up_s: float) -> tuple[float, int]:
    """(VmHWM in MiB, frames read) of `bogiemon run` by python on the hub frames of frames_npy."""
    port = free_udp_port()
    with tempfile.TemporaryDirectory() as tmp:
        config = Path(tmp) / "bogiemon.toml"
        config.write_text(f'[source]\nkind = "can"\ninterface = "socketcan"\nchannel = "can0"\nlayout = "hub"\n[state]\ndirectory = "{tmp}/state"\n')
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "LANG": "C.UTF-8", **unit_environment(unit)}
        log_path = Path(tmp) / "daemon.log"
        with log_path.open("w") as log:
            # In the temporary folder: `python -c` puts its working directory first on sys.path, and
            # from the checkout that would import the checkout's bogiemon instead of the bundle's.
            daemon = subprocess.Popen([str(python), "-c", DAEMON, str(config), str(port)], stdout=log, stderr=subprocess.STDOUT, env=env, cwd=tmp)
            player = None
            try:
                time.sleep(start_up_s)
                player = subprocess.Popen([sys.executable, "-c", sender, str(frames_npy), str(port), str(fs_hz)])
                time.sleep(seconds)
                if daemon.poll() is not None:
                    raise MemoryBenchError(f"bogiemon run exited {daemon.returncode} early: {log_path.read_text()[-2000:]}")
                hwm_kib = vm_hwm_kib(daemon.pid)
            finally:
                if player is not None:
                    player.kill()
                    player.wait()
                daemon.send_signal(signal.SIGTERM)
                status = daemon.wait(timeout=120)
        lines = log_path.read_text().splitlines()
    # JSON lines behind a syslog priority, <6>{...} (daemon/logs.py)
    stopped = [json.loads(line[line.index("{"):]) for line in lines if '"event": "stopped"' in line]
    origin = next((line.removeprefix("bogiemon from ") for line in lines if line.startswith("bogiemon from ")), "")
    if not origin.startswith(str(python.parents[1])):
        raise MemoryBenchError(f"bogiemon run imported bogiemon from {origin or 'nowhere said'}, not from the install at {python.parents[1]}")
    if status != 0 or not stopped:
        raise MemoryBenchError(f"bogiemon run exited {status}: {' | '.join(lines[-5:])}")
    frames = int(stopped[-1]["source"]["frames"])
    if frames < 0.9 * seconds * fs_hz:
        raise MemoryBenchError(f"bogiemon run read {frames} frames in {seconds:g} s at {fs_hz:g} Hz: the sender did not reach it")
    return hwm_kib / 1024, frames
