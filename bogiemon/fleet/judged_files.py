"""A JUDGED folder (docs/fleet-formats.md section 3) read and checked, for the fleet's page.

Every field the page uses is checked, with one line naming the file and the field when it is
missing or of the wrong kind: the files come from `bogiemon fleet judge`, but they may have been
copied, edited or cut short on the way, so the page never trusts them.
"""

from __future__ import annotations

import enum
import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.events import EventKind
from bogiemon.drivers.files import FileKind, open_untrusted, read_untrusted
from bogiemon.fleet.paths import one_line, open_parquet, parquet_kind, shown

# pyarrow and the messages' pydantic models are imported where a file is read, not with the page's
# code: importing fleet/report.py took 0.6 s with them, and a reader that only builds pages from
# what it already holds needs neither (bench/bench_import.py).
if TYPE_CHECKING:
    from bogiemon.daemon.messages import EventMessage


class WagonState(enum.StrEnum):
    """A wagon's state on the fleet page (wagons.json), most urgent first."""

    CONFIRMED = "CONFIRMED"
    SENSOR_FAULT = "SENSOR_FAULT"
    NOT_JUDGED = "NOT_JUDGED"  # a NOT_JUDGED in force: running left unjudged for long
    SUSPECTED = "SUSPECTED"
    NORMAL = "NORMAL"
    NO_DATA = "NO_DATA"


STATES = tuple(WagonState)
EVENT_KINDS = tuple(k.value for k in EventKind)
# A wagon id as the back office writes folders (docs/fleet-formats.md section 1); a series is
# read only for such an id, so a hostile id in wagons.json never names a path outside series/.
WAGON_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$")
SERIES_COLUMNS = ("time_s", "judged", "score", "trend", "warning", "alarm", "trend_warning", "trend_alarm", "mode")
# The bounds of what a JUDGED folder holds: a fleet of 100 000 wagons' wagons.json is about
# 200 MB; a year of a wagon's windows every 10 s is 3.2 M rows of series, about 100 MB.
WAGONS_JSON = FileKind(
    name="wagons.json", description="wagons.json is the JSON `bogiemon fleet judge` writes", max_bytes=1 << 30,
    too_large="wagons.json is a fleet's states: is this the right folder?",
)  # fmt: skip


def events_kind() -> FileKind:
    """events.jsonl's bounds: a line is at most one message's payload."""
    from bogiemon.daemon.messages import MAX_PAYLOAD_BYTES

    return FileKind(
        name="events.jsonl", description="events.jsonl holds one event a line, as `bogiemon fleet judge` writes it", max_bytes=8 << 30,
        too_large="split the fleet's judging", max_line_bytes=MAX_PAYLOAD_BYTES,
    )  # fmt: skip

SERIES_FILE = parquet_kind("series", "a series is the Parquet file `bogiemon fleet judge` writes per wagon", 4 << 30)



class ReportError(ValueError):
    """A JUDGED folder the report cannot read, or an output it cannot write (one line)."""


@dataclass(frozen=True)
class Series:
    """A wagon's windows in time order (the columns of series/wagon=<id>/part-0.parquet the page uses)."""

    time_s: NDArray[np.float64]
    judged: NDArray[np.bool_]
    score: NDArray[np.float64]
    trend: NDArray[np.float64]
    warning: NDArray[np.float64]
    alarm: NDArray[np.float64]
    trend_warning: NDArray[np.float64]
    trend_alarm: NDArray[np.float64]
    mode: NDArray[np.str_]


_NONE = np.zeros(0, dtype=np.float64)
EMPTY_SERIES = Series(_NONE, np.zeros(0, dtype=bool), _NONE, _NONE, _NONE, _NONE, _NONE, _NONE, np.zeros(0, dtype=np.str_))


@dataclass(frozen=True)
class WagonPage:
    entry: Mapping[str, Any]  # the wagon's record in wagons.json, checked
    series: Series | None
    series_note: str  # why there is no series, or ""
    events: Sequence[EventMessage]


@dataclass(frozen=True)
class Judged:
    path: Path
    doc: Mapping[str, Any]  # wagons.json, checked
    wagons: Sequence[WagonPage]  # sorted by attention, descending
    events: int = 0


# ---------------------------------------------------------------------------------------------
# Reading and checking


_KIND_NAMES = {"str": "a string", "num": "a number", "int": "an integer", "bool": "true or false", "list": "a list", "obj": "an object"}


def _is(value: Any, kind: str) -> bool:
    if kind == "str":
        return isinstance(value, str)
    if kind == "num":
        return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
    if kind == "int":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "list":
        return isinstance(value, list)
    return isinstance(value, dict)


# Field -> kind; a trailing "?" allows null.
# 2: the series' mode in the daemon's words ("normal", "suspected", "confirmed").
# 3: each wagon's last_data_s (its newest window's end), sensor_corners (channel -> corner) and
#    diagnosis_now (bogie -> the alarm in force's diagnosis at the period's end).
JUDGED_FORMAT = 3
TOP_FIELDS = {"format": "int", "generated_utc": "str", "fleet": "str", "wagons": "list", "inputs": "obj"}
INPUT_FIELDS = {"wagons": "int", "recordings": "int", "skipped": "list"}
SKIPPED_FIELDS = {"path": "str", "reason": "str"}
WAGON_FIELDS = {
    "wagon": "str",
    "type": "str",
    "state": "str",
    "attention": "num",
    "last_event": "obj?",
    "diagnosis": "obj?",
    "diagnosis_now": "obj",
    "sensor_problems": "obj",
    "trend": "num?",
    "trend_alarm": "num?",
    "commissioned": "list",
    "days": "int",
    "first_day": "str?",
    "last_day": "str?",
    "windows": "int",
    "judged": "int",
    "gated": "int",
    "sensor_fault_windows": "int",
    "last_data_s": "num?",
    "sensor_corners": "obj",
    "fleet_relative": "obj?",
    "notes": "list",
}
LAST_EVENT_FIELDS = {"kind": "str", "time_s": "num", "time_utc": "str", "seq": "int"}
DIAGNOSIS_FIELDS = {"corner": "str?", "kind": "str?", "corner_confidence": "num?", "kind_confidence": "num?"}
FLEET_RELATIVE_FIELDS = {"baseline_distance": "num?", "trend_rank": "num?", "stands_out": "bool", "why": "str"}


def _check(obj: Any, fields: Mapping[str, str], file: Path, where: str) -> dict[str, Any]:
    if not isinstance(obj, dict):
        raise ReportError(f"{file}: {where or 'the file'}: expected an object")
    for name, kind in fields.items():
        nullable = kind.endswith("?")
        kind = kind.rstrip("?")
        at = f"{where}.{name}" if where else name
        if name not in obj:
            raise ReportError(f"{file}: {where or 'top level'}: missing field '{name}'")
        value = obj[name]
        if value is None and nullable:
            continue
        if not _is(value, kind):
            raise ReportError(f"{file}: {at}: expected {_KIND_NAMES[kind]}{' or null' if nullable else ''}")
    return obj


def _strings(value: list[Any], file: Path, at: str) -> list[str]:
    if not all(isinstance(v, str) for v in value):
        raise ReportError(f"{file}: {at}: expected a list of strings")
    return value


def read_wagons_json(path: Path) -> dict[str, Any]:
    """wagons.json, checked against the contract: ReportError (one line, naming the field) if not."""
    from bogiemon.daemon.messages import printable

    if not os.path.lexists(path):
        raise ReportError(f"{shown(path)}: missing (a JUDGED folder is what `bogiemon fleet judge` writes)")
    try:
        text = read_untrusted(path, WAGONS_JSON, ReportError).decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ReportError(f"{shown(path)}: cannot be read (not UTF-8 text: byte {exc.start})") from None
    try:
        doc = json.loads(text, parse_constant=_not_a_number)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise ReportError(f"{path}: not valid JSON ({printable(str(exc))})") from None
    if not isinstance(doc, dict):
        raise ReportError(f"{path}: expected a JSON object")
    if "format" in doc and doc["format"] != JUDGED_FORMAT:
        raise ReportError(
            f"{path}: format {printable(repr(doc['format']), 20)}, this bogiemon reads format {JUDGED_FORMAT}: run `bogiemon fleet judge` again"
        )
    _check(doc, TOP_FIELDS, path, "")
    _check(doc["inputs"], INPUT_FIELDS, path, "inputs")
    for i, skipped in enumerate(doc["inputs"]["skipped"]):
        _check(skipped, SKIPPED_FIELDS, path, f"inputs.skipped[{i}]")
    seen: set[str] = set()
    for i, entry in enumerate(doc["wagons"]):
        where = f"wagons[{i}]"
        _check(entry, WAGON_FIELDS, path, where)
        if entry["state"] not in STATES:
            raise ReportError(f"{path}: {where}.state: {printable(entry['state'], 20)!r} is none of {', '.join(STATES)}")
        if entry["last_event"] is not None:
            _check(entry["last_event"], LAST_EVENT_FIELDS, path, f"{where}.last_event")
        if entry["diagnosis"] is not None:
            _check(entry["diagnosis"], DIAGNOSIS_FIELDS, path, f"{where}.diagnosis")
        if entry["fleet_relative"] is not None:
            _check(entry["fleet_relative"], FLEET_RELATIVE_FIELDS, path, f"{where}.fleet_relative")
        _strings(entry["commissioned"], path, f"{where}.commissioned")
        _strings(entry["notes"], path, f"{where}.notes")
        for channel, problems in entry["sensor_problems"].items():
            if not isinstance(problems, list):
                raise ReportError(f"{path}: {where}.sensor_problems.{printable(channel, 16)}: expected a list of strings")
            _strings(problems, path, f"{where}.sensor_problems.{printable(channel, 16)}")
        for bogie, d in entry["diagnosis_now"].items():
            _check(d, DIAGNOSIS_FIELDS, path, f"{where}.diagnosis_now.{printable(bogie, 16)}")
        if not all(isinstance(c, str) for c in entry["sensor_corners"].values()):
            raise ReportError(f"{path}: {where}.sensor_corners: expected channel -> corner names (strings)")
        if entry["wagon"] in seen:
            raise ReportError(f"{path}: {where}: wagon {printable(entry['wagon'])!r} is listed twice")
        seen.add(entry["wagon"])
    return doc


def _not_a_number(name: str) -> None:
    # NaN and Infinity (what Python's json writes for them) read as null: where a number must be,
    # the check then names the field; where null is allowed (a trend), it shows as none.
    return None


def read_events(path: Path) -> dict[str, list[EventMessage]]:
    """events.jsonl by wagon, each wagon's in time order; ReportError (naming the line) for a bad line."""
    from bogiemon.daemon.messages import EventMessage, SchemaError, decode

    by_wagon: dict[str, list[EventMessage]] = {}
    if not os.path.lexists(path):
        raise ReportError(f"{shown(path)}: missing (a JUDGED folder is what `bogiemon fleet judge` writes)")
    with open_untrusted(path, events_kind(), ReportError) as f:
        for number, raw in f.lines():
            if raw is None or not raw.strip():
                continue
            try:
                message = decode(EventMessage, raw)
            except SchemaError as exc:
                raise ReportError(f"{shown(path)}: line {number}: {exc}") from None
            by_wagon.setdefault(message.wagon_id, []).append(message)
    for events in by_wagon.values():
        events.sort(key=lambda m: (m.time_s, m.seq))
    return by_wagon


def read_series(path: Path) -> Series:
    """A wagon's series file; ReportError (naming the file and the column) when it is not per contract."""
    import pyarrow as pa
    import pyarrow.compute as pc

    from bogiemon.daemon.messages import TIME_S_MAX, TIME_S_MIN

    f, parquet = open_parquet(path, SERIES_FILE, ReportError)
    with f:
        names = parquet.schema_arrow.names
        for name in SERIES_COLUMNS:
            if name not in names:
                raise ReportError(f"{shown(path)}: missing column '{name}'")
        try:
            table = parquet.read(columns=list(SERIES_COLUMNS), use_threads=False)  # not the strings the page does not draw
        except (OSError, pa.ArrowException) as exc:
            raise ReportError(f"{shown(path)}: not a readable Parquet file ({one_line(exc)})") from None

    def floats(name: str) -> NDArray[np.float64]:
        try:
            column = pc.cast(table.column(name), pa.float64())
        except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
            raise ReportError(f"{path}: column '{name}': expected numbers") from None
        return np.asarray(column.to_numpy(zero_copy_only=False), dtype=np.float64)

    time_s = floats("time_s")
    if np.any((time_s < TIME_S_MIN) | (time_s > TIME_S_MAX)):  # NaN passes: such a row is dropped below
        raise ReportError(f"{path}: column 'time_s': a time outside Unix seconds {TIME_S_MIN:g} to {TIME_S_MAX:g}")
    try:
        judged = np.asarray(pc.fill_null(pc.cast(table.column("judged"), pa.bool_()), False).to_numpy(zero_copy_only=False), dtype=bool)
        mode = np.asarray(pc.fill_null(pc.cast(table.column("mode"), pa.string()), "").to_numpy(zero_copy_only=False), dtype=np.str_)
    except (pa.ArrowInvalid, pa.ArrowNotImplementedError):
        raise ReportError(f"{path}: columns 'judged' and 'mode': expected booleans and strings") from None
    arrays = {name: floats(name) for name in ("score", "trend", "warning", "alarm", "trend_warning", "trend_alarm")}
    valid = np.isfinite(time_s)
    order = np.argsort(time_s[valid], kind="stable")  # the contract says time order; a stray row is not drawn across
    pick = np.flatnonzero(valid)[order]
    return Series(
        time_s=time_s[pick],
        judged=judged[pick] & np.isfinite(arrays["score"][pick]),
        mode=mode[pick],
        **{name: a[pick] for name, a in arrays.items()},
    )


def read_judged(judged_dir: Path | str) -> Judged:
    """A JUDGED folder, checked: wagons.json, events.jsonl and each wagon's series."""
    root = Path(judged_dir)
    if not root.is_dir():
        raise ReportError(f"{shown(root)}: no such folder (a JUDGED folder is what `bogiemon fleet judge` writes)")
    doc = read_wagons_json(root / "wagons.json")
    events = read_events(root / "events.jsonl")
    pages = []
    for entry in sorted(doc["wagons"], key=lambda e: -float(e["attention"])):
        wagon = entry["wagon"]
        series, note = None, ""
        if not WAGON_ID.match(wagon):
            note = "its id is no folder name the back office writes: no series is read for it"
        else:
            path = root / "series" / f"wagon={wagon}" / "part-0.parquet"
            if os.path.lexists(path):
                series = read_series(path)  # a folder or a FIFO there is refused, naming it
            else:
                note = "no series file"
        pages.append(WagonPage(entry=entry, series=series, series_note=note, events=events.get(wagon, [])))
    return Judged(path=root, doc=doc, wagons=pages, events=sum(len(p.events) for p in pages))


