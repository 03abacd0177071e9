"""`bogiemon listen`: the back-office consumer as a real process against a real mosquitto."""

from __future__ import annotations

import json
import sqlite3
import subprocess
import sys
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from bogiemon.cli.main import main
from bogiemon.daemon.messages import EventMessage, dump
from tests.daemon.delivery.mqtt_broker import Broker, make_password_file
from tests.daemon.delivery.support import WAGON, make_events

BOGIEMON = str(Path(sys.executable).with_name("bogiemon"))


def publish(port: int, messages: list[tuple[str, str]]) -> None:
    """Publish with QoS 1 and wait for every PUBACK, as a wagon would."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="test-wagon", protocol=mqtt.MQTTv5)
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        for info in [client.publish(topic, payload, qos=1) for topic, payload in messages]:
            info.wait_for_publish(10)
    finally:
        client.disconnect()
        client.loop_stop()


def start_listen(port: int, *args: str) -> subprocess.Popen[str]:
    proc = subprocess.Popen([BOGIEMON, "listen", "--broker", f"127.0.0.1:{port}", "--prefix", "fleet/test", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    assert proc.stderr is not None
    line = proc.stderr.readline()  # after the SUBACK: what is published from now on reaches it
    assert "connected to" in line and "subscribed to fleet/test/+/events" in line, line + proc.stderr.read()
    return proc


def test_listen_prints_each_event_once_and_stores_it_across_runs(tmp_path: Path, broker: Broker) -> None:
    events = [EventMessage.from_event(WAGON, seq, e) for seq, e in enumerate(make_events(4), start=1)]
    topic = f"fleet/test/{WAGON}/events"
    store = tmp_path / "received.sqlite3"
    proc = start_listen(broker.port, "--json", "--store", str(store), "--count", "3", "--client-id", "t1")
    publish(broker.port, [(topic, dump(events[0])), (topic, dump(events[0])), (topic, "not json"), (topic, dump(events[1])), (topic, dump(events[2]))])
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    printed = [json.loads(line) for line in out.splitlines()]
    assert [p["event_id"] for p in printed] == [e.event_id for e in events[:3]]  # the copy is dropped
    assert printed[0]["schema"] == "bogiemon.event/2" and printed[0]["wagon_id"] == WAGON and printed[0]["seq"] == 1
    assert "not a valid message" in err
    # A second run with the same store: an event kept before is a duplicate still.
    proc = start_listen(broker.port, "--store", str(store), "--count", "1", "--client-id", "t2")
    publish(broker.port, [(topic, dump(events[1])), (topic, dump(events[3])), (f"fleet/test/{WAGON}/state", "online")])
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert out.splitlines()[0].startswith(f"{WAGON}  #4      ") and events[3].kind in out.splitlines()[0]
    rows = sqlite3.connect(store).execute("SELECT event_id FROM received ORDER BY n").fetchall()
    assert [r[0] for r in rows] == [e.event_id for e in events]


def test_listen_with_wrong_credentials_ends_with_one_line(tmp_path: Path, mosquitto: None) -> None:
    users = make_password_file(tmp_path / "passwords", "office", "right-Pa55")
    b = Broker(tmp_path / "broker", password_file=users).start()
    try:
        (tmp_path / "user").write_text("office\n")
        (tmp_path / "password").write_text("wrong-Pa55\n")
        (tmp_path / "password").chmod(0o600)  # private, as it should be: no warning
        proc = subprocess.run(
            [BOGIEMON, "listen", "--broker", f"127.0.0.1:{b.port}", "--username-file", str(tmp_path / "user"), "--password-file", str(tmp_path / "password"),
             "--allow-plaintext"],
            capture_output=True, text=True, timeout=20,
        )  # fmt: skip
    finally:
        b.kill()
    assert proc.returncode == 2
    assert proc.stderr.startswith("bogiemon: error: the broker refused the credentials (")  # mosquitto says "Not authorized"
    assert proc.stderr.endswith("): check --username-file and --password-file\n")
    assert "Pa55" not in proc.stderr + proc.stdout and "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    ("broker", "tls", "expected"),
    [("localhost", False, ("localhost", 1883)), ("localhost", True, ("localhost", 8883)), ("h:1884", True, ("h", 1884)),
     ("[::1]", False, ("::1", 1883)), ("[::1]:8884", False, ("::1", 8884)), ("::1", True, ("::1", 8883))],
)  # fmt: skip
def test_listen_defaults_the_port_to_mqtts_1883_or_8883_with_tls(broker: str, tls: bool, expected: tuple[str, int]) -> None:
    from bogiemon.cli.listen import parse_broker

    assert parse_broker(broker, tls) == expected


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--broker", "localhost:"], "--broker: expected HOST or HOST:PORT, e.g. localhost or localhost:8883, got 'localhost:'"),
        (["--broker", "h:1", "--tls-cert", "c.pem"], "--tls-cert and --tls-key go together"),
        (["--broker", "h:1", "--password-file", "p"], "--password-file needs --username-file"),
        (["--broker", "h:1", "--username-file", "/nonexistent/user"], "MQTT username file /nonexistent/user: cannot read it: No such file or directory"),
        (["--broker", "h:1", "--tls-ca", "/nonexistent/ca.pem"], "CA file /nonexistent/ca.pem: no such file"),
        (["--broker", "h:1", "--username-file", "u", "--password-file", "p"],
         "--password-file without TLS would send the password in clear: add --tls or --tls-ca (or --allow-plaintext, on a bench)"),
        (["--broker", "h:1", "--username-file", "/nonexistent/user", "--password-file", "p", "--allow-plaintext"],
         "MQTT username file /nonexistent/user: cannot read it: No such file or directory"),
        (["--broker", "h:1", "--username-file", "/nonexistent/user", "--password-file", "p", "--tls"],
         "MQTT username file /nonexistent/user: cannot read it: No such file or directory"),
    ],
)  # fmt: skip
def test_listen_argument_errors_are_one_line(args: list[str], expected: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["listen", *args]) == 2
    assert capsys.readouterr().err == f"bogiemon: error: {expected}\n"


@pytest.mark.parametrize(("mode", "warning"), [(0o644, "its group and others (mode 0644)"), (0o640, "its group (mode 0640)"), (0o600, None)])
def test_listen_warns_when_the_password_file_is_readable_by_others(tmp_path: Path, mode: int, warning: str | None, capsys: pytest.CaptureFixture[str]) -> None:
    password = tmp_path / "password"
    password.write_text("Pa55\n")
    password.chmod(mode)
    assert main(["listen", "--broker", "h:1", "--username-file", "/nonexistent/user", "--password-file", str(password), "--tls"]) == 2
    said = [] if warning is None else [
        f"bogiemon listen: warning: {password} is readable by {warning}: chmod 600 {password}, or hand it over with systemd's LoadCredential="
    ]  # fmt: skip
    assert capsys.readouterr().err.splitlines() == [*said, "bogiemon: error: MQTT username file /nonexistent/user: cannot read it: No such file or directory"]


def test_listen_skips_a_poison_message_once_and_it_is_not_delivered_again_after_a_restart(tmp_path: Path, broker: Broker) -> None:
    events = [EventMessage.from_event(WAGON, seq, e) for seq, e in enumerate(make_events(2), start=1)]
    topic = f"fleet/test/{WAGON}/events"
    poison = {**json.loads(dump(events[0])), "event_id": "poison", "time_s": 1e300}  # crashed the listener at every restart (issue 17)
    store = tmp_path / "received.sqlite3"
    proc = start_listen(broker.port, "--store", str(store), "--count", "1", "--client-id", "office")
    publish(broker.port, [(topic, json.dumps(poison)), (topic, dump(events[0]))])
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert err.splitlines() == [
        f"bogiemon listen: {WAGON}: not a valid message on {topic}: time_s: Input should be less than or equal to 10000000000",
        "bogiemon listen: events kept: 1, copies dropped: 0, invalid messages skipped: 1",
    ]
    proc = start_listen(broker.port, "--store", str(store), "--count", "1", "--client-id", "office")  # the same session
    publish(broker.port, [(topic, dump(events[1]))])
    out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert err.splitlines() == ["bogiemon listen: events kept: 1, copies dropped: 0, invalid messages skipped: 0"]  # nothing came again
    assert out.splitlines()[0].startswith(f"{WAGON}  #2      ")
    rows = sqlite3.connect(store).execute("SELECT event_id FROM received ORDER BY n").fetchall()
    assert [r[0] for r in rows] == [e.event_id for e in events]
