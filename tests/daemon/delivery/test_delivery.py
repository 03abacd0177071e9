"""The Delivery sink, its configuration, its systemd unit and its documentation (no broker needed)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from bogiemon.daemon.config import ConfigError, parse_config
from bogiemon.daemon.delivery import Delivery
from bogiemon.daemon.messages import OutboxStatus, StatusMessage
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.startup import Snapshot
from bogiemon.daemon.store import EventStore
from tests.daemon.delivery.support import WAGON


def test_a_reload_restarts_only_the_delivery_parts_whose_settings_changed(tmp_path: Path) -> None:
    base = f'[wagon]\nid = "{WAGON}"\n[state]\ndirectory = "{tmp_path}"\n'
    mqtt = '[mqtt]\nenabled = true\nhost = "127.0.0.1"\nport = 9\ntls = false\nreconnect_backoff_min_s = 5.0\n'
    config = parse_config(base + mqtt, "t")
    monitor = Monitor(config.monitor_settings(), EventStore(tmp_path), [])
    delivery = Delivery(tmp_path)
    delivery.start(config, monitor)
    running = Snapshot.of(config)

    def reload(text: str) -> None:
        nonlocal running
        new = Snapshot.of(parse_config(text, "t"))
        delivery.apply(new.config, running.changed(new))
        running = new

    try:
        first = delivery.publisher
        assert first is not None and first.is_alive() and delivery.can_sink is None
        reload(base + mqtt + "[processing]\nwindow_s = 120.0\nhop_s = 20.0\n[decision]\nmethod = \"thresholds\"\n")
        assert delivery.publisher is first  # nothing of its own changed
        reload(base + mqtt.replace("port = 9", "port = 10"))
        assert delivery.publisher is not first and not first.is_alive()
        reload(base)
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
    units = Path(__file__).resolve().parents[3] / "systemd"

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
    from bogiemon.daemon.messages import EventMessage, LatestWindow
    from bogiemon.judgement.diagnosis import Diagnosis
    from bogiemon.judgement.events import DETAILS_TYPES, RunningContext, SisterDetails

    doc = (Path(__file__).resolve().parents[3] / "docs" / "mqtt.md").read_text()
    names = [f"`{field.alias or name}`" for model in (EventMessage, StatusMessage) for name, field in model.model_fields.items()]
    names += [f"`window.{name}`" for name in LatestWindow.model_fields]
    names += [f"`outbox.{name}`" for name in OutboxStatus.model_fields]
    # The details of every kind: the records' fields are their JSON names (RunningContext's are
    # written beside the others, not under `running`).
    names += [f"`{f.name}`" for record in (*DETAILS_TYPES.values(), RunningContext, Diagnosis, SisterDetails) for f in dataclasses.fields(record) if f.name != "running"]
    assert [n for n in names if n not in doc] == []
    assert '"bogiemon.event/2"' in doc and '"bogiemon.event/1"' in doc and '"bogiemon.status/1"' in doc
