"""Alarm delivery: the MQTT outbox publisher and the CAN alarm frames, as the service runs them.

`Delivery` is one event sink in the monitor's list; it starts, reconfigures and stops the parts
the config enables ([mqtt], [can_alarms], [wagon]), each with its own thread, so the monitor's
processing thread only commits and queues. Events reach MQTT through the event store (the outbox),
so the sink's publish() merely wakes the publisher.
"""

from __future__ import annotations

from collections.abc import Set as AbstractSet
from pathlib import Path

from bogiemon.daemon.delivery.can_alarms import CanAlarmSink, Heartbeat, load_alarm_codecs
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.delivery.connection import ConnectionSettings
from bogiemon.daemon.delivery.publisher import OutboxPublisher, PublisherSettings
from bogiemon.daemon.delivery.status import status_from_monitor
from bogiemon.daemon.messages import StatusMessage
from bogiemon.judgement.events import Event
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.sinks import EventSink
from bogiemon.daemon.outbox import OutboxCounts
from bogiemon.drivers.candb import DbcError


def publisher_settings(config: BogiemonConfig) -> PublisherSettings:
    m = config.mqtt
    return PublisherSettings(
        connection=ConnectionSettings(
            host=m.host, port=m.port, tls=m.tls, ca_file=m.tls_ca_file, cert_file=m.tls_cert_file, key_file=m.tls_key_file,
            username_file=m.username_file, password_file=m.password_file, keepalive_s=m.keepalive_s,
            connect_timeout_s=m.connect_timeout_s,
        ),
        wagon_id=config.wagon.id,
        topic_prefix=m.topic_prefix,
        client_id=m.client_id,
        status_period_s=m.status_period_s,
        max_rate_msgs_per_s=m.max_rate_msgs_per_s,
        max_inflight=m.max_inflight,
        outbox_max_messages=m.outbox_max_messages,
        backoff_min_s=m.reconnect_backoff_min_s,
        backoff_max_s=m.reconnect_backoff_max_s,
    )  # fmt: skip


class Delivery(EventSink):
    """The sink the service adds to the monitor: start(config, monitor), apply(config) on reload, close()."""

    def __init__(self, state_dir: str | Path) -> None:
        self.state_dir = Path(state_dir)
        self.publisher: OutboxPublisher | None = None
        self.can_sink: CanAlarmSink | None = None
        self._monitor: Monitor | None = None
        self._config: BogiemonConfig | None = None
        self._log = get_logger(component="delivery")

    def start(self, config: BogiemonConfig, monitor: Monitor) -> None:
        """Start what config enables. Raises DbcError for an unusable [can_alarms] DBC (a user error)."""
        self._monitor = monitor
        self._config = config
        self._restart_can(config)  # first: a bad DBC stops the start before any thread runs
        self._restart_publisher(config)

    def apply(self, config: BogiemonConfig, changed: AbstractSet[str]) -> None:
        """On reload: restart the parts whose sections changed (`changed`, daemon/startup.py
        Snapshot.changed: their settings or a file they name); the others keep running.

        A [can_alarms] DBC that cannot be used is logged and the running CAN alarms are kept.
        """
        assert self._config is not None, "start() first"
        self._config = config
        if changed & {"mqtt", "wagon"}:
            self._restart_publisher(config)
        if "can_alarms" in changed:
            try:
                self._restart_can(config)
            except DbcError as exc:
                self._log.error("reload: can alarms keep their previous settings", reason=str(exc))

    def publish(self, event: Event) -> None:
        can_sink, publisher = self.can_sink, self.publisher
        if can_sink is not None:
            can_sink.publish(event)
        if publisher is not None:
            publisher.wake()  # the event is already in the store: the outbox

    def close(self) -> None:
        publisher, can_sink = self.publisher, self.can_sink
        self.publisher = self.can_sink = None
        if publisher is not None:
            publisher.stop()
        if can_sink is not None:
            can_sink.close()

    def _restart_publisher(self, config: BogiemonConfig) -> None:
        old, self.publisher = self.publisher, None
        if old is not None:
            old.stop()
        if not config.mqtt.enabled:
            return
        monitor, wagon_id = self._monitor, config.wagon.id
        assert monitor is not None

        def status(outbox: OutboxCounts, time_s: float) -> StatusMessage:
            return status_from_monitor(monitor, wagon_id, time_s, outbox)

        publisher = OutboxPublisher(publisher_settings(config), self.state_dir, status_source=status)
        publisher.start()
        self.publisher = publisher
        self._log.info("mqtt delivery started", broker=f"{config.mqtt.host}:{config.mqtt.port}", wagon_id=wagon_id)

    def _restart_can(self, config: BogiemonConfig) -> None:
        c = config.can_alarms
        codecs = load_alarm_codecs(c.dbc_path or None) if c.enabled else None  # before the old sink goes
        old, self.can_sink = self.can_sink, None
        if old is not None:
            old.close()
        if codecs is None:
            return
        sink = CanAlarmSink(codecs, c.interface, c.channel, c.heartbeat_period_s, self._heartbeat)
        sink.start()
        self.can_sink = sink
        self._log.info("can alarms started", interface=c.interface, channel=c.channel)

    def _heartbeat(self) -> Heartbeat:
        monitor = self._monitor
        assert monitor is not None
        report = monitor.latest
        publisher = self.publisher
        outbox = publisher.outbox if publisher is not None else None
        return Heartbeat(
            mode=monitor.mode,
            has_window=report is not None,
            sensors_ok=report.health.sensors_ok if report is not None else True,
            judged=report is not None and report.judgement is not None,
            gate=report.health.gate.value if report is not None and report.health.gate is not None else None,
            mqtt_link="disabled" if publisher is None else ("up" if publisher.connected else "down"),
            windows=monitor.counters.windows,
            events=monitor.counters.events,
            outbox_pending=outbox.pending if outbox is not None else 0,
            judged_windows=monitor.counters.judged,
            not_judged=monitor.coverage.reported,
            unjudged_running_s=monitor.coverage.unjudged_running_s,
        )
