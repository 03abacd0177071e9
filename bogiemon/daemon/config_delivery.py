"""What leaves the gateway: the events over MQTT ([mqtt]), the alarms as CAN frames ([can_alarms])
and the raw samples for the back office ([recorder])."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from bogiemon.daemon.config_sections import Section
from bogiemon.drivers.recording import NEEDS_PYARROW, RecordingFormat, parquet_available

MIB = 1 << 20


class MqttConfig(Section):
    """Alarm delivery to the back office (docs/mqtt.md): events, and a periodic status, as JSON over
    MQTT with QoS 1, to {topic_prefix}/{wagon id}/events, /status and /state. The event store is the
    outbox: an event counts as delivered only after the broker's PUBACK, so nothing is lost while the
    broker or the network is away (duplicates after a crash carry the same event_id)."""

    enabled: bool = Field(False, description="Publish to the broker (needs [wagon] id). Run the daemon with systemd/bogiemon-mqtt.service.")
    host: str = Field("localhost", min_length=1, description="The broker's host name or address.")
    port: int = Field(8883, ge=1, le=65535, description="The broker's port (8883 is MQTT over TLS, 1883 plain MQTT).")
    topic_prefix: str = Field("bogiemon", pattern=r"^[A-Za-z0-9._-]+(/[A-Za-z0-9._-]+)*$", description=(
        "The first levels of every topic (\"fleet/bogies\" gives fleet/bogies/{wagon id}/events)."
    ))  # fmt: skip
    client_id: str = Field("", pattern=r"^[A-Za-z0-9._-]*$", max_length=64, description="The MQTT client id; empty: \"bogiemon-{wagon id}\".")
    tls: bool = Field(True, description="TLS to the broker, its certificate checked against tls_ca_file. false only on a bench.")
    tls_ca_file: str = Field("", description="The CA certificate(s) (PEM) the broker's certificate must chain to; empty: the system's.")
    tls_cert_file: str = Field("", description="This wagon's client certificate (PEM); empty: none. Needs tls_key_file.")
    tls_key_file: str = Field("", description=(
        "The client certificate's private key (PEM, not encrypted: protect the file, or use "
        "LoadCredential= as systemd/bogiemon-mqtt.service does)."
    ))  # fmt: skip
    username_file: str = Field("", description="A file holding the MQTT user name (one line); empty: connect without credentials.")
    password_file: str = Field("", description=(
        "A file holding the MQTT password (one line); never put it on a command line or in this file. "
        "Needs username_file, and tls = true (or allow_plaintext). A credential or key file that its "
        "group or others can read is logged as a warning at every load (chmod 600, or LoadCredential=)."
    ))  # fmt: skip
    # A password over plain MQTT crosses the network readable by anyone on the path: only when
    # the config says so (a bench).
    allow_plaintext: bool = Field(False, description="true lets a password go with tls = false, in clear over the network: a bench only.")
    keepalive_s: int = Field(30, ge=5, le=3600, description="Seconds between keep-alive pings; a dead link is noticed within about twice this.")
    connect_timeout_s: float = Field(10.0, gt=0, le=120, description="Seconds a connection attempt (TCP, TLS and the broker's CONNACK) may take.")
    status_period_s: float = Field(60.0, ge=0, le=86400, description="Seconds between status messages (latest indicators, sensor health, counters); 0: none.")
    max_rate_msgs_per_s: float = Field(10.0, ge=0.01, le=10_000, description="Messages per second at most, also while the backlog drains after an outage.")
    max_inflight: int = Field(10, ge=1, le=1000, description="Messages sent and not yet acknowledged (PUBACK) at most.")
    outbox_max_messages: int = Field(10000, ge=10, le=10_000_000, description=(
        "Undelivered messages the outbox keeps at most: over it, the oldest status messages are dropped "
        "first, then the oldest events that are not alarms; CONFIRMED and CLEARED are never dropped."
    ))  # fmt: skip
    reconnect_backoff_min_s: float = Field(1.0, ge=0.01, le=3600, description=(
        "After a failed or lost connection the next attempt waits this many seconds; each failure "
        "doubles the wait, up to reconnect_backoff_max_s."
    ))  # fmt: skip
    reconnect_backoff_max_s: float = Field(60.0, ge=0.01, le=3600, description="The longest wait between connection attempts, in seconds (at least reconnect_backoff_min_s).")

    @model_validator(mode="after")
    def _consistent(self) -> MqttConfig:
        if bool(self.tls_cert_file) != bool(self.tls_key_file):
            raise ValueError("tls_cert_file and tls_key_file go together: set both for a client certificate, or neither")
        if self.tls_cert_file and not self.tls:
            raise ValueError("a client certificate (tls_cert_file) needs tls = true")
        if self.password_file and not self.username_file:
            raise ValueError("password_file needs username_file")
        if self.password_file and not self.tls and not self.allow_plaintext:
            raise ValueError(
                "password_file with tls = false would send the password in clear: set tls = true "
                "(and the broker's TLS port), or allow_plaintext = true on a bench"
            )
        if self.reconnect_backoff_min_s > self.reconnect_backoff_max_s:
            raise ValueError(
                f"reconnect_backoff_min_s ({self.reconnect_backoff_min_s}) must not exceed "
                f"reconnect_backoff_max_s ({self.reconnect_backoff_max_s})"
            )
        return self


class CanAlarmsConfig(Section):
    """CONFIRMED and CLEARED alarms, and a heartbeat, as frames on a CAN bus for the wagon's telematics
    unit: messages BogieAlarm and BogieHeartbeat of the DBC (docs/mqtt.md)."""

    enabled: bool = Field(False, description="Send the frames.")
    interface: Literal["socketcan", "virtual"] = Field("socketcan", description="The python-can interface: \"socketcan\" on the gateway, \"virtual\" for tests and demos.")
    channel: str = Field("can0", min_length=1, description="The network interface (socketcan) or channel name (virtual).")
    dbc_path: str = Field("", description="The DBC file with BogieAlarm and BogieHeartbeat; empty: the shipped config/bogiemon.dbc.")
    heartbeat_period_s: float = Field(1.0, ge=0, le=3600, description="Seconds between heartbeats; 0: none.")


class RecorderConfig(Section):
    """The raw samples for the back office (docs/recorder.md): around every SUSPECTED and CONFIRMED, a
    snapshot that `bogiemon replay` turns into the same alarm, and optionally a periodic sample of
    healthy running; recordings of time_s,a1,a2,a3 (Unix seconds) named
    `<UTC start YYYYMMDDTHHMMSSZ>_<suspected|confirmed|periodic>.csv.gz` (or .parquet), for an uploader."""

    enabled: bool = Field(False, description="Keep and write the recordings (a ring of the last few minutes of samples in memory).")
    directory: Path = Field(Path("/var/lib/bogiemon/recordings"), description=(
        "The folder of the recordings (created if missing). Only files of the recorder's names count "
        "towards max_total_bytes and are ever deleted; names beginning with '.' are being written."
    ))  # fmt: skip
    # The ring that holds the lead-in never takes more than 64 MiB.
    lead_in_s: float = Field(60.0, ge=0, le=600, description=(
        "Seconds of samples before the windows that confirm an alarm (its last decision.confirm_n "
        "judged windows), rounded up to whole hops; at most 600."
    ))  # fmt: skip
    periodic_every_h: float = Field(0.0, ge=0, le=8760, description="Every this many hours of running, a periodic recording of the next periodic_s seconds; 0: none.")
    # One periodic recording is held in memory until written: an hour at 500 Hz is 21 MiB.
    periodic_s: float = Field(300.0, gt=0, le=3600, description="The length of a periodic recording in seconds, at most 3600 and at most the period.")
    max_total_bytes: int = Field(512 * MIB, ge=MIB, le=2**50, description=(
        "The recordings' total size in bytes at most (512 MiB): after each write the oldest are deleted "
        "until it fits; at least 1 MiB. Whatever this says, the recordings never take the event store's "
        "reserve: 19.6 MiB free on their file system, 29.4 MiB with MQTT's default outbox (1 KiB more a "
        "message of mqtt.outbox_max_messages). Before a write the oldest are deleted to keep it free; "
        "with no room above it nothing is recorded (docs/recorder.md, \"The reserve\")."
    ))  # fmt: skip
    format: RecordingFormat = Field(RecordingFormat.CSV_GZ, description=(
        "\"csv.gz\" (gzip CSV, the standard library's: the gateway loads nothing more) or \"parquet\" "
        "(columnar, half the size, read without parsing text; the daemon then loads pyarrow, about 40 MB "
        "more memory, which a gateway installed from the bundle lacks: `pip install 'bogiemon[recordings]'`). "
        "Every command that reads recordings reads both (Parquet with pyarrow)."
    ))  # fmt: skip

    @model_validator(mode="after")
    def _format_installed(self) -> RecorderConfig:
        if self.enabled and self.format is RecordingFormat.PARQUET and not parquet_available():
            raise ValueError(f"format = \"parquet\" {NEEDS_PYARROW}")
        return self

    @model_validator(mode="after")
    def _periodic_fits(self) -> RecorderConfig:
        if self.periodic_every_h > 0 and self.periodic_s > self.periodic_every_h * 3600:
            raise ValueError(
                f"periodic_s ({self.periodic_s:g}) must not exceed the period periodic_every_h "
                f"({self.periodic_every_h:g} h = {self.periodic_every_h * 3600:g} s)"
            )
        return self
