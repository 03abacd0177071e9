"""Connections to an MQTT broker, shared by the publisher and `bogiemon listen`, whatever the transport.

The settings of a connection; TLS from a CA file and an optional client certificate, credentials
read from files at each attempt (so a rotated password needs no restart), never from the command
line, and never logged (paho_transport.py uses them). Errors are turned into one line that names
the cause and the file or setting to look at.
"""

from __future__ import annotations

import os
import socket
import ssl
import stat
from dataclasses import dataclass


@dataclass(frozen=True)
class Reason:
    """An MQTT 5 reason code (CONNACK, PUBACK, SUBACK, DISCONNECT) and its name in the standard."""

    value: int  # 0x00 success, 0x01 granted QoS 1, 0x80 and above a failure
    name: str  # as the standard and paho spell it: "Not authorized"

    @property
    def is_failure(self) -> bool:
        return self.value >= 0x80

    def __str__(self) -> str:
        return self.name


SUCCESS = Reason(0x00, "Success")


class CredentialsError(Exception):
    """A TLS or credentials file that cannot be used; the message names the file (never its content)."""


@dataclass(frozen=True)
class ConnectionSettings:
    host: str
    port: int
    tls: bool = False
    ca_file: str = ""  # empty with tls: the system's trust store
    cert_file: str = ""  # client certificate (PEM), with key_file
    key_file: str = ""
    username_file: str = ""
    password_file: str = ""
    keepalive_s: int = 30
    connect_timeout_s: float = 10.0

    @property
    def address(self) -> str:
        return f"{self.host}:{self.port}"


# A user name or a password is a line; a file larger than this one is the wrong file (a log, a
# device), and reading it to its first line end must not take the daemon's memory.
MAX_SECRET_BYTES = 4096


def read_secret(path: str, what: str) -> str:
    """The first line of a credentials file (a regular file), without its line end."""
    try:
        # O_NONBLOCK: a FIFO must not block the open (it is refused below); a NUL in the name is a ValueError.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise CredentialsError(f"{what} {path}: cannot read it: {exc.strerror or exc}") from None
    except ValueError:
        raise CredentialsError(f"{what} {path!r}: not a file name") from None
    try:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            raise CredentialsError(f"{what} {path}: not a regular file")
        raw = os.read(fd, MAX_SECRET_BYTES + 1)  # a regular file: one read returns what is there, up to the limit
    except OSError as exc:
        raise CredentialsError(f"{what} {path}: cannot read it: {exc.strerror or exc}") from None
    finally:
        os.close(fd)
    line, newline, _ = raw.partition(b"\n")
    if len(line) > MAX_SECRET_BYTES or (not newline and len(raw) > MAX_SECRET_BYTES):
        raise CredentialsError(f"{what} {path}: its first line is longer than {MAX_SECRET_BYTES} bytes: not a credentials file")
    try:
        value = line.decode("utf-8").rstrip("\r")
    except UnicodeDecodeError:
        raise CredentialsError(f"{what} {path}: not UTF-8 text") from None
    if not value:
        raise CredentialsError(f"{what} {path}: the file is empty")
    return value


def readable_by_others(path: str) -> str | None:
    """Why a credential or key file is exposed (its group or others may read it), or None.

    A file that is missing or unreadable now gives None: it is named when it is read (at each
    connection attempt: systemd's LoadCredential= puts it in place at start, mode 0400).
    """
    try:
        mode = os.stat(path).st_mode
    except (OSError, ValueError):
        return None
    readers = [who for who, bit in (("its group", stat.S_IRGRP), ("others", stat.S_IROTH)) if mode & bit]
    if not readers:
        return None
    return (
        f"{path} is readable by {' and '.join(readers)} (mode {stat.S_IMODE(mode):04o}): "
        f"chmod 600 {path}, or hand it over with systemd's LoadCredential="
    )


def _refuse_encrypted_key() -> bytes:
    # Without a password callback OpenSSL would prompt on the terminal: a daemon would hang.
    raise CredentialsError("the key file is encrypted: give an unencrypted key, protected by its file mode or LoadCredential=")


def tls_context(settings: ConnectionSettings) -> ssl.SSLContext:
    """A client context: TLS 1.2 or newer, the broker's certificate and host name checked."""
    try:
        context = ssl.create_default_context(cafile=settings.ca_file or None)
    except FileNotFoundError:
        raise CredentialsError(f"CA file {settings.ca_file}: no such file") from None
    except (OSError, ssl.SSLError) as exc:
        raise CredentialsError(f"CA file {settings.ca_file}: cannot load it: {_ssl_reason(exc)}") from None
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    if settings.cert_file:
        try:
            context.load_cert_chain(settings.cert_file, settings.key_file or None, password=_refuse_encrypted_key)
        except FileNotFoundError as exc:
            raise CredentialsError(f"client certificate or key {exc.filename or settings.cert_file}: no such file") from None
        except (OSError, ssl.SSLError) as exc:
            raise CredentialsError(
                f"client certificate {settings.cert_file} with key {settings.key_file}: cannot load them: {_ssl_reason(exc)}"
            ) from None
    return context


def _ssl_reason(exc: BaseException) -> str:
    return getattr(exc, "reason", None) or getattr(exc, "strerror", None) or str(exc) or type(exc).__name__


@dataclass(frozen=True)
class LinkProblem:
    """Why a connection failed or ended: kind is what a log says once ("tls", "credentials", ...)."""

    kind: str  # unreachable, tls, credentials, refused, closed, lost, files, rejected-message
    text: str  # one line naming the cause and what to check

    def __str__(self) -> str:
        return self.text


def describe_connect_error(exc: OSError, settings: ConnectionSettings) -> LinkProblem:
    """A failed TCP or TLS connection."""
    if isinstance(exc, ssl.SSLCertVerificationError):
        where = settings.ca_file or "the system's trust store"
        return LinkProblem("tls", f"TLS: the broker's certificate is not trusted ({exc.verify_message}); check mqtt.tls_ca_file ({where}) and mqtt.host")
    if isinstance(exc, ssl.SSLError):
        return LinkProblem("tls", f"TLS handshake failed ({_ssl_reason(exc)}): the broker may refuse the client certificate")
    if isinstance(exc, ConnectionRefusedError):
        return LinkProblem("unreachable", f"connection refused by {settings.address}: is the broker running and listening there?")
    if isinstance(exc, socket.gaierror):
        return LinkProblem("unreachable", f"cannot resolve {settings.host}: {exc.strerror}")
    if isinstance(exc, TimeoutError):
        return LinkProblem("unreachable", f"{settings.address} did not answer within {settings.connect_timeout_s:g} s")
    return LinkProblem("unreachable", f"cannot connect to {settings.address}: {exc.strerror or exc}")


def describe_closed(settings: ConnectionSettings, connected: bool, reason: Reason, socket_error: str | None) -> LinkProblem:
    """A connection that ended without a refusal; socket_error is paho's last error line, if any."""
    detail = f" ({socket_error})" if socket_error else ("" if reason.value == 0 else f": {reason}")
    if connected:
        return LinkProblem("lost", "connection lost" + detail)
    if settings.tls:
        # TLS 1.3 checks the client certificate after the handshake: a refusal shows as an alert or
        # an EOF on the first read, before any CONNACK.
        return LinkProblem("tls", f"TLS: the broker closed the connection before CONNACK{detail}: it may refuse the client certificate (mqtt.tls_cert_file)")
    return LinkProblem("closed", "connection closed before CONNACK" + detail)


def describe_refusal(reason: Reason, credentials: str = "mqtt.username_file and mqtt.password_file") -> LinkProblem:
    """A CONNACK that refuses the connection; credentials names where they come from."""
    if is_auth_refusal(reason):
        return LinkProblem("credentials", f"the broker refused the credentials ({reason}): check {credentials}")
    return LinkProblem("refused", f"the broker refused the connection ({reason})")


def is_auth_refusal(reason: Reason) -> bool:
    # Bad user name or password, not authorized, bad authentication method.
    return reason.value in (0x86, 0x87, 0x8C)
