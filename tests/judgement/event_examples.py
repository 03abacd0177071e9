"""Events of every kind with details as the judgement writes them, for the tests (and benchmarks)
of what carries, stores, sends or prints events."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any, TypeVar

from bogiemon.detection.kinematics import Corner
from bogiemon.judgement.diagnosis import Diagnosis
from bogiemon.judgement.events import (
    DEFAULT_SEVERITY,
    ClearedDetails,
    ConfirmedDetails,
    Event,
    EventDetails,
    EventKind,
    JudgedAgainDetails,
    KOfN,
    NotJudgedDetails,
    RunningContext,
    SensorClearedDetails,
    SensorFaultDetails,
    SuspectedDetails,
    Trigger,
)
from bogiemon.judgement.rules import Threshold
from bogiemon.judgement.vocabulary import LoadSource, LoadState, Method, Mode

D = TypeVar("D", SuspectedDetails, ConfirmedDetails, ClearedDetails)
WINDOW_S = 120.0
THRESHOLDS = {"i4_norm": Threshold(warning=0.1, alarm=0.2, center=0.05)}
RUNNING = RunningContext(load_source=LoadSource.CONFIGURED)
DIAGNOSIS = Diagnosis(
    corners=(Corner.LEADING_LEFT, Corner.TRAILING_RIGHT), kind="unknown", corner_confidence=0.947, kind_confidence=0.0,
    best_match="pitch-roll +4.1, bounce-roll +3.2 sd at 4-8 Hz: leading-left or trailing-right (leading-left if softer)", cosine=0.9, windows=3,
)  # fmt: skip


def details_of(kind: EventKind, end_s: float, text: str = "") -> EventDetails:
    """Details of a kind for the window ending at end_s. text, where given, goes where an event
    holds free text: a NOT_JUDGED's reason (`unlike`), a CONFIRMED's diagnosis in words."""
    start_s = end_s - WINDOW_S
    if text and kind not in (EventKind.NOT_JUDGED, EventKind.CONFIRMED):
        raise ValueError(f"a {kind} holds no free text")

    def decided(record: type[D], **own: Any) -> D:
        return record(
            window_start_s=start_s, window_end_s=end_s, load=LoadState.FULL, thresholds=THRESHOLDS, method=Method.THRESHOLDS, running=RUNNING, **own
        )

    if kind is EventKind.SUSPECTED:
        return decided(SuspectedDetails, warning_windows=KOfN(2, 3))
    if kind is EventKind.CONFIRMED:
        diagnosis = dataclasses.replace(DIAGNOSIS, best_match=text or DIAGNOSIS.best_match)
        return decided(ConfirmedDetails, alarm_windows=KOfN(3, 5), trigger=Trigger.WINDOWS, diagnosis=diagnosis)
    if kind is EventKind.CLEARED:
        return decided(ClearedDetails, cleared=Mode.CONFIRMED)
    if kind is EventKind.SENSOR_FAULT:
        return SensorFaultDetails(window_start_s=start_s, window_end_s=end_s, rms_mps2=(0.8, 0.0, 0.7), problems={"a2": ("flat",)}, reported={"a2": ("flat",)})
    if kind is EventKind.SENSOR_CLEARED:
        return SensorClearedDetails(window_start_s=start_s, window_end_s=end_s, rms_mps2=(0.8, 0.9, 0.7), cleared={"a2": ("flat",)})
    if kind is EventKind.NOT_JUDGED:
        return NotJudgedDetails(
            window_start_s=start_s, window_end_s=end_s, message="not judged for the last 2.0 h of running: the wagon is unlike its commissioning",
            unjudged_running_s=7200.0, last_judged_s=end_s - 7300.0, unlike=text or "between the commissioned load states",
        )  # fmt: skip
    return JudgedAgainDetails(window_start_s=start_s, window_end_s=end_s)

def event_of(
    kind: EventKind, time_s: float, indicators: Mapping[str, float] | None = None, config_hash: str = "c0ffee", text: str = "", event_id: str | None = None
) -> Event:
    """An event of a kind at time_s (its window's end), with details_of's details."""
    fired = dict(indicators) if indicators is not None else {"i4_norm": 0.25}
    event = Event(time_s, kind, DEFAULT_SEVERITY[kind], config_hash, fired, details=details_of(kind, time_s, text))
    return event if event_id is None else Event(time_s, kind, event.severity, config_hash, fired, details=event.details, event_id=event_id)


T = TypeVar("T")


def details_as(event: Event, record: type[T]) -> T:
    """An event's details, checked to be the record of its kind the test expects."""
    assert isinstance(event.details, record), (event.kind, type(event.details).__name__)
    return event.details


# An event in the script of a child process (which imports bogiemon alone): CHILD_EVENT.format(t=...)
# with `i` the event's number, as its id.
CHILD_IMPORTS = "from bogiemon.judgement.events import Event, EventKind, JudgedAgainDetails, Severity\n"
CHILD_EVENT = (
    "Event({t}, EventKind.JUDGED_AGAIN, Severity.INFO, 'x', details=JudgedAgainDetails(window_start_s={t} - 120.0, window_end_s={t}), event_id=str(i))"
)
