"""The default MQTT transport: a fresh paho-mqtt client (MQTT 5) per connection attempt.

TLS and credentials as connection.py reads them (at each attempt), the last will, the MQTT 5
session properties, and paho's last error line kept for the disconnect event: under TLS 1.3 an
SSL alert there is the only sign that the broker refused the client certificate.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import paho.mqtt.client as mqtt
from paho.mqtt.enums import CallbackAPIVersion
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties
from paho.mqtt.reasoncodes import ReasonCode

from bogiemon.daemon.delivery.connection import ConnectionSettings, read_secret, tls_context
from bogiemon.daemon.delivery.transport import MqttTransport, Publication, Reason, TransportEvents, Will


def new_client(settings: ConnectionSettings, client_id: str, will: Will | None = None) -> mqtt.Client:
    """A configured, unconnected client. Raises CredentialsError for an unusable file."""
    # manual_ack: a received message is acknowledged when the caller says so (the listener, once
    # the event is committed), not when the callback returns.
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5, manual_ack=True)
    client.connect_timeout = settings.connect_timeout_s
    # The caller bounds what is in flight; paho must neither queue nor hold anything back.
    client.max_inflight_messages_set(0)
    client.suppress_exceptions = False
    if settings.tls:
        client.tls_set_context(tls_context(settings))
    if settings.username_file:
        username = read_secret(settings.username_file, "MQTT username file")
        password = read_secret(settings.password_file, "MQTT password file") if settings.password_file else None
        client.username_pw_set(username, password)
    if will is not None:
        client.will_set(will.topic, will.payload, qos=1, retain=True)
    return client


def session_properties(expiry_s: int) -> Properties:
    """CONNECT properties asking the broker to keep the session (subscriptions, queued messages)."""
    properties = Properties(PacketTypes.CONNECT)
    properties.SessionExpiryInterval = expiry_s
    return properties


def _reason(code: ReasonCode) -> Reason:
    return Reason(code.value, str(code))


class PahoTransport(MqttTransport):
    """One paho client; its callbacks become the caller's TransportEvents."""

    def __init__(self, settings: ConnectionSettings, client_id: str, will: Will | None = None) -> None:
        self.settings = settings
        self.client = new_client(settings, client_id, will)
        self._socket_error: str | None = None  # paho's last error line
        self._qos_by_mid: dict[int, int] = {}  # received, not yet acknowledged

    def connect(self, events: TransportEvents, clean_start: bool, session_expiry_s: int | None = None) -> None:
        self._bind(events)
        properties = session_properties(session_expiry_s) if session_expiry_s is not None else None
        # Blocking: TCP and TLS (bounded by connect_timeout_s).
        self.client.connect(self.settings.host, self.settings.port, keepalive=self.settings.keepalive_s, clean_start=clean_start, properties=properties)

    def loop(self, timeout_s: float) -> str | None:
        rc = self.client.loop(timeout=timeout_s)  # network I/O; the callbacks run here
        return None if rc == mqtt.MQTT_ERR_SUCCESS else mqtt.error_string(rc)

    def publish(self, topic: str, payload: str | bytes, retain: bool = False) -> Publication:
        info = self.client.publish(topic, payload, qos=1, retain=retain)
        return Publication(info.mid, None if info.rc == mqtt.MQTT_ERR_SUCCESS else mqtt.error_string(info.rc))

    def subscribe(self, topics: Sequence[str]) -> None:
        self.client.subscribe([(topic, 1) for topic in topics])

    def acknowledge(self, mid: int) -> None:
        self.client.ack(mid, self._qos_by_mid.pop(mid, 0))

    def disconnect(self) -> None:
        try:
            self.client.disconnect()
        except Exception:  # noqa: BLE001 - a broken socket may fail to close cleanly; it is dropped anyway
            pass

    def _bind(self, events: TransportEvents) -> None:
        def on_connect(_c: mqtt.Client, _u: Any, _flags: Any, reason: ReasonCode, _p: Any) -> None:
            events.connected(_reason(reason))

        def on_disconnect(_c: mqtt.Client, _u: Any, _flags: Any, reason: ReasonCode, _p: Any) -> None:
            events.disconnected(_reason(reason), self._socket_error)

        def on_log(_c: mqtt.Client, _u: Any, level: int, text: str) -> None:
            if level == mqtt.MQTT_LOG_ERR:
                self._socket_error = text

        def on_publish(_c: mqtt.Client, _u: Any, mid: int, reason: ReasonCode, _p: Any) -> None:
            events.published(mid, _reason(reason))

        def on_subscribe(_c: mqtt.Client, _u: Any, _mid: int, reasons: list[ReasonCode], _p: Any) -> None:
            events.subscribed([_reason(r) for r in reasons])

        def on_message(_c: mqtt.Client, _u: Any, message: mqtt.MQTTMessage) -> None:
            self._qos_by_mid[message.mid] = message.qos
            events.message(message.topic, bytes(message.payload), message.mid)

        self.client.on_connect = on_connect
        self.client.on_disconnect = on_disconnect
        self.client.on_log = on_log
        self.client.on_publish = on_publish
        self.client.on_subscribe = on_subscribe
        self.client.on_message = on_message


def paho_transport(settings: ConnectionSettings, client_id: str, will: Will | None = None) -> MqttTransport:
    """The default TransportFactory."""
    return PahoTransport(settings, client_id, will)
