"""Alarm frames on CAN: sent on a real python-can virtual bus, decoded back with cantools."""

from __future__ import annotations

import dataclasses
import itertools
import time
from typing import Any
from pathlib import Path

import can
import cantools
import pytest
import structlog.testing
from can.interfaces.virtual import VirtualBus

from bogiemon.daemon.delivery.can_alarms import (
    CanAlarmSink,
    Heartbeat,
    alarm_payload,
    coverage_payload,
    diagnosis_payload,
    heartbeat_payload,
    load_alarm_codecs,
    worst_indicator,
)
from bogiemon.detection.kinematics import Corner
from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.judgement.events import DecisionDetails, Event, EventKind, Trigger
from bogiemon.judgement.rules import Threshold
from bogiemon.drivers.candb import DbcError, load_layout, shipped_dbc_text
from bogiemon.drivers.player import PlayError, open_player_bus
from tests.judgement.event_examples import event_of

DB = cantools.database.load_string(shipped_dbc_text(), database_format="dbc")
THRESHOLDS = {"i2_norm": Threshold(warning=0.02, alarm=0.03), "i4_norm": Threshold(warning=0.1, alarm=0.15)}
_channels = itertools.count()


def decode(frame_id: int, data: bytes | bytearray) -> dict[str, Any]:
    """A frame's signals as cantools decodes them (the DBC has no container frames)."""
    assert isinstance(DB, cantools.database.can.Database)
    decoded = DB.decode_message(frame_id, bytes(data))
    assert isinstance(decoded, dict)
    return decoded


def channel() -> str:
    return f"bogiemon-alarms-test-{next(_channels)}"


def alarm_event(kind: EventKind, i4_norm: float = 0.2, i2_norm: float = 0.031, **details: Any) -> Event:
    """An event with these values fired; a suspension event's against THRESHOLDS (and these details besides)."""
    event = event_of(kind, 1.7e9, {"i2_norm": i2_norm, "i4_norm": i4_norm})
    if not isinstance(event.details, DecisionDetails):
        return event
    return dataclasses.replace(event, details=dataclasses.replace(event.details, thresholds=THRESHOLDS, **details))


def receive(bus: can.BusABC, frame_id: int | tuple[int, ...], n: int, timeout_s: float = 10.0) -> list[can.Message]:
    """The next n frames of these identifiers (others are passed over), in the order they came."""
    wanted = frame_id if isinstance(frame_id, tuple) else (frame_id,)
    got: list[can.Message] = []
    end_s = time.monotonic() + timeout_s
    while len(got) < n and time.monotonic() < end_s:
        message = bus.recv(0.1)
        if message is not None and message.arbitration_id in wanted:
            got.append(message)
    return got


def idle_heartbeat(mode: str = "normal") -> Heartbeat:
    return Heartbeat(mode=mode, has_window=True, sensors_ok=True, judged=True, gate=None, mqtt_link="up", windows=70_000, events=3, outbox_pending=300)


def test_the_shipped_dbc_keeps_the_sensor_layouts_and_defines_the_alarm_frames() -> None:
    assert load_layout(None, "hub").hub is not None and len(load_layout(None, "per-node").nodes) == 3
    codecs = load_alarm_codecs()
    assert (codecs.alarm.frame_id, codecs.alarm.length, codecs.heartbeat.frame_id, codecs.heartbeat.length) == (0x300, 8, 0x301, 8)
    assert DB.get_message_by_name("BogieAlarm").senders == ["Gateway"]


def test_a_dbc_without_the_alarm_frames_is_named(tmp_path: Path) -> None:
    old = tmp_path / "old.dbc"
    old.write_text('VERSION ""\nNS_ :\nBS_:\nBU_: Gateway\nBO_ 769 BogieHeartbeat: 8 Gateway\n SG_ Counter : 0|8@1+ (1,0) [0|255] "" Vector__XXX\n')
    with pytest.raises(DbcError, match=r"old.dbc: no message 'BogieAlarm'"):
        load_alarm_codecs(old)


def test_the_indicator_furthest_beyond_its_alarm_level_is_the_one_sent() -> None:
    assert worst_indicator(alarm_event(EventKind.CONFIRMED, i4_norm=0.2, i2_norm=0.031)) == ("i4_norm", 0.2)  # 1.33 > 1.03
    assert worst_indicator(alarm_event(EventKind.CONFIRMED, i4_norm=0.16, i2_norm=0.06)) == ("i2_norm", 0.06)  # 2.0 > 1.07
    assert worst_indicator(event_of(EventKind.CLEARED, 0.0, {})) == (None, 0.0)
    assert worst_indicator(event_of(EventKind.SENSOR_FAULT, 0.0, {"i1": -3.0})) == ("i1", -3.0)  # no limits: the largest value


def test_encoded_payloads_decode_with_cantools_to_what_was_meant() -> None:
    codecs = load_alarm_codecs()
    event = alarm_event(EventKind.CLEARED, i4_norm=-7.5)  # beyond the Value signal's range: clipped
    decoded = decode(0x300, alarm_payload(codecs, event, counter=258))
    assert decoded["Counter"] == 2 and str(decoded["Kind"]) == "CLEARED" and str(decoded["Severity"]) == "info"
    assert str(decoded["Indicator"]) == "i4_norm" and decoded["Fired"] == 2
    assert decoded["Value"] == pytest.approx(-3.2768) and decoded["EventRef"] == int(event.event_id[:6], 16)
    beat = decode(0x301, heartbeat_payload(codecs, idle_heartbeat("confirmed"), counter=7, alarm_counter=300))
    assert beat == {"Counter": 7, "Mode": beat["Mode"], "SensorsOk": 1, "Judged": 1, "Gate": beat["Gate"], "MqttLink": beat["MqttLink"],
                    "AlarmCounter": 300 % 256, "Windows": 70_000 % 65536, "Events": 3, "OutboxPending": 255}  # fmt: skip
    assert (str(beat["Mode"]), str(beat["Gate"]), str(beat["MqttLink"])) == ("confirmed", "none", "up")


def test_confirmed_and_cleared_go_on_the_bus_and_nothing_else_does() -> None:
    name = channel()
    receiver = VirtualBus(channel=name, receive_own_messages=False)
    sink = CanAlarmSink(load_alarm_codecs(), "virtual", name, heartbeat_period_s=0.0)
    sink.start()
    try:
        events = [alarm_event(k) for k in (EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.SENSOR_FAULT, EventKind.CLEARED, EventKind.SENSOR_CLEARED)]
        for event in events:
            sink.publish(event)
        frames = receive(receiver, (0x300, 0x302), 3)
        assert receive(receiver, (0x300, 0x302), 1, timeout_s=0.3) == []  # exactly these
        (diagnosis,) = [f for f in frames if f.arbitration_id == 0x302]  # the CONFIRMED's diagnosis, after it
        assert [f.arbitration_id for f in frames] == [0x300, 0x302, 0x300]
        frames = [f for f in frames if f.arbitration_id == 0x300]
    finally:
        sink.close()
        receiver.shutdown()
    decoded = [decode(f.arbitration_id, f.data) for f in frames]
    assert [(str(d["Kind"]), d["Counter"], str(d["Severity"])) for d in decoded] == [("CONFIRMED", 1, "alarm"), ("CLEARED", 2, "info")]
    assert [d["EventRef"] for d in decoded] == [int(events[1].event_id[:6], 16), int(events[3].event_id[:6], 16)]
    assert all(not f.is_extended_id and f.dlc == 8 for f in frames)
    assert decode(0x302, diagnosis.data)["Counter"] == 1  # the alarm frame it belongs to


def test_the_heartbeat_repeats_the_state_and_the_last_alarm_counter() -> None:
    name = channel()
    receiver = VirtualBus(channel=name, receive_own_messages=False)
    mode = ["normal"]
    sink = CanAlarmSink(load_alarm_codecs(), "virtual", name, heartbeat_period_s=0.02, heartbeat_source=lambda: idle_heartbeat(mode[0]))
    sink.start()
    try:
        before = [decode(0x301, f.data) for f in receive(receiver, 0x301, 3)]
        mode[0] = "confirmed"
        sink.publish(alarm_event(EventKind.CONFIRMED))
        assert len(receive(receiver, 0x300, 1)) == 1
        receive(receiver, 0x301, 1)  # one that may have been under way
        after = decode(0x301, receive(receiver, 0x301, 1)[0].data)
    finally:
        sink.close()
        receiver.shutdown()
    assert [b["Counter"] for b in before] == [1, 2, 3]
    assert all(str(b["Mode"]) == "normal" and b["AlarmCounter"] == 0 for b in before)
    assert str(after["Mode"]) == "confirmed" and after["AlarmCounter"] == 1


def test_a_bus_that_is_not_there_yet_is_retried_quietly_and_the_alarm_waits_for_it(monkeypatch: pytest.MonkeyPatch) -> None:
    import bogiemon.daemon.delivery.can_alarms as can_alarms

    monkeypatch.setattr(can_alarms, "BACKOFF_MIN_S", 0.02)
    name = channel()
    receiver = VirtualBus(channel=name, receive_own_messages=False)
    attempts = []

    def flaky_open(interface: str, chan: str) -> can.BusABC:
        attempts.append(chan)
        if len(attempts) < 4:
            raise PlayError(f"CAN interface '{chan}' does not exist")
        return open_player_bus(interface, chan)

    with structlog.testing.capture_logs() as logs:
        sink = CanAlarmSink(load_alarm_codecs(), "virtual", name, heartbeat_period_s=0.0, open_bus=flaky_open)
        sink.publish(alarm_event(EventKind.CONFIRMED))
        sink.start()
        try:
            frames = receive(receiver, 0x300, 1)
        finally:
            sink.close()
            receiver.shutdown()
    assert len(frames) == 1 and len(attempts) == 4
    assert [entry["event"] for entry in logs] == ["CAN alarm bus unusable, retrying", "CAN alarm bus open again"]


def test_a_confirmed_diagnosis_names_its_diagonal_pair_a_bit_each_and_never_a_certainty() -> None:
    codecs = load_alarm_codecs()
    pair = Diagnosis((Corner.LEADING_LEFT, Corner.TRAILING_RIGHT), "unknown", 0.999, 0.0, "", 1.0, 3)
    event = alarm_event(EventKind.CONFIRMED, diagnosis=pair, trigger=Trigger.TREND)
    decoded = decode(0x302, diagnosis_payload(codecs, event, alarm_counter=5))
    assert decoded["Counter"] == 5 and decoded["Corners"] == 1 | 8 and str(decoded["Trigger"]) == "trend"
    assert decoded["Confidence"] == 99 and decoded["EventRef"] == int(event.event_id[:6], 16)
    unknown = alarm_event(EventKind.CONFIRMED, diagnosis=Diagnosis((), "unknown", 0.6, 0.0, "", 0.0, 3))
    assert decode(0x302, diagnosis_payload(codecs, unknown, alarm_counter=6))["Corners"] == 0
    unsaid = alarm_event(EventKind.CONFIRMED, diagnosis=None, trigger=None)  # an event of a version before the diagnosis
    decoded = decode(0x302, diagnosis_payload(codecs, unsaid, alarm_counter=7))
    assert (decoded["Corners"], str(decoded["Trigger"]), decoded["Confidence"]) == (0, "none", 0)


def test_not_judged_and_judged_again_go_on_the_bus_as_alarm_frames() -> None:
    codecs = load_alarm_codecs()
    for kind, code in ((EventKind.NOT_JUDGED, "NOT_JUDGED"), (EventKind.JUDGED_AGAIN, "JUDGED_AGAIN")):
        event = event_of(kind, 1.7e9, {})
        decoded = decode(0x300, alarm_payload(codecs, event, counter=1))
        assert str(decoded["Kind"]) == code and str(decoded["Indicator"]) == "none" and decoded["Fired"] == 0


def test_the_coverage_goes_with_every_heartbeat() -> None:
    codecs = load_alarm_codecs()
    beat = Heartbeat(mode="normal", has_window=True, sensors_ok=True, judged=False, gate=None, mqtt_link="up", windows=10, events=1,
                     outbox_pending=0, judged_windows=70_001, not_judged=True, unjudged_running_s=7_259.0)  # fmt: skip
    decoded = decode(0x303, coverage_payload(codecs, beat, counter=9))
    assert decoded == {"Counter": 9, "NotJudged": 1, "UnjudgedRunning": 120, "JudgedWindows": 70_001 % 65536}
    name = channel()
    receiver = VirtualBus(channel=name, receive_own_messages=False)
    sink = CanAlarmSink(codecs, "virtual", name, heartbeat_period_s=0.02, heartbeat_source=lambda: beat)
    sink.start()
    try:
        coverage = [decode(0x303, f.data) for f in receive(receiver, 0x303, 2)]
    finally:
        sink.close()
        receiver.shutdown()
    assert [c["Counter"] for c in coverage] == [1, 2] and all(c["NotJudged"] == 1 for c in coverage)
