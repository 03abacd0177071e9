"""Events as JSON at the edges (daemon/event_json.py): every kind round-trips, and every shape an
earlier version wrote (its store's rows, its messages) reads into today's typed records."""

from __future__ import annotations

import dataclasses
import json
import sqlite3
from pathlib import Path
from typing import Any

import pytest

from bogiemon.daemon.event_json import EventJsonError, details_body, details_from_body, event_body, event_from_body
from bogiemon.daemon.messages import EVENT_SCHEMA, EventMessage, SchemaError, decode, encode_event
from bogiemon.daemon.store import EventStore
from bogiemon.daemon.store_file import _MIGRATIONS, SCHEMA_VERSION
from bogiemon.detection.kinematics import Corner
from bogiemon.judgement.events import (
    ClearedDetails,
    ConfirmedDetails,
    EventKind,
    JudgedAgainDetails,
    KOfN,
    NotJudgedDetails,
    RunningContext,
    SensorClearedDetails,
    SensorFaultDetails,
    SisterDetails,
    SuspectedDetails,
    SuspensionHint,
    Trigger,
)
from bogiemon.judgement.rules import Threshold
from bogiemon.judgement.vocabulary import LoadSource, LoadState, Method, Mode
from tests.judgement.event_examples import details_as, event_of

OLD = json.loads((Path(__file__).parent / "data" / "events-fef8356.json").read_text())
LIMITS = {"i4_norm": Threshold(warning=0.1, alarm=0.2, center=0.05)}
RUNNING = RunningContext(load_source=LoadSource.COMMISSIONED, load_distance=0.812, p_full=0.9688, excitation_outside=1.562, level_margin=1.25)


@pytest.mark.parametrize("kind", list(EventKind))
def test_every_kind_of_event_reads_back_from_its_json_as_it_was(kind: EventKind) -> None:
    event = event_of(kind, 1.7e9)
    assert event_from_body(json.loads(json.dumps(event_body(event)))) == event
    assert decode(EventMessage, encode_event("W1", 1, event).encode()).to_event() == event


def test_k_of_n_is_written_as_two_integers() -> None:
    body = event_body(event_of(EventKind.CONFIRMED, 1.7e9))
    assert body["details"]["alarm_windows"] == {"k": 3, "n": 5}
    assert json.loads(encode_event("W1", 1, event_of(EventKind.SUSPECTED, 1.7e9)))["details"]["warning_windows"] == {"k": 2, "n": 3}


def _store_of_schema_2(state_dir: Path, bodies: list[dict[str, Any]]) -> None:
    """An event store as bogiemon at fef8356 left it: schema 2, these rows pending delivery."""
    state_dir.mkdir()
    db = sqlite3.connect(state_dir / "events.sqlite3")
    for version in (1, 2):
        for statement in _MIGRATIONS[version]:
            db.execute(statement)
    db.execute("PRAGMA user_version=2")
    for b in bodies:
        db.execute(
            "INSERT INTO events (event_id, time_s, kind, severity, config_hash, body) VALUES (?, ?, ?, ?, ?, ?)",
            (b["event_id"], b["time_s"], b["kind"], b["severity"], b["config_hash"], json.dumps(b)),
        )
    db.commit()
    db.close()


def test_a_store_written_by_the_previous_version_reads_into_typed_records(tmp_path: Path) -> None:
    _store_of_schema_2(tmp_path / "state", OLD["store_bodies"])
    store = EventStore(tmp_path / "state")
    assert store.schema_version == SCHEMA_VERSION == 3
    events = store.events()
    assert [e.kind for e in events] == [
        EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.CLEARED, EventKind.SENSOR_FAULT, EventKind.SENSOR_CLEARED, EventKind.NOT_JUDGED,
        EventKind.JUDGED_AGAIN, EventKind.CONFIRMED,
    ]  # fmt: skip
    suspected, confirmed, cleared, fault, healthy, not_judged, again, fused = events
    assert details_as(suspected, SuspectedDetails) == SuspectedDetails(
        window_start_s=1700000010.0, window_end_s=1700000130.0, load=LoadState.FULL, thresholds=LIMITS, method=Method.THRESHOLDS, running=RUNNING,
        warning_windows=KOfN(2, 2),
    )  # fmt: skip
    d = details_as(confirmed, ConfirmedDetails)
    assert (d.alarm_windows, d.trigger, d.running, d.thresholds) == (KOfN(3, 5), Trigger.WINDOWS, RUNNING, LIMITS)
    assert d.diagnosis is not None and d.diagnosis.corners == () and d.diagnosis.corner == "unknown"
    assert details_as(cleared, ClearedDetails).cleared is Mode.CONFIRMED
    assert details_as(fault, SensorFaultDetails).problems == details_as(fault, SensorFaultDetails).reported == {"a2": ("flat",)}
    assert details_as(fault, SensorFaultDetails).rms_mps2 == (0.5, 0.25, 0.75)
    assert details_as(healthy, SensorClearedDetails).cleared == {"a2": ("flat",)}
    said = details_as(not_judged, NotJudgedDetails)
    assert (said.unjudged_running_s, said.last_judged_s, said.unlike) == (20.0, None, "between the commissioned load states")
    assert details_as(again, JudgedAgainDetails) == JudgedAgainDetails(window_start_s=1700000300.0, window_end_s=1700000420.0)
    f = details_as(fused, ConfirmedDetails)
    assert (f.method, f.baseline, f.trend, f.alarm_windows, f.running) == (Method.FUSED, "calibrated", 0.17720339307260083, KOfN(3, 3), None)
    assert f.diagnosis is not None and f.diagnosis.corners == (Corner.LEADING_LEFT, Corner.TRAILING_RIGHT) and f.diagnosis.corner_confidence == 0.95


def test_the_previous_versions_backlog_goes_out_as_the_new_schema(tmp_path: Path) -> None:
    _store_of_schema_2(tmp_path / "state", OLD["store_bodies"])
    store = EventStore(tmp_path / "state")
    pending = store.outbox.pending_events()
    assert len(pending) == len(OLD["store_bodies"])
    sent = json.loads(encode_event("W1", pending[1].seq, pending[1].event))
    assert sent["schema"] == EVENT_SCHEMA == "bogiemon.event/2"
    assert sent["details"]["alarm_windows"] == {"k": 3, "n": 5}
    old = {k: v for k, v in OLD["store_bodies"][1]["details"].items() if k != "alarm_windows"}
    assert {k: v for k, v in sent["details"].items() if k != "alarm_windows"} == old  # every other detail as it was


def test_a_message_of_the_previous_schema_reads_into_the_typed_record() -> None:
    messages = [decode(EventMessage, json.dumps(p).encode()) for p in OLD["payloads"]]
    assert {m.schema_id for m in messages} == {"bogiemon.event/1"}
    events = [m.to_event() for m in messages]
    stored = [event_from_body(b) for b in OLD["store_bodies"]]
    assert events == stored
    assert details_as(events[-1], ConfirmedDetails).alarm_windows == KOfN(3, 3)


def test_the_first_versions_details_read_with_what_they_did_not_say_yet_as_none() -> None:
    # bogiemon at 87d092b: no method, no load source, no trigger nor diagnosis, no warning count.
    first = {"load": "full", "window_start_s": 10.0, "window_end_s": 130.0, "thresholds": {"i4_norm": {"center": 0.05, "warning": 0.1, "alarm": 0.2}}}
    confirmed = details_from_body(EventKind.CONFIRMED, {**first, "alarm_windows": "3 of 5"})
    assert confirmed == ConfirmedDetails(window_start_s=10.0, window_end_s=130.0, load=LoadState.FULL, thresholds=LIMITS, alarm_windows=KOfN(3, 5))
    assert details_from_body(EventKind.SUSPECTED, first) == SuspectedDetails(window_start_s=10.0, window_end_s=130.0, load=LoadState.FULL, thresholds=LIMITS)
    fault = details_from_body(EventKind.SENSOR_FAULT, {"window_start_s": 10.0, "window_end_s": 130.0, "rms_mps2": [0.0, 1.0, 1.0], "problems": {"a1": ["flat"]}})
    assert isinstance(fault, SensorFaultDetails) and fault.reported is None


def test_a_diagnosis_of_the_version_before_the_pair_names_its_one_corner() -> None:
    # bogiemon at 2938de8: "corner" alone, a kind of its own.
    before = {"corner": "trailing-left", "kind": "spring-softer", "corner_confidence": 0.8, "kind_confidence": 0.6, "best_match": "", "cosine": 0.9, "windows": 3}
    body = {**OLD["store_bodies"][1]["details"], "diagnosis": before}
    d = details_from_body(EventKind.CONFIRMED, body)
    assert isinstance(d, ConfirmedDetails) and d.diagnosis is not None
    assert (d.diagnosis.corners, d.diagnosis.corner, d.diagnosis.kind) == ((Corner.TRAILING_LEFT,), "trailing-left", "spring-softer")
    unknown = details_from_body(EventKind.CONFIRMED, {**body, "diagnosis": {**before, "corner": "unknown"}})
    assert isinstance(unknown, ConfirmedDetails) and unknown.diagnosis is not None and unknown.diagnosis.corners == ()


def test_a_null_number_reads_as_not_finite_and_a_null_optional_as_unsaid() -> None:
    body = {"window_start_s": 10.0, "window_end_s": 130.0, "rms_mps2": [None, 1.0, 1.0], "problems": {"a1": ["flat"]}, "reported": None}
    fault = details_from_body(EventKind.SENSOR_FAULT, body)
    assert isinstance(fault, SensorFaultDetails) and fault.rms_mps2[0] != fault.rms_mps2[0] and fault.reported is None


CONFIRMED = OLD["store_bodies"][1]["details"]
BAD = [
    ("no window", EventKind.JUDGED_AGAIN, {"window_end_s": 1.0}, "details: window_start_s: missing"),
    ("a word that is none", EventKind.CONFIRMED, {**CONFIRMED, "trigger": "hunch"}, "details: trigger: expected one of windows, trend"),
    ("counts as a sentence", EventKind.CONFIRMED, {**CONFIRMED, "alarm_windows": "three of five"},
     'details: alarm_windows: expected {"k": k, "n": n} (or "k of n")'),
    ("more than all", EventKind.CONFIRMED, {**CONFIRMED, "alarm_windows": {"k": 6, "n": 5}}, "details: alarm_windows: expected 0 <= k <= n"),
    ("a count of true", EventKind.CONFIRMED, {**CONFIRMED, "alarm_windows": {"k": True, "n": 5}}, "details: alarm_windows: k: expected an integer"),
    ("an upside-down limit", EventKind.CLEARED, {**CONFIRMED, "cleared": "confirmed", "thresholds": {"i4_norm": {"center": 0, "warning": 0.3, "alarm": 0.2}}},
     "details: thresholds: i4_norm: expected 0 < warning <= alarm"),
    ("a corner nobody has", EventKind.CONFIRMED, {**CONFIRMED, "diagnosis": {**CONFIRMED["diagnosis"], "corners": ["middle"]}},
     "details: diagnosis: corners: expected one of leading-left, leading-right, trailing-left, trailing-right"),
    ("a number as text", EventKind.NOT_JUDGED, {"window_start_s": 0, "window_end_s": 1, "message": "m", "unjudged_running_s": "7200"},
     "details: unjudged_running_s: expected a number"),
    ("problems as a list", EventKind.SENSOR_CLEARED, {"window_start_s": 0, "window_end_s": 1, "rms_mps2": [], "cleared": ["a1"]},
     "details: cleared: expected channel -> list of problem names"),
]  # fmt: skip


@pytest.mark.parametrize(("kind", "body", "error"), [b[1:] for b in BAD], ids=[b[0] for b in BAD])
def test_details_that_are_not_a_record_of_their_kind_are_refused_in_one_line_naming_the_field(kind: EventKind, body: dict[str, Any], error: str) -> None:
    with pytest.raises(EventJsonError) as caught:
        details_from_body(kind, body)
    assert str(caught.value) == error
    payload = {**OLD["payloads"][0], "kind": kind.value, "details": body}
    with pytest.raises(SchemaError) as refused:
        decode(EventMessage, json.dumps(payload).encode())
    assert str(refused.value) == error


def test_an_event_names_its_bogie_at_the_top_and_one_without_is_bogie_1s() -> None:
    event = dataclasses.replace(event_of(EventKind.CONFIRMED, 1.7e9), bogie="2")
    body = event_body(event)
    assert body["bogie"] == "2"
    assert event_from_body(json.loads(json.dumps(body))) == event
    assert decode(EventMessage, encode_event("W1", 1, event).encode()).to_event().bogie == "2"
    assert event_body(event_of(EventKind.CONFIRMED, 1.7e9))["bogie"] == "1"  # a one-bogie gateway's
    earlier = {k: v for k, v in body.items() if k != "bogie"}
    assert event_from_body(earlier).bogie == "1"
    assert decode(EventMessage, json.dumps({"schema": "bogiemon.event/2", "wagon_id": "W1", "seq": 1, **earlier}).encode()).to_event().bogie == "1"


def test_a_bogie_that_is_no_short_name_is_refused_in_one_line() -> None:
    body = {**event_body(event_of(EventKind.CLEARED, 1.7e9)), "bogie": "bogie two"}
    with pytest.raises(EventJsonError, match="^bogie: expected a bogie id"):
        event_from_body(body)
    with pytest.raises(SchemaError, match="bogie"):
        decode(EventMessage, json.dumps({"schema": "bogiemon.event/2", "wagon_id": "W1", "seq": 1, **body}).encode())


@pytest.mark.parametrize("kind", [EventKind.SUSPECTED, EventKind.CONFIRMED])
def test_the_sister_evidence_of_a_wagon_reads_back_as_its_record(kind: EventKind) -> None:
    sister = SisterDetails(score=41.5, warning=12.0, alarm=20.0, baseline="commissioned", blamed=2, own_scores=(3.25, 17.5))
    event = dataclasses.replace(event_of(kind, 1.7e9), bogie="2")
    details = event.details
    assert isinstance(details, SuspectedDetails | ConfirmedDetails)
    event = dataclasses.replace(event, details=dataclasses.replace(details, sister=sister))
    body = json.loads(json.dumps(event_body(event)))
    assert body["details"]["sister"] == {"score": 41.5, "warning": 12.0, "alarm": 20.0, "baseline": "commissioned", "blamed": 2, "own_scores": [3.25, 17.5]}
    assert event_from_body(body) == event
    assert decode(EventMessage, encode_event("W1", 1, event).encode()).to_event() == event
    body["details"]["sister"]["own_scores"] = [1.0]
    with pytest.raises(EventJsonError, match="^details: sister: own_scores: expected two numbers"):
        event_from_body(body)


def test_a_sensor_fault_that_points_at_a_corner_pair_reads_back_as_written_and_one_without_states_none() -> None:
    noisy = {"a3": ("noisy",)}
    hint = SuspensionHint(("trailing-left", "leading-right"), 80.5, 67.0, "pitch-roll -3.1 sd at 4-8 Hz: trailing-left or leading-right")
    pointed = SensorFaultDetails(window_start_s=10.0, window_end_s=130.0, rms_mps2=(1.0, 1.1, 1.4), problems=noisy, reported=noisy, suspension=hint)
    body = json.loads(json.dumps(details_body(pointed)))
    assert body["suspension"]["corners"] == ["trailing-left", "leading-right"]
    assert details_from_body(EventKind.SENSOR_FAULT, body) == pointed
    alone = dataclasses.replace(pointed, suspension=None)
    assert "suspension" not in details_body(alone) and details_from_body(EventKind.SENSOR_FAULT, details_body(alone)) == alone
