"""bogiemon.service under a real systemd: PID 1 of a systemd-nspawn container booted from this host.

The container (`systemd-nspawn -D / --volatile=yes --private-network --register=no --keep-unit
-b`, in a pty from `script`) runs the shipped unit with its hardening, fed by a serial ADC
simulated on a pseudo-terminal by a second unit. A oneshot unit inside drives the checks and
writes what it saw to a shared folder, then powers the container off: READY with the first
data, the hardening in force on the live process, a reload and a rejected reload, and a watchdog
restart when the data stop. About 30 s.

Test-only differences from an install, in a drop-in beside the unit: the interpreter is the
host's /usr/bin/python3 with this checkout on PYTHONPATH (bind-mounted read-only outside /root
and /tmp, which ProtectHome and PrivateTmp hide from the service), DeviceAllow for the pty
(char-pts instead of a USB serial adapter), and a 4 s watchdog and 1 s restart delay for speed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
IN_CONTAINER_SITE = "/opt/bogiemon-test/site"  # the package folder bogiemon/, bind-mounted
IN_CONTAINER_DEPS = "/opt/bogiemon-test/deps"  # this venv's site-packages, bind-mounted
FEED_TTY = "/run/bogiemon-feed/tty"

FEEDER = f"""
import os, sys, time
import numpy as np
from bogiemon.detection import BogieGeometry, from_modal
from bogiemon.drivers.serial_protocol import encode_packets

# A running bogie: independent bounce, pitch and roll noise, with gravity, at 500 Hz.
rng = np.random.default_rng(1)
master, slave = os.openpty()
os.chmod(os.ttyname(slave), 0o666)
os.makedirs(os.path.dirname("{FEED_TTY}"), exist_ok=True)
os.symlink(os.ttyname(slave), "{FEED_TTY}")
seq, t0, sent = 0, time.monotonic(), 0
while True:
    due = int((time.monotonic() - t0) * 500.0)
    if due > sent:
        modal = rng.standard_normal((due - sent, 3)) * [1.0, 0.7, 0.7]
        os.write(master, encode_packets(from_modal(modal, BogieGeometry()) + 9.81, first_sequence=seq % 65536))
        seq += due - sent
        sent = due
    time.sleep(0.02)
"""

CONFIG = f"""
[source]
kind = "serial"
port = "{FEED_TTY}"
baudrate = 115200
reconnect_backoff_min_s = 0.2
reconnect_backoff_max_s = 1.0

[processing]
window_s = 10.0
hop_s = 2.0
max_lag_s = 2.0

[decision]
# Short windows for a quick test: the per-indicator method (the fused model needs 120 s windows).
method = "thresholds"
load = "full"

[health]
noise_ratio = 4.0
"""

RUNNER = r"""#!/bin/bash
# Runs inside the container as a oneshot unit; every observation goes to /T/results.
set -u
R=/T/results
mkdir -p $R
show() { systemctl show bogiemon.service -p "$1" --value; }
mkdir -p /etc/bogiemon && cp /T/bogiemon.toml /etc/bogiemon/bogiemon.toml

systemctl start bogiemon-feeder.service
for i in $(seq 100); do [ -e /run/bogiemon-feed/tty ] && break; sleep 0.1; done

systemctl start bogiemon.service; echo $? > $R/start_rc     # returns once READY=1 arrived
show ActiveState > $R/active_after_start
show StatusText > $R/status_after_start
pid=$(show MainPID)
grep -E '^(Uid|CapEff|NoNewPrivs|Seccomp):' /proc/$pid/status > $R/proc_status
( nsenter -t $pid -m touch /usr/bogiemon-probe && echo writable || echo read-only ) > $R/usr_write 2>/dev/null
( nsenter -t $pid -m ls -A /root | wc -l ) > $R/root_entries 2>/dev/null
systemd-analyze security bogiemon.service --no-pager > $R/security.txt 2>&1
sleep 12                                                  # a few windows
show StatusText > $R/status_running

sed -i 's/noise_ratio = 4.0/noise_ratio = 4.5/' /etc/bogiemon/bogiemon.toml
systemctl reload bogiemon.service; echo $? > $R/reload_rc
sleep 2
show StatusText > $R/status_after_reload
show ActiveState > $R/active_after_reload

echo 'this is [not toml' >> /etc/bogiemon/bogiemon.toml
systemctl reload bogiemon.service; echo $? > $R/bad_reload_rc
sleep 2
show StatusText > $R/status_after_bad_reload
show ActiveState > $R/active_after_bad_reload
show MainPID > $R/pid_after_bad_reload
echo $pid > $R/pid_at_start
cp /T/bogiemon.toml /etc/bogiemon/bogiemon.toml

show NRestarts > $R/restarts_before_stall
systemctl kill -s SIGSTOP bogiemon-feeder.service          # the data stop: the pipeline stalls
for i in $(seq 300); do [ "$(show NRestarts)" != "$(cat $R/restarts_before_stall)" ] && break; sleep 0.1; done
show NRestarts > $R/restarts_after_stall
systemctl kill -s SIGCONT bogiemon-feeder.service
for i in $(seq 150); do [ "$(show ActiveState)/$(show SubState)" = active/running ] && break; sleep 0.2; done
show ActiveState > $R/active_after_restart

systemctl stop bogiemon.service; echo $? > $R/stop_rc
show Result > $R/result_after_stop
journalctl -u bogiemon.service --no-pager -o cat > $R/journal.txt
journalctl -u bogiemon.service --no-pager -o cat -p warning > $R/journal_warning.txt
touch $R/done
systemctl poweroff
"""


def _units(tmp: Path) -> Path:
    units = tmp / "units"
    (units / "bogiemon.service.d").mkdir(parents=True)
    service = (REPO / "systemd" / "bogiemon.service").read_text()
    assert "/opt/bogiemon/bin/bogiemon run" in service
    (units / "bogiemon.service").write_text(
        service.replace("/opt/bogiemon/bin/bogiemon run", "/usr/bin/python3 -m bogiemon run")
    )
    (units / "bogiemon.service.d" / "system-test.conf").write_text(
        "[Service]\n"
        f"Environment=PYTHONPATH={IN_CONTAINER_SITE}:{IN_CONTAINER_DEPS}\n"
        "DeviceAllow=char-pts rw\n"
        "WatchdogSec=4\n"
        "RestartSec=1\n"
        "TimeoutStartSec=60\n"
    )
    (units / "bogiemon-feeder.service").write_text(
        "[Unit]\nDescription=simulated serial ADC on a pty\n[Service]\n"
        f"Environment=PYTHONPATH={IN_CONTAINER_SITE}:{IN_CONTAINER_DEPS}\n"
        "ExecStart=/usr/bin/python3 /T/feeder.py\n"
    )
    (units / "bogiemon-systemtest.service").write_text(
        "[Unit]\nDescription=bogiemon system test\nAfter=multi-user.target\n"
        "[Service]\nType=oneshot\nExecStart=/bin/bash /T/runner.sh\nTimeoutStartSec=240\n"
    )
    return units


def _nspawn_available() -> str | None:
    """None when the container can run here, else why not (after trying to install what is missing)."""
    if os.geteuid() != 0:
        return "systemd-nspawn needs root"
    if shutil.which("systemd-nspawn") is None and shutil.which("apt-get"):
        subprocess.run(["apt-get", "install", "-y", "-q", "systemd-container"], capture_output=True, timeout=600)
    if shutil.which("systemd-nspawn") is None:
        return "systemd-nspawn is missing and could not be installed (apt-get install systemd-container)"
    if shutil.which("script") is None:
        return "`script` (util-linux) is missing: nspawn -b needs a pty"
    if not Path("/usr/bin/python3").exists():
        return "the container runs the service with /usr/bin/python3, which this host lacks"
    return None


@pytest.fixture(scope="module")
def results(tmp_path_factory: pytest.TempPathFactory) -> Path:
    reason = _nspawn_available()
    if reason is not None:
        pytest.skip(reason)
    tmp = tmp_path_factory.mktemp("system")
    _units(tmp)
    (tmp / "feeder.py").write_text(FEEDER)
    (tmp / "bogiemon.toml").write_text(CONFIG)
    (tmp / "runner.sh").write_text(RUNNER)
    binds = [f"--bind={tmp}:/T", f"--bind-ro={sysconfig.get_paths()['purelib']}:{IN_CONTAINER_DEPS}"]
    binds.append(f"--bind-ro={REPO / 'bogiemon'}:{IN_CONTAINER_SITE}/bogiemon")
    nspawn = [
        "systemd-nspawn", "-D", "/", "--volatile=yes", "--private-network", "--register=no", "--keep-unit",
        "--machine=bogiemon-test", *binds, "--setenv=SYSTEMD_UNIT_PATH=/T/units:", "-b",
        "systemd.firstboot=off", "systemd.wants=bogiemon-systemtest.service",
    ]  # fmt: skip
    console = tmp / "console.log"
    proc = subprocess.run(
        ["script", "-qfc", " ".join(nspawn), str(console)], stdin=subprocess.DEVNULL, capture_output=True, timeout=300
    )
    done = tmp / "results" / "done"
    assert done.exists(), f"the container did not finish (status {proc.returncode}); console:\n{console.read_text(errors='replace')[-4000:]}"
    return tmp / "results"


def read(results: Path, name: str) -> str:
    return (results / name).read_text().strip()


def test_ready_comes_with_the_first_data(results: Path) -> None:
    assert read(results, "start_rc") == "0"
    assert read(results, "active_after_start") == "active"
    # READY=1 carries "receiving data"; the first STATUS= may follow it at once.
    assert read(results, "status_after_start").startswith(("receiving data", "running, first window"))
    assert read(results, "status_running").startswith("mode normal")


def test_the_hardening_is_in_force_on_the_live_process(results: Path) -> None:
    status = dict(line.split(":", 1) for line in read(results, "proc_status").splitlines())
    assert status["Uid"].split()[0] != "0"  # a dynamic user, not root
    assert int(status["CapEff"].strip(), 16) == 0
    assert status["NoNewPrivs"].strip() == "1" and status["Seccomp"].strip() == "2"
    assert read(results, "usr_write") == "read-only"
    assert read(results, "root_entries") == "0"
    exposure = [line for line in read(results, "security.txt").splitlines() if "Overall exposure level" in line]
    assert exposure and float(exposure[0].split(":")[1].split()[0]) <= 2.0


def test_reload_applies_a_good_config_and_rejects_a_bad_one_while_running(results: Path) -> None:
    assert read(results, "reload_rc") == "0"
    assert read(results, "status_after_reload") == "reloaded"
    assert read(results, "active_after_reload") == "active"
    assert read(results, "status_after_bad_reload").startswith("reload rejected")
    assert read(results, "active_after_bad_reload") == "active"
    assert read(results, "pid_after_bad_reload") == read(results, "pid_at_start")  # the same process kept running


def test_a_stalled_pipeline_is_restarted_by_the_watchdog(results: Path) -> None:
    assert int(read(results, "restarts_after_stall")) == int(read(results, "restarts_before_stall")) + 1
    assert "Failed with result 'watchdog'" in read(results, "journal.txt")
    assert read(results, "active_after_restart") == "active"


def test_it_stops_cleanly_and_logs_with_priorities(results: Path) -> None:
    assert read(results, "stop_rc") == "0"
    assert read(results, "result_after_stop") == "success"
    journal = read(results, "journal.txt")
    assert '"event": "ready"' in journal and '"event": "stopped"' in journal
    assert '"reload rejected' in read(results, "journal_warning.txt")  # logged at error: shown by -p warning
    assert '"event": "ready"' not in read(results, "journal_warning.txt")  # info stays out


if __name__ == "__main__":  # pragma: no cover - run by hand: python tests/systemd/test_system.py
    sys.exit(pytest.main([__file__, "-v"]))
