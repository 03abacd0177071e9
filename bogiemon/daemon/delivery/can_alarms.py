"""Alarms on the CAN bus: CONFIRMED, CLEARED, NOT_JUDGED and JUDGED_AGAIN as BogieAlarm frames (a
CONFIRMED followed by its BogieDiagnosis), and a BogieHeartbeat with its BogieCoverage.

For a telematics unit on the wagon's bus that forwards alarms itself. The frames are messages of
the DBC (config/bogiemon.dbc, docs/mqtt.md), encoded with the compiled codecs of drivers/candb.py.
publish() only queues: a thread of its own sends, so the monitor never waits for the bus. An
alarm frame goes once; the heartbeat repeats the mode and the last alarm Counter, so a receiver
that missed a frame notices. A bus that fails is reopened with a doubling backoff, the failure
logged once; alarm frames wait for it (the newest ALARM_QUEUE_N), heartbeats are not queued.
"""

from __future__ import annotations

import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import can
import cantools
import numpy as np

from bogiemon.judgement.events import INDICATOR_FIELDS, ConfirmedDetails, DecisionDetails, Event, EventKind, Severity, Trigger
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.sinks import EventSink
from bogiemon.detection.kinematics import Corner
from bogiemon.drivers.candb import DbcError, MessageCodec, compile_message, shipped_dbc_text
from bogiemon.drivers.player import PlayError, open_player_bus
from bogiemon.drivers.reconnect import Backoff

ALARM_MESSAGE, HEARTBEAT_MESSAGE = "BogieAlarm", "BogieHeartbeat"
DIAGNOSIS_MESSAGE, COVERAGE_MESSAGE = "BogieDiagnosis", "BogieCoverage"
# The events that make a frame.
ALARM_KINDS = {EventKind.CONFIRMED: 1, EventKind.CLEARED: 2, EventKind.NOT_JUDGED: 3, EventKind.JUDGED_AGAIN: 4}
CORNER_BITS = {Corner.LEADING_LEFT: 1, Corner.LEADING_RIGHT: 2, Corner.TRAILING_LEFT: 4, Corner.TRAILING_RIGHT: 8}
TRIGGER_CODES = {Trigger.WINDOWS: 1, Trigger.TREND: 2}  # 0: none
SEVERITY_CODES = {Severity.INFO: 0, Severity.WARNING: 1, Severity.ALARM: 2}
INDICATOR_CODES = {name: i + 1 for i, name in enumerate(INDICATOR_FIELDS)}  # 0: none
MODE_CODES = {"normal": 0, "suspected": 1, "confirmed": 2}
# The frame is full (64 bits): a stop or a start inside the window shares the standstill code, 1;
# MQTT's window.gate tells them apart. A window not judged for an unfamiliar load is Judged 0,
# SensorsOk 1, Gate 0 (config/bogiemon.dbc says so).
GATE_CODES = {None: 0, "standstill": 1, "non_stationary": 1, "weak_excitation": 2}
NO_WINDOW_GATE = 3
LINK_CODES = {"disabled": 0, "down": 1, "up": 2}
ALARM_QUEUE_N = 64
SEND_TIMEOUT_S = 0.1
BACKOFF_MIN_S, BACKOFF_MAX_S = 1.0, 30.0

BusOpener = Callable[[str, str], can.BusABC]


@dataclass(frozen=True)
class AlarmCodecs:
    alarm: MessageCodec
    heartbeat: MessageCodec
    diagnosis: MessageCodec
    coverage: MessageCodec


def load_alarm_codecs(dbc_path: str | Path | None = None) -> AlarmCodecs:
    """BogieAlarm and BogieHeartbeat from a DBC (None: the shipped one). Raises DbcError."""
    source = str(dbc_path) if dbc_path is not None else "shipped bogiemon.dbc"
    try:
        text = shipped_dbc_text() if dbc_path is None else Path(dbc_path).read_text(encoding="utf-8")
        db = cantools.database.load_string(text, database_format="dbc")
    except OSError as exc:
        raise DbcError(f"{source}: cannot read the DBC file: {exc.strerror or exc}") from None
    except Exception as exc:  # cantools raises parser-specific errors; all mean a bad file
        raise DbcError(f"{source}: not a valid DBC file: {str(exc).splitlines()[0] if str(exc) else type(exc).__name__}") from None
    assert isinstance(db, cantools.database.can.Database)  # what a DBC always loads as
    by_name = {m.name: m for m in db.messages}
    needs = {
        ALARM_MESSAGE: ("Counter", "Kind", "Severity", "Indicator", "Fired", "Value", "EventRef"),
        HEARTBEAT_MESSAGE: ("Counter", "Mode", "SensorsOk", "Judged", "Gate", "MqttLink", "AlarmCounter", "Windows", "Events", "OutboxPending"),
        DIAGNOSIS_MESSAGE: ("Counter", "Corners", "Trigger", "Confidence", "EventRef"),
        COVERAGE_MESSAGE: ("Counter", "NotJudged", "UnjudgedRunning", "JudgedWindows"),
    }
    codecs = {}
    for name, signals in needs.items():
        if name not in by_name:
            raise DbcError(f"{source}: no message '{name}', which [can_alarms] sends (see docs/mqtt.md)")
        codec = compile_message(by_name[name])
        missing = [s for s in signals if s not in codec.signals]
        if missing:
            raise DbcError(f"{source}: message '{name}' lacks signal(s) {', '.join(missing)}")
        codecs[name] = codec
    return AlarmCodecs(codecs[ALARM_MESSAGE], codecs[HEARTBEAT_MESSAGE], codecs[DIAGNOSIS_MESSAGE], codecs[COVERAGE_MESSAGE])


def worst_indicator(event: Event) -> tuple[str | None, float]:
    """The indicator of the event furthest beyond its alarm level (relative to it), and its value."""
    limits = event.details.thresholds if isinstance(event.details, DecisionDetails) else {}
    best: tuple[float, str, float] | None = None
    for name, value in event.indicators.items():
        if value != value:  # NaN never wins
            continue
        limit = limits.get(name)
        ratio = abs(value - limit.center) / limit.alarm if limit is not None else abs(value)
        if best is None or ratio > best[0]:
            best = (ratio, name, float(value))
    return (None, 0.0) if best is None else (best[1], best[2])


def alarm_payload(codecs: AlarmCodecs, event: Event, counter: int) -> bytes:
    name, value = worst_indicator(event)
    value_raw, _clipped = codecs.alarm.signals["Value"].to_raw(np.array([value]))
    raw = {
        "Counter": counter % 256,
        "Kind": ALARM_KINDS[event.kind],
        "Severity": SEVERITY_CODES[event.severity],
        "Indicator": INDICATOR_CODES.get(name, 0) if name is not None else 0,
        "Fired": min(15, len(event.indicators)),
        "Value": int(value_raw[0]),
        "EventRef": _event_ref(event),
    }
    return _encode(codecs.alarm, raw)


def _event_ref(event: Event) -> int:
    return int(event.event_id[:6], 16) if _is_hex(event.event_id[:6]) else 0


def diagnosis_payload(codecs: AlarmCodecs, event: Event, alarm_counter: int) -> bytes:
    """The BogieDiagnosis of a CONFIRMED: the corners it names (a bit each), its trigger and confidence."""
    details = event.details if isinstance(event.details, ConfirmedDetails) else None
    diagnosis = details.diagnosis if details is not None else None
    corners = 0
    for corner in diagnosis.corners if diagnosis is not None else ():
        corners |= CORNER_BITS[corner]
    confidence = diagnosis.corner_confidence if diagnosis is not None and math.isfinite(diagnosis.corner_confidence) else 0.0
    trigger = details.trigger if details is not None else None
    raw = {
        "Counter": alarm_counter % 256,
        "Corners": corners,
        "Trigger": 0 if trigger is None else TRIGGER_CODES[trigger],
        "Confidence": min(100, max(0, int(100 * confidence))),  # floored: never rounded up to a certainty
        "EventRef": _event_ref(event),
    }
    return _encode(codecs.diagnosis, raw)


@dataclass(frozen=True)
class Heartbeat:
    """What a heartbeat says about the monitor."""

    mode: str
    has_window: bool
    sensors_ok: bool
    judged: bool
    gate: str | None
    mqtt_link: str  # "disabled", "down" or "up"
    windows: int
    events: int
    outbox_pending: int
    judged_windows: int = 0
    not_judged: bool = False  # a NOT_JUDGED in force (judgement/coverage.py)
    unjudged_running_s: float = 0.0  # running left unjudged since the last judged window


def heartbeat_payload(codecs: AlarmCodecs, beat: Heartbeat, counter: int, alarm_counter: int) -> bytes:
    raw = {
        "Counter": counter % 256,
        "Mode": MODE_CODES[beat.mode],
        "SensorsOk": int(beat.sensors_ok),
        "Judged": int(beat.judged),
        "Gate": GATE_CODES.get(beat.gate, 0) if beat.has_window else NO_WINDOW_GATE,
        "MqttLink": LINK_CODES[beat.mqtt_link],
        "AlarmCounter": alarm_counter % 256,
        "Windows": beat.windows % 65536,
        "Events": beat.events % 65536,
        "OutboxPending": min(255, beat.outbox_pending),
    }
    return _encode(codecs.heartbeat, raw)


def coverage_payload(codecs: AlarmCodecs, beat: Heartbeat, counter: int) -> bytes:
    raw = {
        "Counter": counter % 256,
        "NotJudged": int(beat.not_judged),
        "UnjudgedRunning": min(65535, int(beat.unjudged_running_s // 60)),
        "JudgedWindows": beat.judged_windows % 65536,
    }
    return _encode(codecs.coverage, raw)


def _encode(codec: MessageCodec, raw: dict[str, int]) -> bytes:
    payload = codec.encode_raw({k: np.array([v], dtype=np.int64) for k, v in raw.items()}, 1)
    return bytes(payload[0])


def _is_hex(text: str) -> bool:
    return len(text) == 6 and all(c in "0123456789abcdefABCDEF" for c in text)


@dataclass
class CanAlarmCounters:
    alarms_sent: int = 0
    heartbeats_sent: int = 0
    alarms_dropped: int = 0  # the queue for a failed bus overflowed
    bus_failures: int = 0


class CanAlarmSink(EventSink):
    """Queues the events of ALARM_KINDS; its thread sends them (a CONFIRMED with its diagnosis) and
    the heartbeat with its coverage."""

    def __init__(
        self,
        codecs: AlarmCodecs,
        interface: str,
        channel: str,
        heartbeat_period_s: float = 1.0,
        heartbeat_source: Callable[[], Heartbeat] | None = None,
        open_bus: BusOpener = open_player_bus,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.codecs = codecs
        self.interface = interface
        self.channel = channel
        self.heartbeat_period_s = heartbeat_period_s
        self.heartbeat_source = heartbeat_source
        self.counters = CanAlarmCounters()
        self._open_bus = open_bus
        self._clock = clock
        self._events: queue.SimpleQueue[Event | None] = queue.SimpleQueue()  # None: wake up
        self._frames: deque[can.Message] = deque(maxlen=ALARM_QUEUE_N)
        self._alarm_counter = 0  # of the last frame built
        self._sent_alarm_counter = 0  # of the last frame sent
        self._beat_counter = 0
        self._stop = threading.Event()
        self._last_problem: str | None = None
        self._log = get_logger(component="can_alarms", interface=interface, channel=channel)
        self._thread = threading.Thread(target=self._run, name="bogiemon-can-alarms", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def publish(self, event: Event) -> None:
        if event.kind in ALARM_KINDS:
            self._events.put(event)

    def close(self) -> None:
        self._stop.set()
        self._events.put_nowait(None)
        if self._thread.is_alive():
            self._thread.join(2.0)

    def _run(self) -> None:
        bus: can.BusABC | None = None
        backoff = Backoff(BACKOFF_MIN_S, BACKOFF_MAX_S, self._clock)  # the first open is due at once
        next_beat_s = self._clock()
        try:
            while not self._stop.is_set():
                now_s = self._clock()
                if bus is None and backoff.due_in_s() <= 0:
                    try:
                        bus = self._open()
                        backoff.reset()
                        self._problem(None)
                    except PlayError as exc:
                        backoff.failed()
                        self._problem(str(exc))
                beat_due = self.heartbeat_period_s > 0 and self.heartbeat_source is not None
                wait_s = max(0.0, next_beat_s - now_s) if beat_due else 0.5
                if bus is None:
                    wait_s = min(wait_s, backoff.due_in_s())
                self._take_events(wait_s)
                now_s = self._clock()
                if beat_due and now_s >= next_beat_s:
                    next_beat_s = max(next_beat_s + self.heartbeat_period_s, now_s)
                    if bus is not None:
                        bus = self._send_heartbeat(bus)
                if bus is not None:
                    bus = self._send_alarms(bus)
                    if bus is None:
                        backoff.failed()  # the bus was lost sending an alarm: reopen after a wait
        finally:
            if bus is not None:
                bus.shutdown()

    def _open(self) -> can.BusABC:
        bus = self._open_bus(self.interface, self.channel)
        # A send-only socket: receive nothing (only another gateway's heartbeat could match), so the
        # kernel does not fill a receive buffer nobody reads with the bus's sensor frames.
        bus.set_filters([{"can_id": self.codecs.heartbeat.frame_id, "can_mask": 0x7FF, "extended": False}])
        return bus

    def _take_events(self, wait_s: float) -> None:
        try:
            event = self._events.get(timeout=wait_s)
        except queue.Empty:
            return
        while event is not None:
            self._alarm_counter = (self._alarm_counter + 1) % 256
            if len(self._frames) == self._frames.maxlen:
                self.counters.alarms_dropped += 1
            payload = alarm_payload(self.codecs, event, self._alarm_counter)
            self._frames.append(self._message(self.codecs.alarm, payload))
            if event.kind is EventKind.CONFIRMED:
                diagnosis = diagnosis_payload(self.codecs, event, self._alarm_counter)
                self._frames.append(self._message(self.codecs.diagnosis, diagnosis))
            try:
                event = self._events.get_nowait()
            except queue.Empty:
                return

    def _send_alarms(self, bus: can.BusABC) -> can.BusABC | None:
        while self._frames:
            frame = self._frames[0]
            if not self._send(bus, frame):
                return None
            self._frames.popleft()
            if frame.arbitration_id == self.codecs.alarm.frame_id:
                self._sent_alarm_counter = frame.data[0]
                self.counters.alarms_sent += 1
        return bus

    def _send_heartbeat(self, bus: can.BusABC) -> can.BusABC | None:
        assert self.heartbeat_source is not None
        self._beat_counter = (self._beat_counter + 1) % 256
        beat = self.heartbeat_source()
        payload = heartbeat_payload(self.codecs, beat, self._beat_counter, self._sent_alarm_counter)
        if not self._send(bus, self._message(self.codecs.heartbeat, payload)):
            return None
        if not self._send(bus, self._message(self.codecs.coverage, coverage_payload(self.codecs, beat, self._beat_counter))):
            return None
        self.counters.heartbeats_sent += 1
        return bus

    def _send(self, bus: can.BusABC, frame: can.Message) -> bool:
        try:
            bus.send(frame, timeout=SEND_TIMEOUT_S)
            return True
        except can.CanError as exc:
            self.counters.bus_failures += 1
            self._problem(f"sending failed: {exc}")
            try:
                bus.shutdown()
            except can.CanError:
                pass
            return False

    @staticmethod
    def _message(codec: MessageCodec, payload: bytes) -> can.Message:
        return can.Message(arbitration_id=codec.frame_id, is_extended_id=codec.is_extended, data=payload)

    def _problem(self, problem: str | None) -> None:
        """Log a change: the bus failing (once per reason) or working again."""
        if problem == self._last_problem:
            return
        if problem is None:
            if self._last_problem is not None:
                self._log.info("CAN alarm bus open again")
        else:
            self._log.warning("CAN alarm bus unusable, retrying", reason=problem)
        self._last_problem = problem
