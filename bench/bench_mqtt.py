"""Benchmark of alarm delivery: how fast the outbox drains after an outage, against a local mosquitto.

The broker is down while N events are committed (the publisher failing and backing off), then it
starts with a back-office listener subscribed; the figure is N over the time from the publisher's
connection to the listener holding every event, for the shipped rate limit and for the publisher
unlimited (its ceiling on this machine: SQLite marking, paho, the broker, the listener). Also
prints the CPU the monitor's side pays per committed event with delivery enabled, and the CPU an
idle, connected publisher costs.
Run with `make bench-mqtt` or `.venv/bin/python bench/bench_mqtt.py [--events N]`.
"""

from __future__ import annotations

import argparse
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bogiemon.daemon.config import MqttConfig  # noqa: E402
from bogiemon.daemon.delivery.connection import ConnectionSettings  # noqa: E402
from bogiemon.daemon.delivery.listener import Listener  # noqa: E402
from bogiemon.daemon.delivery.publisher import OutboxPublisher, PublisherSettings  # noqa: E402
from bogiemon.judgement.events import Event, EventKind  # noqa: E402
from bogiemon.daemon.logs import configure_logging  # noqa: E402
from bogiemon.daemon.store import EventStore  # noqa: E402
from tests.daemon.delivery.mqtt_broker import Broker, ensure_mosquitto  # noqa: E402
from tests.judgement.event_examples import event_of  # noqa: E402

WAGON = "bench-wagon"


def events(n: int) -> list[Event]:
    return [event_of(EventKind.SUSPECTED, 1.7e9 + i, {"i4_norm": 0.2}, config_hash="bench") for i in range(n)]


def drain(workdir: Path, n: int, rate_per_s: float, max_inflight: int) -> tuple[float, float]:
    """(messages per second from connection to the last event kept, commit CPU s per event)."""
    broker = Broker(workdir / "broker").start()  # once, so that the back office's session exists
    connection = ConnectionSettings("127.0.0.1", broker.port)
    prime = Listener(connection, prefix="bench", client_id="bench-office")
    stop = threading.Event()
    thread = threading.Thread(target=prime.run, args=(stop,), daemon=True)
    thread.start()
    prime.subscribed.wait(10)
    stop.set()
    thread.join(5)
    broker.kill(signal.SIGTERM)  # down while the events are committed

    store = EventStore(workdir / "state")
    settings = PublisherSettings(connection, WAGON, topic_prefix="bench", status_period_s=0, max_rate_msgs_per_s=rate_per_s,
                                 max_inflight=max_inflight, backoff_min_s=0.05, backoff_max_s=0.05)  # fmt: skip
    publisher = OutboxPublisher(settings, workdir / "state")
    publisher.start()
    cpu_start_s = time.thread_time()
    for event in events(n):
        store.append([event])
        publisher.wake()
    commit_cpu_s = (time.thread_time() - cpu_start_s) / n
    broker.start()
    listener = Listener(connection, prefix="bench", client_id="bench-office")
    stop = threading.Event()
    thread = threading.Thread(target=listener.run, args=(stop,), daemon=True)
    thread.start()
    while not publisher.connected:
        time.sleep(0.001)
    start_s = time.perf_counter()
    while len(listener.events) < n:
        time.sleep(0.001)
    elapsed_s = time.perf_counter() - start_s
    publisher.stop()
    stop.set()
    thread.join(5)
    broker.kill()
    store.close()
    return n / elapsed_s, commit_cpu_s


def idle_cpu_fraction(workdir: Path, seconds: float) -> float:
    """CPU of this process (a connected publisher with nothing to send; the main thread sleeps)."""
    broker = Broker(workdir / "broker").start()
    publisher = OutboxPublisher(PublisherSettings(ConnectionSettings("127.0.0.1", broker.port), WAGON, status_period_s=0), workdir / "state")
    publisher.start()
    while not publisher.connected:
        time.sleep(0.01)
    cpu_start_s, wall_start_s = time.process_time(), time.perf_counter()
    time.sleep(seconds)
    fraction = (time.process_time() - cpu_start_s) / (time.perf_counter() - wall_start_s)
    publisher.stop()
    broker.kill()
    return fraction


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=2000, help="backlog size for the unlimited runs")
    args = parser.parse_args()
    if (reason := ensure_mosquitto()) is not None:
        print(f"bench_mqtt: skipped: {reason}")
        return 0
    configure_logging(sys.stderr, level="error")  # figures only on stdout
    shipped = MqttConfig()
    cases = [
        (f"shipped limits ({shipped.max_rate_msgs_per_s:g} msg/s, {shipped.max_inflight} in flight)",
         min(args.events, int(20 * shipped.max_rate_msgs_per_s)), shipped.max_rate_msgs_per_s, shipped.max_inflight),
        ("no rate limit, 10 in flight", args.events, 1e9, 10),
        ("no rate limit, 100 in flight", args.events, 1e9, 100),
    ]  # fmt: skip
    print(f"# backlog drain after an outage, mosquitto on loopback, {time.strftime('%Y-%m-%d')}")
    for name, n, rate, inflight in cases:
        with tempfile.TemporaryDirectory(prefix="bench-mqtt-") as scratch:
            per_s, commit_cpu_s = drain(Path(scratch), n, rate, inflight)
        print(f"{name:<45} {n:>6} events  {per_s:10.1f} msg/s   (commit + wake: {commit_cpu_s * 1e3:.2f} ms CPU per event)")
    with tempfile.TemporaryDirectory(prefix="bench-mqtt-") as scratch:
        print(f"{'idle publisher, connected':<45} {100 * idle_cpu_fraction(Path(scratch), 5.0):.2f} % of one core")
    return 0


if __name__ == "__main__":
    sys.exit(main())
