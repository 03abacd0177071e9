"""Alarm delivery over MQTT against a real mosquitto: every committed event arrives, in order.

The real-component cases: TLS with a client certificate and a password, refused credentials and
certificates, the broker down at the start and the backlog drained, the broker restarted
mid-burst, the daemon (a publisher process) killed with SIGKILL, and the service end to end. Each
commits events to a real event store exactly as the monitor does (EventStore.append) while the
outbox publisher runs, and counts what a real consumer (the `bogiemon listen` library) kept: every
committed event at least once, the first copies in commit order. The broker runs on loopback on a
free port. The publisher's logic without a broker is in test_publisher.py (the in-memory transport).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import cantools
import pytest
import structlog.testing
from can.interfaces.virtual import VirtualBus

from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.messages import EVENT_SCHEMA, STATUS_SCHEMA
from bogiemon.daemon.service import Service
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Block, EndOfStream, MemorySource
from bogiemon.drivers.candb import shipped_dbc_text
from tests.daemon.delivery.mqtt_broker import Broker, Certs, make_password_file
from tests.daemon.delivery.support import (
    DEADLINE_S,
    WAGON,
    assert_all_in_order,
    commit,
    listening,
    make_events,
    mqtt_logs,
    publishing,
    settings,
    wait_until,
)
from tests.daemon.synthetic import as_blocks, bogie_accel, short_windows_config

DB = cantools.database.load_string(shipped_dbc_text(), database_format="dbc")


def plain(broker: Broker) -> ConnectionSettings:
    return ConnectionSettings("127.0.0.1", broker.port, connect_timeout_s=2.0)


def test_normal_delivery_over_tls_with_a_client_certificate_and_credentials(tmp_path: Path, certs: Certs) -> None:
    users = make_password_file(tmp_path / "passwords", "wagon", "s3cret-Pa55")
    (tmp_path / "user").write_text("wagon\n")
    (tmp_path / "password").write_text("s3cret-Pa55\n")
    b = Broker(tmp_path / "broker", certs=certs, password_file=users).start()
    try:
        connection = ConnectionSettings(
            "127.0.0.1", b.port, tls=True, ca_file=str(certs.ca), cert_file=str(certs.client_cert), key_file=str(certs.client_key),
            username_file=str(tmp_path / "user"), password_file=str(tmp_path / "password"), connect_timeout_s=2.0,
        )  # fmt: skip
        store = EventStore(tmp_path / "state")
        committed = make_events(30)
        with listening(connection) as listener, publishing(tmp_path / "state", settings(connection, status_period_s=0.1), status=True) as publisher:
            for batch in (committed[:10], committed[10:25], committed[25:]):
                commit(store, batch, publisher)
            assert_all_in_order(listener, committed)
            assert wait_until(lambda: store.outbox.counts().pending_events == 0)  # every PUBACK recorded
            assert wait_until(lambda: len(listener.statuses) >= 2)
        assert [m.to_event() for m in listener.events] == committed  # every field survives the trip
        assert listener.duplicates == 0
        assert listener.statuses[0].schema_id == STATUS_SCHEMA and listener.events[0].schema_id == EVENT_SCHEMA
        assert listener.statuses[-1].outbox.dropped_status == 0
        assert listener.states == {WAGON: "offline"}  # "online" on connect, "offline" at a clean stop
        assert publisher.counters.connections == 1 and publisher.counters.delivered_events == 30
    finally:
        b.kill()


def test_broker_down_at_start_then_the_backlog_arrives_oldest_first(tmp_path: Path, broker: Broker) -> None:
    with listening(plain(broker)):
        pass  # the back office's session exists: the broker queues for it while it is away
    broker.kill(signal.SIGTERM)
    store = EventStore(tmp_path / "state")
    committed = make_events(40)
    with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(plain(broker), max_rate_msgs_per_s=200.0)) as publisher:
        commit(store, committed[:25], publisher)
        assert wait_until(lambda: publisher.counters.connect_failures >= 3)
        assert store.outbox.counts().pending_events == 25  # nothing is delivered, nothing is lost
        broker.start()
        commit(store, committed[25:], publisher)
        with listening(plain(broker)) as listener:
            assert_all_in_order(listener, committed)
    failing = mqtt_logs(logs, "failing")
    assert len(failing) == 1 and "connection refused" in str(failing[0]["reason"])  # logged once, not per attempt
    assert len(mqtt_logs(logs, "connected")) == 1


def test_broker_stopped_mid_burst_and_restarted_loses_nothing(tmp_path: Path, broker: Broker) -> None:
    """The broker goes down (SIGTERM: it saves its sessions) with messages in flight, then comes back.

    mosquitto killed with SIGKILL can lose messages it has already acknowledged (its persistence is
    periodic): past the PUBACK a message is the broker's to keep (docs/mqtt.md), so the abrupt case
    for the publisher is the network cut below, where the broker keeps what it acknowledged.
    """
    store = EventStore(tmp_path / "state")
    committed = make_events(300)
    with listening(plain(broker)) as listener, publishing(tmp_path / "state", settings(plain(broker), max_rate_msgs_per_s=300.0)) as publisher:
        commit(store, committed, publisher)
        assert wait_until(lambda: len(listener.events) >= 60)
        broker.kill(signal.SIGTERM)
        assert len(listener.events) < len(committed), "the burst ended before the broker went down"
        assert wait_until(lambda: publisher.counters.connections_lost == 1)
        broker.start()
        assert_all_in_order(listener, committed)
        assert publisher.counters.connections == 2


def test_daemon_killed_9_mid_burst_then_restarted_delivers_every_committed_event(tmp_path: Path, broker: Broker) -> None:
    """A publisher in a real process, committing and publishing, killed with SIGKILL mid-burst."""
    state_dir = tmp_path / "state"
    code = textwrap.dedent(
        f"""
        import sys, time
        from bogiemon.daemon.logs import configure_logging
        from bogiemon.daemon.delivery.connection import ConnectionSettings
        from bogiemon.daemon.delivery.publisher import OutboxPublisher, PublisherSettings
        from bogiemon.daemon.store import EventStore
        from tests.daemon.delivery.support import make_events, WAGON
        configure_logging(sys.stderr)  # stdout carries the committed event ids
        store = EventStore({str(state_dir)!r})
        publisher = OutboxPublisher(PublisherSettings(ConnectionSettings("127.0.0.1", {broker.port}), WAGON, topic_prefix="fleet/test",
                                    status_period_s=0, max_rate_msgs_per_s=100.0, max_inflight=10), {str(state_dir)!r})
        publisher.start()
        for event in make_events(400):
            store.append([event])
            publisher.wake()
            print(event.event_id, flush=True)
            time.sleep(0.005)  # a burst that lasts a few seconds: the kill comes in the middle
        publisher.stop()
        """
    )
    daemon_log = tmp_path / "daemon.log"
    with listening(plain(broker)) as listener, daemon_log.open("w") as log:
        repo = Path(__file__).resolve().parents[3]
        proc = subprocess.Popen([sys.executable, "-c", code], cwd=repo, stdout=subprocess.PIPE, stderr=log, text=True)
        assert proc.stdout is not None
        printed = [proc.stdout.readline().strip() for _ in range(150)]  # committed: the process is mid-burst
        assert wait_until(lambda: len(listener.events) >= 20), broker.log() + daemon_log.read_text()
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        proc.stdout.close()
        assert proc.returncode == -signal.SIGKILL
        assert wait_until(lambda: listener.states.get(WAGON) == "offline")  # the last will
        store = EventStore(state_dir)
        committed = store.events()
        assert [e.event_id for e in committed[: len(printed)]] == printed and len(committed) < 400
        pending_after_kill = store.outbox.counts().pending_events
        assert 0 < pending_after_kill < len(committed)
        with publishing(state_dir, settings(plain(broker))):  # the daemon restarted
            assert_all_in_order(listener, committed)
            assert wait_until(lambda: listener.states.get(WAGON) == "online")


@pytest.mark.parametrize("case", ["untrusted broker", "untrusted client"])
def test_a_bad_certificate_is_logged_once_and_retried_without_delivering(tmp_path: Path, certs: Certs, case: str) -> None:
    b = Broker(tmp_path / "broker", certs=certs).start()
    try:
        if case == "untrusted broker":  # the wagon does not trust the broker's CA
            connection = ConnectionSettings("127.0.0.1", b.port, tls=True, ca_file=str(certs.rogue_ca), cert_file=str(certs.client_cert),
                                            key_file=str(certs.client_key), connect_timeout_s=2.0)  # fmt: skip
            expected = "the broker's certificate is not trusted"
        else:  # the broker does not trust the wagon's certificate
            connection = ConnectionSettings("127.0.0.1", b.port, tls=True, ca_file=str(certs.ca), cert_file=str(certs.rogue_client_cert),
                                            key_file=str(certs.rogue_client_key), connect_timeout_s=2.0)  # fmt: skip
            expected = "certificate"
        store = EventStore(tmp_path / "state")
        with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(connection)) as publisher:
            commit(store, make_events(5), publisher)
            assert wait_until(lambda: publisher.counters.connect_failures >= 3)
            assert publisher.is_alive() and publisher.counters.connections == 0
        failing = mqtt_logs(logs, "failing")
        assert len(failing) == 1, failing
        assert expected in str(failing[0]["reason"])
        assert store.outbox.counts().pending_events == 5
    finally:
        b.kill()


def test_wrong_credentials_are_logged_once_backed_off_and_picked_up_when_fixed(tmp_path: Path, mosquitto: None) -> None:
    users = make_password_file(tmp_path / "passwords", "wagon", "right-Pa55")
    (tmp_path / "user").write_text("wagon\n")
    password_file = tmp_path / "password"
    password_file.write_text("wrong-Pa55\n")
    b = Broker(tmp_path / "broker", password_file=users).start()
    try:
        connection = ConnectionSettings("127.0.0.1", b.port, username_file=str(tmp_path / "user"), password_file=str(password_file), connect_timeout_s=2.0)
        store = EventStore(tmp_path / "state")
        committed = make_events(5)
        with structlog.testing.capture_logs() as logs, publishing(tmp_path / "state", settings(connection, backoff_min_s=0.05, backoff_max_s=0.4)) as publisher:
            commit(store, committed, publisher)
            assert wait_until(lambda: publisher.counters.connect_failures >= 4)
            assert publisher.is_alive() and store.outbox.counts().pending_events == 5
            refused = mqtt_logs(logs, "failing")
            assert len(refused) == 1 and refused[0]["log_level"] == "error"
            assert "refused the credentials" in str(refused[0]["reason"]) and "mqtt.password_file" in str(refused[0]["reason"])
            password_file.write_text("right-Pa55\n")  # rotated without a restart: read at each attempt
            with listening(ConnectionSettings("127.0.0.1", b.port, username_file=str(tmp_path / "user"), password_file=str(password_file))) as listener:
                assert_all_in_order(listener, committed)
        assert not any("Pa55" in repr(entry) for entry in logs)  # no password in the log, right or wrong
    finally:
        b.kill()


class HeldSource(MemorySource):
    """The blocks of a run, then no data until released: a live source whose wagon has stopped."""

    finite = True

    def __init__(self, blocks: list[Block], release: threading.Event) -> None:
        super().__init__(blocks)
        self.release = release

    def read(self, timeout_s: float) -> Block | None:
        try:
            return super().read(timeout_s)
        except EndOfStream:
            if self.release.wait(timeout_s):
                raise
            return None


def service_config(tmp_path: Path, broker: Broker, can_channel: str, status_period_s: float = 0.2) -> Path:
    path = tmp_path / "bogiemon.toml"  # the daemon tests' 6 s windows: a coupled bogie alarms quickly
    path.write_text(short_windows_config(state_dir=tmp_path / "state") + textwrap.dedent(f"""
        [wagon]
        id = "{WAGON}"
        [mqtt]
        enabled = true
        host = "127.0.0.1"
        port = {broker.port}
        tls = false
        topic_prefix = "fleet/test"
        status_period_s = {status_period_s}
        max_rate_msgs_per_s = 100.0
        reconnect_backoff_min_s = 0.1
        reconnect_backoff_max_s = 0.5
        [can_alarms]
        enabled = true
        interface = "virtual"
        channel = "{can_channel}"
        heartbeat_period_s = 0.05
        """))  # fmt: skip
    return path


def test_the_service_delivers_its_events_status_and_alarm_frames_and_survives_a_reload(tmp_path: Path, broker: Broker) -> None:
    can_channel = f"bogiemon-service-test-{os.getpid()}"
    config_path = service_config(tmp_path, broker, can_channel)
    receiver = VirtualBus(channel=can_channel, receive_own_messages=False)
    release = threading.Event()
    blocks = as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0))
    sink = MemorySink()
    service = Service(config_path, lambda config: HeldSource(blocks, release), sinks=[sink])
    exit_codes: list[int] = []
    with listening(plain(broker)) as listener:
        thread = threading.Thread(target=lambda: exit_codes.append(service.run()), daemon=True)
        thread.start()
        try:
            assert wait_until(lambda: len(listener.events) >= 2)
            assert wait_until(lambda: any(s.window is not None and s.mode == "confirmed" for s in listener.statuses))
            alarm = next(f for f in iter(lambda: receiver.recv(DEADLINE_S), None) if f.arbitration_id == 0x300)
            first_publisher = service.delivery.publisher
            config_path.write_text(config_path.read_text().replace("status_period_s = 0.2", "status_period_s = 0.1"))
            service.request_reload()
            assert wait_until(lambda: (p := service.delivery.publisher) is not None and p is not first_publisher and p.connected)
            statuses_before = len(listener.statuses)
            assert wait_until(lambda: len(listener.statuses) > statuses_before)  # the new publisher reports
        finally:
            release.set()
            thread.join(DEADLINE_S)
        assert wait_until(lambda: listener.states.get(WAGON) == "offline")
    receiver.shutdown()
    assert exit_codes == [0]
    assert [e.kind.value for e in sink.events] == ["SUSPECTED", "CONFIRMED"]
    assert [m.to_event() for m in listener.events] == sink.events == EventStore(tmp_path / "state").events()
    status = next(s for s in listener.statuses if s.window is not None and s.mode == "confirmed")
    assert status.wagon_id == WAGON and status.window is not None and status.window.judged and status.counters["events"] == 2
    assert set(status.window.indicators) == {"i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm"}
    decoded = DB.decode_message(alarm.arbitration_id, bytes(alarm.data))
    assert isinstance(decoded, dict) and str(decoded["Kind"]) == "CONFIRMED"
