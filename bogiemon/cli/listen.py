"""`bogiemon listen --broker HOST[:PORT]`: the back office's side, for bench tests and demos.

Subscribes to every wagon's events, status and state under --prefix and prints each event once
(deduplicated by event_id), or commits it to --store. Credentials come from files only, and a
password goes over TLS only (unless --allow-plaintext). A message outside the schema is said on
stderr with its wagon, counted and acknowledged; the counts are printed at the end.
"""

from __future__ import annotations

import argparse
import signal
import socket
import sys
import threading
from datetime import UTC, datetime
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from bogiemon.daemon.delivery.connection import ConnectionSettings
    from bogiemon.daemon.delivery.listener import Received


def add_parser(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    p = sub.add_parser("listen", help="receive the wagons' events from an MQTT broker, each once")
    p.add_argument("--broker", required=True, metavar="HOST[:PORT]",
                   help="the broker; the port defaults to MQTT's, 1883, or 8883 with TLS (an IPv6 address in brackets: [::1]:8883)")  # fmt: skip
    p.add_argument("--prefix", default="bogiemon", help="the wagons' topic prefix (default: bogiemon)")
    p.add_argument("--tls", action="store_true", help="TLS, the broker checked against the system's CAs (implied by --tls-ca)")
    p.add_argument("--tls-ca", metavar="F", help="CA certificate(s) the broker's certificate must chain to (PEM)")
    p.add_argument("--tls-cert", metavar="F", help="client certificate (PEM), with --tls-key")
    p.add_argument("--tls-key", metavar="F", help="the client certificate's private key (PEM, not encrypted)")
    p.add_argument("--username-file", metavar="F", help="a file holding the MQTT user name")
    p.add_argument("--password-file", metavar="F", help="a file holding the MQTT password (needs TLS, or --allow-plaintext)")
    p.add_argument("--allow-plaintext", action="store_true", help="send the password without TLS (a bench's broker on loopback only)")
    p.add_argument("--client-id", help="the MQTT client id, which the broker keeps the session under (default: bogiemon-listen-HOSTNAME)")
    p.add_argument("--store", metavar="FILE.sqlite3", help="commit each event to this SQLite file (deduplicated across runs too)")
    p.add_argument("--json", action="store_true", help="one JSON message per line (the events, and the status with --status)")
    p.add_argument("--status", action="store_true", help="print the status messages too")
    p.add_argument("--count", type=int, metavar="N", help="exit after N new events")
    p.set_defaults(run=run)


# MQTT's registered ports (IANA): plain and over TLS.
MQTT_PORT, MQTTS_PORT = 1883, 8883


def parse_broker(text: str, tls: bool = False) -> tuple[str, int]:
    """(host, port) of HOST[:PORT] ([v6]:PORT); without a port, MQTT's: 8883 with TLS, else 1883."""
    from bogiemon.daemon.delivery.listener import ListenError
    bracketed = text.startswith("[") and "]" in text
    if bracketed and not text.endswith("]") or (not bracketed and text.count(":") == 1):
        host, _, port = text.rpartition(":")
    else:
        host, port = text, str(MQTTS_PORT if tls else MQTT_PORT)
    host = host.removeprefix("[").removesuffix("]")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ListenError(f"--broker: expected HOST or HOST:PORT, e.g. localhost or localhost:8883, got '{text}'")
    return host, int(port)


def connection_from_args(args: argparse.Namespace) -> ConnectionSettings:
    from bogiemon.daemon.delivery.connection import ConnectionSettings
    from bogiemon.daemon.delivery.listener import ListenError
    tls = bool(args.tls or args.tls_ca or args.tls_cert)
    host, port = parse_broker(args.broker, tls)
    if bool(args.tls_cert) != bool(args.tls_key):
        raise ListenError("--tls-cert and --tls-key go together")
    if args.password_file and not args.username_file:
        raise ListenError("--password-file needs --username-file")
    if args.password_file and not tls and not args.allow_plaintext:
        raise ListenError("--password-file without TLS would send the password in clear: add --tls or --tls-ca (or --allow-plaintext, on a bench)")
    return ConnectionSettings(
        host=host,
        port=port,
        tls=tls,
        ca_file=args.tls_ca or "",
        cert_file=args.tls_cert or "",
        key_file=args.tls_key or "",
        username_file=args.username_file or "",
        password_file=args.password_file or "",
    )


def format_received(received: Received, as_json: bool, with_status: bool) -> str | None:
    """The line to print for a message, or None."""
    from bogiemon.cli.events import format_event
    from bogiemon.daemon.messages import dump
    if received.event is not None:
        if received.duplicate:
            return None
        m = received.event
        return dump(m) if as_json else f"{m.wagon_id}  #{m.seq:<6} {format_event(m.to_event())}"
    if received.status is not None and with_status:
        s = received.status
        if as_json:
            return dump(s)
        when = datetime.fromtimestamp(s.time_s, tz=UTC).strftime("%Y-%m-%dT%H:%M:%SZ")
        window = "no window yet" if s.window is None else ("judged" if s.window.judged else f"not judged ({s.window.gate or 'sensor fault'})")
        return f"{s.wagon_id}  status {when}  mode {s.mode}, {window}, outbox {s.outbox.pending_events} events pending"
    if received.state is not None and not as_json:
        return f"{received.wagon_id}  is {received.state}"
    if received.cleared and not as_json:
        return f"{received.wagon_id}  {received.leaf} deleted at the broker"
    return None


def run(args: argparse.Namespace) -> int:
    from bogiemon.daemon.delivery.connection import readable_by_others
    from bogiemon.daemon.delivery.listener import Listener, ListenError, ReceivedStore
    connection = connection_from_args(args)
    for secret in (args.password_file, args.tls_key):  # the files whose content must stay private
        if secret and (exposed := readable_by_others(secret)) is not None:
            print(f"bogiemon listen: warning: {exposed}", file=sys.stderr, flush=True)
    if args.count is not None and args.count < 1:
        raise ListenError(f"--count: expected a positive number of events, got {args.count}")
    store = ReceivedStore(args.store) if args.store else None
    stop = threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda _signum, _frame: stop.set())

    def show(received: Received) -> None:
        if received.error is not None:
            print(f"bogiemon listen: {received.error}", file=sys.stderr, flush=True)
            return
        line = format_received(received, args.json, args.status)
        if line is not None:
            print(line, flush=True)

    listener = Listener(
        connection,
        prefix=args.prefix,
        client_id=args.client_id or f"bogiemon-listen-{socket.gethostname()}",
        store=store,
        on_message=show,
        on_link=lambda text: print(f"bogiemon listen: {text}", file=sys.stderr, flush=True),
        recent_events=0,  # printed or stored as they come: a long run holds none in memory
        recent_statuses=0,
    )
    try:
        listener.run(stop, max_events=args.count)
    except KeyboardInterrupt:
        print(f"bogiemon listen: {listener.summary()}", file=sys.stderr, flush=True)
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
        if store is not None:
            store.close()
    print(f"bogiemon listen: {listener.summary()}", file=sys.stderr, flush=True)
    return 0
