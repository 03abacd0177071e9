"""An event as JSON: the one shape every edge writes and reads, in one place.

The event store's rows (daemon/store.py), the journal (daemon/sinks.py), `bogiemon events --json`
and `replay --json`, and the body of a bogiemon.event message (daemon/messages.py, which the
fleet's events.jsonl holds too) are all `event_body(event)`; each is read back into the typed
record of its kind (judgement/events.py) by `event_from_body`. Inside the process an event is
never JSON.

The details as written since bogiemon.event/2 (store schema 3): the k-of-n counts are objects,
{"k": 3, "n": 5}; every event names its bogie at the top ("bogie": "1", the [[bogie]] id of the
config), and a wagon judged on both bogies adds the pair's sister evidence to a SUSPECTED's or
CONFIRMED's details ("sister"). A body without "bogie" (every one before) is bogie "1"'s: the one
place that says so. The reader also takes every shape an earlier version wrote, which a gateway may
still hold in its store or outbox and a back office in its files: the counts as text ("3 of 5"),
a diagnosis naming one corner ("corner") rather than its list ("corners"), and the fields added
over time missing (the record says None). A body outside these shapes is an EventJsonError of one
line, naming the field and never quoting its value.

A leaf like the message schema: the record's heavier types (the limits, the diagnosis and its
corners) are imported when a body that holds them is read.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, NoReturn, TypeVar

from bogiemon.judgement.events import (
    DEFAULT_BOGIE,
    ClearedDetails,
    ConfirmedDetails,
    DecisionDetails,
    Event,
    EventDetails,
    EventKind,
    JudgedAgainDetails,
    KOfN,
    NotJudgedDetails,
    Problems,
    RunningContext,
    SensorClearedDetails,
    SensorFaultDetails,
    Severity,
    SisterDetails,
    SuspensionHint,
    SuspectedDetails,
    Trigger,
)
from bogiemon.judgement.vocabulary import LoadSource, LoadState, Method, Mode

if TYPE_CHECKING:
    from bogiemon.judgement.diagnosis import Diagnosis
    from bogiemon.judgement.rules import Threshold

# A bogie's id as the config allows it (daemon/config_bogies.py): a topic level and a word of a line.
_BOGIE_ID = re.compile(r"^[A-Za-z0-9._-]{1,16}$")
_K_OF_N_TEXT = re.compile(r"^(\d{1,9}) of (\d{1,9})$")  # "3 of 5", as bodies before bogiemon.event/2 hold it
W = TypeVar("W", bound=enum.Enum)
D = TypeVar("D", SuspectedDetails, ConfirmedDetails, ClearedDetails)


class EventJsonError(ValueError):
    """A stored or received event body that is not an event of its kind; one line, no values."""


def event_body(event: Event) -> dict[str, Any]:
    """The event as JSON-able values (what the store keeps and a message carries)."""
    return {
        "event_id": event.event_id,
        "time_s": event.time_s,
        "kind": event.kind.value,
        "severity": event.severity.value,
        "config_hash": event.config_hash,
        "indicators": dict(event.indicators),
        "details": details_body(event.details),
        "bogie": event.bogie,
    }


def event_from_body(data: Mapping[str, Any]) -> Event:
    """An event from its body (event_body's, or an earlier version's); EventJsonError if it is none."""
    if not isinstance(data, Mapping):
        raise EventJsonError("expected an object")
    body = _Reader(data, "")
    kind = body.word("kind", EventKind)
    indicators = body.field("indicators", lambda v, where: _object(v, where), {})
    return Event(
        time_s=body.number("time_s"),
        kind=kind,
        severity=body.word("severity", Severity),
        config_hash=body.text("config_hash"),
        indicators={str(name): _number(v, f"indicators: {name}") for name, v in indicators.items()},
        details=details_from_body(kind, body.field("details", lambda v, where: _object(v, where), {})),
        event_id=body.text("event_id"),
        bogie=body.field("bogie", _bogie, DEFAULT_BOGIE),
    )


def details_body(details: EventDetails) -> dict[str, Any]:
    """The details of an event as JSON-able values, in the order they have always been written."""
    out: dict[str, Any]
    if isinstance(details, DecisionDetails):
        out = {"load": details.load.value}
        if details.running is not None:
            out |= _present(
                load_source=details.running.load_source.value, load_distance=details.running.load_distance, p_full=details.running.p_full,
                excitation_outside=details.running.excitation_outside, level_margin=details.running.level_margin,
            )  # fmt: skip
        out |= _present(method=None if details.method is None else details.method.value)
        out |= {"window_start_s": details.window_start_s, "window_end_s": details.window_end_s}
        out["thresholds"] = {name: {"center": t.center, "warning": t.warning, "alarm": t.alarm} for name, t in details.thresholds.items()}
        out |= _present(baseline=details.baseline, trend=details.trend)
        if isinstance(details, SuspectedDetails):
            out |= _present(warning_windows=_k_of_n_body(details.warning_windows))
            out |= _present(sister=_sister_body(details.sister))
        elif isinstance(details, ConfirmedDetails):
            out |= _present(trigger=None if details.trigger is None else details.trigger.value)
            out["alarm_windows"] = _k_of_n_body(details.alarm_windows)
            out |= _present(diagnosis=None if details.diagnosis is None else _diagnosis_body(details.diagnosis))
            out |= _present(sister=_sister_body(details.sister))
        else:
            out["cleared"] = details.cleared.value
        return out
    out = {"window_start_s": details.window_start_s, "window_end_s": details.window_end_s}
    if isinstance(details, SensorFaultDetails):
        out |= {"rms_mps2": list(details.rms_mps2), "problems": _problems_body(details.problems)}
        out |= _present(reported=None if details.reported is None else _problems_body(details.reported))
        out |= _present(suspension=None if details.suspension is None else _suspension_body(details.suspension))
    elif isinstance(details, SensorClearedDetails):
        out |= {"rms_mps2": list(details.rms_mps2), "cleared": _problems_body(details.cleared)}
    elif isinstance(details, NotJudgedDetails):
        out |= {"message": details.message, "unjudged_running_s": details.unjudged_running_s, "last_judged_s": details.last_judged_s}
        out |= _present(unlike=details.unlike)
    return out


def details_from_body(kind: EventKind, data: Mapping[str, Any]) -> EventDetails:
    """The details record of an event of this kind; EventJsonError if the body does not hold one."""
    d = _Reader(data, "details: ")
    start_s, end_s = d.number("window_start_s"), d.number("window_end_s")
    if kind in (EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.CLEARED):

        def decided(record: type[D], **own: Any) -> D:
            return record(
                window_start_s=start_s, window_end_s=end_s, load=d.word("load", LoadState), thresholds=d.field("thresholds", _thresholds),
                method=d.field("method", lambda v, where: _word(v, where, Method), None), running=_running(d),
                baseline=d.field("baseline", _text, None), trend=d.field("trend", _number, None), **own,
            )  # fmt: skip

        if kind is EventKind.SUSPECTED:
            return decided(SuspectedDetails, warning_windows=d.field("warning_windows", _k_of_n, None), sister=d.field("sister", _sister, None))
        if kind is EventKind.CONFIRMED:
            return decided(
                ConfirmedDetails, alarm_windows=d.field("alarm_windows", _k_of_n), trigger=d.field("trigger", lambda v, where: _word(v, where, Trigger), None),
                diagnosis=d.field("diagnosis", _diagnosis, None), sister=d.field("sister", _sister, None),
            )  # fmt: skip
        return decided(ClearedDetails, cleared=d.word("cleared", Mode))
    if kind is EventKind.SENSOR_FAULT:
        return SensorFaultDetails(
            window_start_s=start_s, window_end_s=end_s, rms_mps2=d.field("rms_mps2", _numbers), problems=d.field("problems", _problems),
            reported=d.field("reported", _problems, None), suspension=d.field("suspension", _suspension, None),
        )  # fmt: skip
    if kind is EventKind.SENSOR_CLEARED:
        return SensorClearedDetails(window_start_s=start_s, window_end_s=end_s, rms_mps2=d.field("rms_mps2", _numbers), cleared=d.field("cleared", _problems))
    if kind is EventKind.NOT_JUDGED:
        return NotJudgedDetails(
            window_start_s=start_s, window_end_s=end_s, message=d.text("message"), unjudged_running_s=d.number("unjudged_running_s"),
            last_judged_s=d.field("last_judged_s", _number, None), unlike=d.field("unlike", _text, None),
        )  # fmt: skip
    return JudgedAgainDetails(window_start_s=start_s, window_end_s=end_s)


def _present(**values: Any) -> dict[str, Any]:
    """The values that are stated: a field the record leaves None is not written."""
    return {k: v for k, v in values.items() if v is not None}


def _k_of_n_body(count: KOfN | None) -> dict[str, int] | None:
    return None if count is None else {"k": count.k, "n": count.n}


def _diagnosis_body(d: Diagnosis) -> dict[str, Any]:
    return {
        "corner": d.corner, "corners": [c.value for c in d.corners], "kind": d.kind, "corner_confidence": d.corner_confidence,
        "kind_confidence": d.kind_confidence, "best_match": d.best_match, "cosine": d.cosine, "windows": d.windows,
    }  # fmt: skip


def _sister_body(s: SisterDetails | None) -> dict[str, Any] | None:
    if s is None:
        return None
    return {"score": s.score, "warning": s.warning, "alarm": s.alarm, "baseline": s.baseline, "blamed": s.blamed, "own_scores": list(s.own_scores)}


def _suspension_body(s: SuspensionHint) -> dict[str, Any]:
    return {"corners": list(s.corners), "fused_score": s.fused_score, "alarm": s.alarm, "best_match": s.best_match}


def _problems_body(problems: Problems) -> dict[str, list[str]]:
    return {channel: list(names) for channel, names in problems.items()}


_MISSING: Any = object()


class _Reader:
    """The fields of one JSON object, each read and checked by its own reader."""

    def __init__(self, data: Mapping[str, Any], where: str) -> None:
        self.data, self.where = data, where

    def field(self, key: str, read: Callable[[Any, str], Any], default: Any = _MISSING) -> Any:
        """The value of key as read(value, where) returns it; default when absent (or null, for an
        optional field); EventJsonError when a required field is missing."""
        value = self.data.get(key, _MISSING)
        if value is _MISSING or (value is None and default is not _MISSING):
            if default is _MISSING:
                _fail(f"{self.where}{key}", "missing")
            return default
        return read(value, f"{self.where}{key}")

    def number(self, key: str) -> float:
        return float(self.field(key, _number))

    def text(self, key: str) -> str:
        return str(self.field(key, _text))

    def word(self, key: str, words: type[W]) -> W:
        value: W = self.field(key, lambda v, where: _word(v, where, words))
        return value


def _fail(where: str, what: str) -> NoReturn:
    raise EventJsonError(f"{where}: {what}")


def _number(value: Any, where: str) -> float:
    """A number; null is a number that was not finite (strict JSON writes NaN and infinities as null)."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, int | float):
        _fail(where, "expected a number")
    try:
        return float(value)
    except OverflowError:  # an integer too large for a float
        _fail(where, "expected a number that fits a float")


def _integer(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        _fail(where, "expected an integer")
    return value


def _text(value: Any, where: str) -> str:
    if not isinstance(value, str):
        _fail(where, "expected a string")
    return value


def _word(value: Any, where: str, words: type[W]) -> W:
    try:
        return words(_text(value, where))
    except ValueError:
        _fail(where, f"expected one of {', '.join(str(w.value) for w in words)}")


def _object(value: Any, where: str) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        _fail(where, "expected an object")
    return value


def _numbers(value: Any, where: str) -> tuple[float, ...]:
    if not isinstance(value, list):
        _fail(where, "expected a list of numbers")
    return tuple(_number(v, where) for v in value)


def _problems(value: Any, where: str) -> Problems:
    if not isinstance(value, Mapping) or not all(isinstance(names, list) and all(isinstance(n, str) for n in names) for names in value.values()):
        _fail(where, "expected channel -> list of problem names")
    return {str(channel): tuple(names) for channel, names in value.items()}


def _k_of_n(value: Any, where: str) -> KOfN:
    if isinstance(value, str) and (m := _K_OF_N_TEXT.match(value)):
        k, n = int(m.group(1)), int(m.group(2))
    elif isinstance(value, Mapping):
        count = _Reader(value, f"{where}: ")
        k, n = count.field("k", _integer), count.field("n", _integer)
    else:
        _fail(where, 'expected {"k": k, "n": n} (or "k of n")')
    if not 0 <= k <= n:
        _fail(where, "expected 0 <= k <= n")
    return KOfN(k, n)


def _thresholds(value: Any, where: str) -> dict[str, Threshold]:
    from bogiemon.judgement.rules import Threshold

    out = {}
    for name, limit in _object(value, where).items():
        at = f"{where}: {name}"
        levels = _Reader(_object(limit, at), f"{at}: ")
        warning, alarm, center = levels.number("warning"), levels.number("alarm"), levels.number("center")
        try:
            out[str(name)] = Threshold(warning, alarm, center)
        except ValueError:
            _fail(at, "expected 0 < warning <= alarm")
    return out


def _running(d: _Reader) -> RunningContext | None:
    """How the window was judged: absent from events of versions before the load was decided per window."""
    source = d.field("load_source", lambda v, where: _word(v, where, LoadSource), None)
    if source is None:
        return None
    return RunningContext(
        load_source=source, load_distance=d.field("load_distance", _number, None), p_full=d.field("p_full", _number, None),
        excitation_outside=d.field("excitation_outside", _number, None), level_margin=d.field("level_margin", _number, None),
    )  # fmt: skip


def _diagnosis(value: Any, where: str) -> Diagnosis:
    from bogiemon.detection.kinematics import Corner
    from bogiemon.judgement.diagnosis import Diagnosis
    from bogiemon.judgement.models import UNKNOWN

    d = _Reader(_object(value, where), f"{where}: ")
    # Versions before the pair wrote one corner, or "unknown", as "corner" alone.
    names = d.field("corners", _names, None)
    if names is None:
        said = d.text("corner")
        names = [] if said == UNKNOWN else said.split(" or ")
    corners = tuple(_word(name, f"{where}: corners", Corner) for name in names)
    return Diagnosis(
        corners=corners, kind=d.text("kind"), corner_confidence=d.number("corner_confidence"), kind_confidence=d.number("kind_confidence"),
        best_match=d.text("best_match"), cosine=d.number("cosine"), windows=d.field("windows", _integer),
    )  # fmt: skip


def _sister(value: Any, where: str) -> SisterDetails:
    d = _Reader(_object(value, where), f"{where}: ")
    own = d.field("own_scores", _numbers)
    if len(own) != 2:
        _fail(f"{where}: own_scores", "expected two numbers, one per bogie")
    blamed = d.field("blamed", _integer, None)
    if blamed not in (None, 1, 2):
        _fail(f"{where}: blamed", "expected 1, 2 or null")
    return SisterDetails(
        score=d.number("score"), warning=d.number("warning"), alarm=d.number("alarm"), baseline=d.text("baseline"), blamed=blamed,
        own_scores=(own[0], own[1]),
    )  # fmt: skip


def _suspension(value: Any, where: str) -> SuspensionHint:
    d = _Reader(_object(value, where), f"{where}: ")
    return SuspensionHint(corners=tuple(d.field("corners", _names)), fused_score=d.number("fused_score"), alarm=d.number("alarm"), best_match=d.text("best_match"))


def _bogie(value: Any, where: str) -> str:
    """A bogie's id: a short name, as [[bogie]] id in the config allows."""
    text = _text(value, where)
    if not _BOGIE_ID.match(text):
        _fail(where, "expected a bogie id: 1 to 16 letters, digits, '.', '_' or '-'")
    return text


def _names(value: Any, where: str) -> list[str]:
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        _fail(where, "expected a list of names")
    return value
