"""Alarm delivery over MQTT against a real mosquitto: every committed event arrives, in order.

Each case commits events to a real event store exactly as the monitor does (EventStore.append)
while the outbox publisher runs, and counts what a real consumer (the `bogiemon listen` library)
kept: every committed event at least once, the first copies in commit order. The broker runs on
loopback on a free port; the daemon-killed case runs the publisher in a subprocess killed with
SIGKILL. Waits have generous deadlines as safety nets; no test asserts a duration.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import cantools
import pytest
import structlog.testing
from can.interfaces.virtual import VirtualBus

from bogiemon.daemon.config import ConfigError, parse_config
from bogiemon.daemon.delivery import Delivery
from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.listener import Listener
from bogiemon.daemon.delivery.publisher import Backoff, OutboxPublisher, PublisherSettings, TokenBucket
from bogiemon.daemon.delivery.schema import EVENT_SCHEMA, STATUS_SCHEMA, OutboxStatus, StatusMessage
from bogiemon.daemon.events import DEFAULT_SEVERITY, Event, EventKind
from bogiemon.daemon.store import EventStore, OutboxCounts
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.service import Service, monitor_settings
from bogiemon.daemon.sinks import MemorySink
from bogiemon.drivers.base import Block, EndOfStream, MemorySource
from bogiemon.drivers.candb import shipped_dbc_text
from tests.daemon.mqtt_broker import Broker, Certs, LinkProxy, ensure_mosquitto, make_certs, make_password_file
from tests.daemon.synthetic import as_blocks, bogie_accel
from tests.daemon.test_service import write_config

WAGON = "318045331234"
DEADLINE_S = 20.0  # a safety net for waits, never a measured figure
DB = cantools.database.load_string(shipped_dbc_text(), database_format="dbc")
KINDS = [EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.SENSOR_FAULT, EventKind.SENSOR_CLEARED, EventKind.CLEARED]


@pytest.fixture(scope="session")
def mosquitto() -> None:
    reason = ensure_mosquitto()
    if reason is not None:
        pytest.skip(reason)


@pytest.fixture(scope="session")
def certs(tmp_path_factory: pytest.TempPathFactory, mosquitto: None) -> Certs:
    if shutil.which("openssl") is None:
        pytest.skip("the openssl command is not installed: it makes the test certificates (apt-get install openssl)")
    return make_certs(tmp_path_factory.mktemp("certs"))


@pytest.fixture
def broker(tmp_path: Path, mosquitto: None) -> Iterator[Broker]:
    b = Broker(tmp_path / "broker").start()
    yield b
    b.kill()


def wait_until(predicate: Callable[[], bool], deadline_s: float = DEADLINE_S) -> bool:
    end_s = time.monotonic() + deadline_s
    while time.monotonic() < end_s:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def plain(broker: Broker) -> ConnectionSettings:
    return ConnectionSettings("127.0.0.1", broker.port, connect_timeout_s=2.0)


def make_events(n: int, start_s: float = 1.7e9) -> list[Event]:
    kinds = [KINDS[i % len(KINDS)] for i in range(n)]
    return [
        Event(time_s=start_s + 10 * i, kind=k, severity=DEFAULT_SEVERITY[k], config_hash="c0ffee", indicators={"i4_norm": 0.2 + i / 1000},
              details={"load": "full", "window_end_s": start_s + 10 * i})  # fmt: skip
        for i, k in enumerate(kinds)
    ]


def commit(store: EventStore, events: list[Event], publisher: OutboxPublisher | None = None) -> None:
    """As the monitor does: commit, then tell the sinks (the publisher's wake-up)."""
    for event in events:
        store.append([event])
        if publisher is not None:
            publisher.wake()


def stub_status(outbox: OutboxCounts, time_s: float) -> StatusMessage:
    return StatusMessage(
        wagon_id=WAGON, time_s=time_s, mode="normal", config_hash="c0ffee", window=None, counters={"windows": 1},
        outbox=OutboxStatus(**{k: getattr(outbox, k) for k in OutboxStatus.model_fields}),
    )  # fmt: skip


def settings(connection: ConnectionSettings, **overrides: object) -> PublisherSettings:
    base: dict[str, object] = dict(
        connection=connection, wagon_id=WAGON, topic_prefix="fleet/test", status_period_s=0.0, max_rate_msgs_per_s=1000.0,
        max_inflight=20, backoff_min_s=0.1, backoff_max_s=0.5, poll_s=0.05,
    )  # fmt: skip
    base.update(overrides)
    return PublisherSettings(**base)  # type: ignore[arg-type]


@contextmanager
def publishing(state_dir: Path, publisher_settings: PublisherSettings, status: bool = False) -> Iterator[OutboxPublisher]:
    publisher = OutboxPublisher(publisher_settings, state_dir, status_source=stub_status if status else None)
    publisher.start()
    try:
        yield publisher
    finally:
        publisher.stop()


@contextmanager
def listening(connection: ConnectionSettings, client_id: str = "back-office") -> Iterator[Listener]:
    listener = Listener(connection, prefix="fleet/test", client_id=client_id, backoff_min_s=0.1, backoff_max_s=0.5)
    stop = threading.Event()
    errors: list[BaseException] = []

    def run() -> None:
        try:
            listener.run(stop)
        except BaseException as exc:  # surfaced by the test below
            errors.append(exc)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    assert listener.subscribed.wait(DEADLINE_S), errors
    try:
        yield listener
    finally:
        stop.set()
        thread.join(5)
    assert not errors, errors


def assert_all_in_order(listener: Listener, committed: list[Event]) -> None:
    assert wait_until(lambda: len(listener.events) >= len(committed)), f"{len(listener.events)} of {len(committed)} arrived"
    kept = [m for m in listener.events if m.wagon_id == WAGON]
    assert [m.event_id for m in kept] == [e.event_id for e in committed]  # all, once each, in commit order
    assert [m.seq for m in kept] == sorted(m.seq for m in kept)


def mqtt_logs(logs: list[dict[str, object]], state: str) -> list[dict[str, object]]:
    return [entry for entry in logs if entry.get("event") == f"mqtt {state}"]


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
            assert wait_until(lambda: store.outbox_counts().pending_events == 0)  # every PUBACK recorded
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
        assert store.outbox_counts().pending_events == 25  # nothing is delivered, nothing is lost
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


def test_network_cut_mid_burst_loses_nothing_and_resends_what_was_unacknowledged(tmp_path: Path, broker: Broker) -> None:
    proxy = LinkProxy(broker.port)  # the wagon's link: cut abruptly, both ways, mid-burst
    try:
        store = EventStore(tmp_path / "state")
        committed = make_events(300)
        link = ConnectionSettings("127.0.0.1", proxy.port, keepalive_s=5, connect_timeout_s=2.0)
        with listening(plain(broker)) as listener, publishing(tmp_path / "state", settings(link, max_rate_msgs_per_s=300.0)) as publisher:
            commit(store, committed, publisher)
            assert wait_until(lambda: len(listener.events) >= 60)
            proxy.cut()
            assert wait_until(lambda: publisher.counters.connections_lost == 1)
            assert wait_until(lambda: publisher.counters.connect_failures >= 1)  # the link stays down a while
            assert len(listener.events) < len(committed), "the burst ended before the link was cut"
            proxy.restore()
            assert_all_in_order(listener, committed)
            assert wait_until(lambda: store.outbox_counts().pending_events == 0)
        assert publisher.counters.published >= len(committed)  # what was in flight at the cut went again
    finally:
        proxy.close()


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
        from tests.daemon.test_mqtt import make_events, WAGON
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
        repo = Path(__file__).resolve().parents[2]
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
        pending_after_kill = store.outbox_counts().pending_events
        assert 0 < pending_after_kill < len(committed)
        with publishing(state_dir, settings(plain(broker))):  # the daemon restarted
            assert_all_in_order(listener, committed)
            assert wait_until(lambda: listener.states.get(WAGON) == "online")


def test_outbox_full_drops_the_oldest_status_first_and_keeps_every_event(tmp_path: Path, broker: Broker) -> None:
    with listening(plain(broker)):
        pass
    broker.kill(signal.SIGTERM)
    store = EventStore(tmp_path / "state")
    committed = make_events(8)
    bound = 20
    low = settings(plain(broker), outbox_max_messages=bound, status_period_s=0.02, backoff_min_s=0.2, backoff_max_s=0.2)
    with publishing(tmp_path / "state", low, status=True) as publisher:
        commit(store, committed, publisher)
        assert wait_until(lambda: publisher.counters.dropped_status >= 30)
        counts = store.outbox_counts()
        assert counts.pending_events == 8 and counts.dropped_events == 0  # the events all wait
        assert counts.pending <= bound + 1  # the bound, give or take the status queued since the last trim
        dropped_before = publisher.counters.dropped_status
        broker.start()
        with listening(plain(broker)) as listener:
            assert_all_in_order(listener, committed)
            # The back office learns how many were dropped from a later status.
            assert wait_until(lambda: any(s.outbox.dropped_status >= dropped_before for s in listener.statuses))
            queued_times = [s.time_s for s in listener.statuses]
    assert queued_times == sorted(queued_times)  # oldest first
    assert len(queued_times) >= bound - len(committed)  # what the bound left of the outage's status
    assert publisher.counters.dropped_events == 0


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
        assert store.outbox_counts().pending_events == 5
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
            assert publisher.is_alive() and store.outbox_counts().pending_events == 5
            refused = mqtt_logs(logs, "failing")
            assert len(refused) == 1 and refused[0]["log_level"] == "error"
            assert "refused the credentials" in str(refused[0]["reason"]) and "mqtt.password_file" in str(refused[0]["reason"])
            password_file.write_text("right-Pa55\n")  # rotated without a restart: read at each attempt
            with listening(ConnectionSettings("127.0.0.1", b.port, username_file=str(tmp_path / "user"), password_file=str(password_file))) as listener:
                assert_all_in_order(listener, committed)
        assert not any("Pa55" in repr(entry) for entry in logs)  # no password in the log, right or wrong
    finally:
        b.kill()


def test_the_token_bucket_allows_the_rate_and_a_burst_on_its_clock() -> None:
    bucket = TokenBucket(rate_per_s=8.0, burst=2.0, now_s=0.0)  # binary fractions: exact arithmetic
    assert [bucket.take(0.0) for _ in range(3)] == [True, True, False]  # the burst, then empty
    assert bucket.take(0.0625) is False and bucket.take(0.125) is True  # one token per 1/8 s
    sent = sum(bucket.take(1.0 + k / 64) for k in range(641))  # 10 s of asking 64 times a second
    assert sent == 2 + 80  # the refilled burst (capped), then 8 per second


def test_the_backoff_doubles_up_to_its_maximum_with_jitter_and_resets() -> None:
    import random

    backoff = Backoff(1.0, 8.0, random.Random("w"))
    delays = [backoff.next_delay_s() for _ in range(6)]
    for delay, ceiling in zip(delays, [1, 2, 4, 8, 8, 8], strict=True):
        assert ceiling / 2 <= delay <= ceiling
    backoff.reset()
    assert backoff.next_delay_s() <= 1.0


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
    path = write_config(tmp_path)  # the service test's: 6 s windows, a coupled bogie alarms quickly
    path.write_text(path.read_text() + textwrap.dedent(f"""
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
            service.flags.reload.set()
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
    assert str(DB.decode_message(alarm.arbitration_id, alarm.data)["Kind"]) == "CONFIRMED"


def test_a_reload_restarts_only_the_delivery_parts_whose_settings_changed(tmp_path: Path) -> None:
    base = f'[wagon]\nid = "{WAGON}"\n[state]\ndirectory = "{tmp_path}"\n'
    mqtt = '[mqtt]\nenabled = true\nhost = "127.0.0.1"\nport = 9\ntls = false\nreconnect_backoff_min_s = 5.0\n'
    config = parse_config(base + mqtt, "t")
    monitor = Monitor(monitor_settings(config), EventStore(tmp_path), [])
    delivery = Delivery(tmp_path)
    delivery.start(config, monitor)
    try:
        first = delivery.publisher
        assert first is not None and first.is_alive() and delivery.can_sink is None
        delivery.apply(parse_config(base + mqtt + "[processing]\nwindow_s = 120.0\nhop_s = 20.0\n", "t"))
        assert delivery.publisher is first  # nothing of its own changed
        delivery.apply(parse_config(base + mqtt.replace("port = 9", "port = 10"), "t"))
        assert delivery.publisher is not first and not first.is_alive()
        delivery.apply(parse_config(base, "t"))
        assert delivery.publisher is None
    finally:
        delivery.close()


def test_mqtt_without_a_wagon_id_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"mqtt.enabled needs the wagon's id in its topics: set \[wagon\] id"):
        parse_config("[mqtt]\nenabled = true\n", "site.toml")
    with pytest.raises(ConfigError, match=r"mqtt: tls_cert_file and tls_key_file go together"):
        parse_config('[mqtt]\ntls_cert_file = "/c.pem"\n', "site.toml")
    with pytest.raises(ConfigError, match=r"wagon.id: String should match pattern"):
        parse_config('[wagon]\nid = "31 80/4533"\n', "site.toml")


def test_the_mqtt_unit_is_bogiemon_service_plus_the_network_and_the_credentials() -> None:
    units = Path(__file__).resolve().parents[2] / "systemd"

    def settings_of(name: str) -> list[str]:
        return [line for line in (units / name).read_text().splitlines() if line and not line.startswith("#")]

    plain_unit, mqtt_unit = settings_of("bogiemon.service"), settings_of("bogiemon-mqtt.service")
    assert sorted(set(plain_unit) - set(mqtt_unit)) == [
        "Description=bogiemon suspension monitor (Y25 bogie primary suspension)",
        "RestrictAddressFamilies=AF_UNIX AF_CAN AF_NETLINK",
    ]
    assert sorted(set(mqtt_unit) - set(plain_unit)) == [
        "Conflicts=bogiemon.service",
        "Description=bogiemon suspension monitor (Y25 bogie primary suspension), alarms over MQTT",
        "IPAddressAllow=localhost 192.0.2.10",
        "LoadCredential=mqtt:/etc/bogiemon/mqtt",
        "RestrictAddressFamilies=AF_UNIX AF_CAN AF_NETLINK AF_INET AF_INET6",
    ]
    assert "IPAddressDeny=any" in mqtt_unit


def test_docs_mqtt_md_documents_every_field_of_both_schemas() -> None:
    from bogiemon.daemon.delivery.schema import EventMessage, LatestWindow

    doc = (Path(__file__).resolve().parents[2] / "docs" / "mqtt.md").read_text()
    names = [f"`{field.alias or name}`" for model in (EventMessage, StatusMessage) for name, field in model.model_fields.items()]
    names += [f"`window.{name}`" for name in LatestWindow.model_fields]
    names += [f"`outbox.{name}`" for name in OutboxStatus.model_fields]
    assert [n for n in names if n not in doc] == []
    assert '"bogiemon.event/1"' in doc and '"bogiemon.status/1"' in doc
