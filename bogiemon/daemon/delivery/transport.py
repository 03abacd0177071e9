"""The seam between MQTT delivery and the MQTT client: what the publisher and the listener use.

One transport is one connection attempt (a fresh one per attempt, so nothing pending lives in a
client's memory). The caller's thread drives it: connect(), then loop() repeatedly, which does
the I/O and calls the caller's TransportEvents from that same thread. Two implementations:
paho_transport (the default: paho-mqtt, TLS, credentials) and memory_transport (an in-process
broker for tests and the demo, which can also fail on demand). The models are httpx's
`BaseTransport` and python-can's `BusABC`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from bogiemon.daemon.delivery.connection import SUCCESS, ConnectionSettings, Reason

__all__ = ["SUCCESS", "Reason"]  # the reason codes belong to the connection; transports name them from here too




@dataclass(frozen=True)
class Will:
    """The last will: published by the broker (QoS 1, retained) when the link dies without a DISCONNECT."""

    topic: str
    payload: str


@dataclass(frozen=True)
class Publication:
    """What publish() did: the message id its PUBACK will carry, or why it could not be sent."""

    mid: int
    error: str | None = None  # e.g. "The client is not currently connected."


class TransportEvents:
    """What a transport reports, each from inside loop(); the defaults ignore it.

    connected: the CONNACK (a failure reason is a refusal). disconnected: the link ended without
    the caller's disconnect() (detail: the client's last error line, e.g. an SSL alert, if any).
    published: the PUBACK of a message. subscribed: the SUBACK, one reason per topic. message: a
    message of a subscription, to be acknowledged with acknowledge(mid) once it is safe.
    """

    def connected(self, reason: Reason) -> None:
        pass

    def disconnected(self, reason: Reason, detail: str | None) -> None:
        pass

    def published(self, mid: int, reason: Reason) -> None:
        pass

    def subscribed(self, reasons: Sequence[Reason]) -> None:
        pass

    def message(self, topic: str, payload: bytes, mid: int) -> None:
        pass


class MqttTransport(ABC):
    """One MQTT 5 connection; every message goes with QoS 1."""

    @abstractmethod
    def connect(self, events: TransportEvents, clean_start: bool, session_expiry_s: int | None = None) -> None:
        """Open the link and send CONNECT; the CONNACK comes as events.connected in loop().

        Raises OSError when the link cannot be opened (refused, unreachable, TLS). session_expiry_s
        asks the broker to keep the session that long after the link ends (None: not at all).
        """

    @abstractmethod
    def loop(self, timeout_s: float) -> str | None:
        """Do the I/O, waiting at most timeout_s, and report the events; returns why the link failed, if it did."""

    @abstractmethod
    def publish(self, topic: str, payload: str | bytes, retain: bool = False) -> Publication:
        """Send a message (QoS 1); its PUBACK comes as events.published with the same mid."""

    @abstractmethod
    def subscribe(self, topics: Sequence[str]) -> None:
        """Subscribe with QoS 1; the SUBACK comes as events.subscribed."""

    @abstractmethod
    def acknowledge(self, mid: int) -> None:
        """Send the PUBACK for a received message: the broker may forget it from now on."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the link cleanly (the will is not published); never raises."""


# (connection settings, client id, last will or None) -> an unconnected transport. Raises
# CredentialsError (connection.py) for a TLS or credentials file that cannot be used.
TransportFactory = Callable[[ConnectionSettings, str, Will | None], MqttTransport]
