"""A real mosquitto broker for the real-component MQTT tests, on loopback on a free port, with test certificates.

mosquitto comes from Debian's package (`make test` installs it through `make system-deps` when
root can use apt-get; `ensure_mosquitto` tries the same). The certificates are made with the
openssl command line: a CA, the broker's certificate for 127.0.0.1, a client certificate, and a
second, untrusted CA with a client certificate of its own (the bad-certificate case).
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

READY_TIMEOUT_S = 10.0


def find_mosquitto() -> str | None:
    return shutil.which("mosquitto") or next((p for p in ("/usr/sbin/mosquitto",) if os.access(p, os.X_OK)), None)


def ensure_mosquitto() -> str | None:
    """None when mosquitto is there (installing it if root can); else why the tests must skip."""
    if find_mosquitto() is not None:
        return None
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        return "mosquitto is not installed and cannot be here (needs root and apt-get): `apt-get install mosquitto`, or `make system-deps` as root"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    install = ["apt-get", "install", "-y", "-qq", "--no-install-recommends", "mosquitto"]
    proc = subprocess.run(install, capture_output=True, text=True, env=env)
    if proc.returncode != 0:  # an empty or stale package list: update once and retry
        subprocess.run(["apt-get", "update", "-qq"], capture_output=True, text=True, env=env)
        proc = subprocess.run(install, capture_output=True, text=True, env=env)
    if find_mosquitto() is None:
        return f"mosquitto is not installed and `apt-get install mosquitto` failed: {proc.stderr.strip().splitlines()[-1:]}"
    return None


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass(frozen=True)
class Certs:
    ca: Path
    server_cert: Path
    server_key: Path
    client_cert: Path
    client_key: Path
    rogue_ca: Path  # a CA nobody trusts
    rogue_client_cert: Path  # signed by rogue_ca
    rogue_client_key: Path


def _openssl(*args: str, cwd: Path) -> None:
    proc = subprocess.run(["openssl", *args], cwd=cwd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"openssl {' '.join(args)}: {proc.stderr}")


def make_certs(directory: Path) -> Certs:
    """EC P-256 keys (quick to make), certificates valid for a day."""
    directory.mkdir(parents=True, exist_ok=True)
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    for ca in ("ca", "rogue-ca"):
        _openssl("req", "-x509", *ec, "-keyout", f"{ca}.key", "-out", f"{ca}.crt", "-days", "1", "-subj", f"/CN=bogiemon test {ca}", cwd=directory)
    (directory / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\nextendedKeyUsage=serverAuth\n")
    (directory / "client.ext").write_text("extendedKeyUsage=clientAuth\n")
    for name, ca, ext in (("server", "ca", "server.ext"), ("client", "ca", "client.ext"), ("rogue-client", "rogue-ca", "client.ext")):
        _openssl("req", *ec, "-keyout", f"{name}.key", "-out", f"{name}.csr", "-subj", f"/CN=bogiemon test {name}", cwd=directory)
        _openssl(
            "x509", "-req", "-in", f"{name}.csr", "-CA", f"{ca}.crt", "-CAkey", f"{ca}.key", "-CAcreateserial",
            "-out", f"{name}.crt", "-days", "1", "-extfile", ext, cwd=directory,
        )  # fmt: skip
    d = directory
    return Certs(d / "ca.crt", d / "server.crt", d / "server.key", d / "client.crt", d / "client.key",
                 d / "rogue-ca.crt", d / "rogue-client.crt", d / "rogue-client.key")  # fmt: skip


def make_password_file(path: Path, username: str, password: str) -> Path:
    subprocess.run(["mosquitto_passwd", "-b", "-c", str(path), username, password], check=True, capture_output=True)
    path.chmod(0o600)
    return path


class Broker:
    """One mosquitto process; kill() and start() again keep its port and its persistence file."""

    def __init__(self, workdir: Path, certs: Certs | None = None, password_file: Path | None = None) -> None:
        self.workdir = workdir
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.port = free_port()
        self.tls = certs is not None
        self.log_path = workdir / "mosquitto.log"
        self.proc: subprocess.Popen[bytes] | None = None
        lines = [
            f"listener {self.port} 127.0.0.1",
            "user root" if os.geteuid() == 0 else "",  # as root mosquitto would switch to `mosquitto`, who cannot read tmp_path
            # Sessions and queued messages survive a restart (saved at exit and every second).
            "persistence true",
            f"persistence_location {workdir}/",
            "autosave_interval 1",
            "max_queued_messages 100000",
            f"log_dest file {self.log_path}",
            "log_type error",
            "log_type warning",
            "log_type notice",
            "log_type information",
            "connection_messages true",
        ]
        if certs is not None:
            lines += [f"cafile {certs.ca}", f"certfile {certs.server_cert}", f"keyfile {certs.server_key}",
                      "require_certificate true", "tls_version tlsv1.2"]  # fmt: skip
        if password_file is not None:
            lines += ["allow_anonymous false", f"password_file {password_file}"]
        else:
            lines += ["allow_anonymous true"]
        self.conf_path = workdir / "mosquitto.conf"
        self.conf_path.write_text("\n".join(line for line in lines if line) + "\n")

    def start(self) -> Broker:
        binary = find_mosquitto()
        assert binary is not None, "ensure_mosquitto() first"
        stderr_path = self.workdir / "mosquitto.stderr"
        with stderr_path.open("ab") as stderr:
            self.proc = subprocess.Popen([binary, "-c", str(self.conf_path)], stdout=subprocess.DEVNULL, stderr=stderr)
        deadline_s = time.monotonic() + READY_TIMEOUT_S
        while time.monotonic() < deadline_s:
            if self.proc.poll() is not None:
                raise RuntimeError(f"mosquitto exited {self.proc.returncode}: {stderr_path.read_text(errors='replace')}\n{self.log()}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return self
            except OSError:
                time.sleep(0.02)
        raise RuntimeError(f"mosquitto did not listen on {self.port} within {READY_TIMEOUT_S} s\n{self.log()}")

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.send_signal(sig)
            self.proc.wait(10)
        self.proc = None

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""

    @property
    def running(self) -> bool:
        return self.proc is not None and self.proc.poll() is None
