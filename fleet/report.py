"""The fleet on one page: a JUDGED folder (docs/fleet-formats.md section 3) as one static HTML file.

The page is what a keeper opens and mails: no server, no network, nothing outside the file (the
plots are inline SVG drawn by fleet/svg.py, the style is inline, and the one tiny script only
sorts the table: the page is complete without it). Every text that comes from the data (ids,
notes, reasons, paths) is escaped: those files were not written by the keeper.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from html import escape
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
from numpy.typing import NDArray

from bogiemon.daemon.delivery.schema import TIME_S_MAX, TIME_S_MIN, EventMessage, SchemaError, decode, printable
from bogiemon.fleet import svg

STATES = ("CONFIRMED", "SUSPECTED", "SENSOR_FAULT", "NORMAL", "NO_DATA")
EVENT_KINDS = ("SUSPECTED", "CONFIRMED", "CLEARED", "SENSOR_FAULT", "SENSOR_CLEARED")
# The colours a keeper learns once: the badges, the event markers and the plot lines.
STATE_COLOURS = {"CONFIRMED": "#c62828", "SUSPECTED": "#ffb300", "SENSOR_FAULT": "#7b1fa2", "NORMAL": "#2e7d32", "NO_DATA": "#757575"}
EVENT_COLOURS = {"SUSPECTED": "#e69500", "CONFIRMED": "#c62828", "CLEARED": "#2e7d32", "SENSOR_FAULT": "#7b1fa2", "SENSOR_CLEARED": "#546e7a"}
SCORE_COLOUR, TREND_COLOUR = "#1565c0", "#00838f"
WARNING_COLOUR, ALARM_COLOUR = "#e69500", "#c62828"

MAX_POINTS_PER_PANEL = 1500  # a line's points after decimation: about 1.6 per pixel column
MAX_GAP_HOPS = 3.5  # consecutive drawn windows further apart (in hops) are a gap: the line breaks
DEFAULT_HOP_S = 10.0  # the daemon's default hop, for a series too short to measure its own
MAX_EVENTS_LISTED = 200  # per wagon section; the plot marks every event
# A wagon id as the back office writes folders (docs/fleet-formats.md section 1); a series is
# read only for such an id, so a hostile id in wagons.json never names a path outside series/.
WAGON_ID = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9._-]{0,63}$")
SERIES_COLUMNS = ("time_s", "judged", "score", "trend", "warning", "alarm", "trend_warning", "trend_alarm", "mode")


class ReportError(ValueError):
    """A JUDGED folder the report cannot read, or an output it cannot write (one line)."""


@dataclass(frozen=True)
class ReportSummary:
    path: Path
    wagons: int
    bytes: int
    states: Mapping[str, int]  # wagons per state, every state listed
    events: int
    skipped_inputs: int
    points: int  # plotted points after decimation, all wagons and panels


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
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ReportError(f"{path}: missing (a JUDGED folder is what `bogiemon fleet judge` writes)") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ReportError(f"{path}: cannot be read ({printable(str(exc))})") from None
    try:
        doc = json.loads(text, parse_constant=_not_a_number)
    except (ValueError, RecursionError) as exc:  # JSONDecodeError is a ValueError
        raise ReportError(f"{path}: not valid JSON ({printable(str(exc))})") from None
    if not isinstance(doc, dict):
        raise ReportError(f"{path}: expected a JSON object")
    if "format" in doc and doc["format"] != 1:
        raise ReportError(f"{path}: format {printable(repr(doc['format']), 20)}, this bogiemon reads format 1")
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
    by_wagon: dict[str, list[EventMessage]] = {}
    try:
        with path.open("rb") as f:
            for number, raw in enumerate(f, start=1):
                if not raw.strip():
                    continue
                try:
                    message = decode(EventMessage, raw.rstrip(b"\r\n"))
                except SchemaError as exc:
                    raise ReportError(f"{path}: line {number}: {exc}") from None
                by_wagon.setdefault(message.wagon_id, []).append(message)
    except FileNotFoundError:
        raise ReportError(f"{path}: missing (a JUDGED folder is what `bogiemon fleet judge` writes)") from None
    except OSError as exc:
        raise ReportError(f"{path}: cannot be read ({printable(str(exc))})") from None
    for events in by_wagon.values():
        events.sort(key=lambda m: (m.time_s, m.seq))
    return by_wagon


def read_series(path: Path) -> Series:
    """A wagon's series file; ReportError (naming the file and the column) when it is not per contract."""
    try:
        names = pq.read_schema(path).names
        for name in SERIES_COLUMNS:
            if name not in names:
                raise ReportError(f"{path}: missing column '{name}'")
        table = pq.read_table(path, columns=list(SERIES_COLUMNS))  # not the strings the page does not draw
    except (OSError, pa.ArrowException) as exc:
        raise ReportError(f"{path}: not a readable Parquet file ({printable(str(exc))})") from None

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
        raise ReportError(f"{root}: no such folder (a JUDGED folder is what `bogiemon fleet judge` writes)")
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
            if path.is_file():
                series = read_series(path)
            else:
                note = "no series file"
        pages.append(WagonPage(entry=entry, series=series, series_note=note, events=events.get(wagon, [])))
    return Judged(path=root, doc=doc, wagons=pages, events=sum(len(p.events) for p in pages))


# ---------------------------------------------------------------------------------------------
# The page


def html_id(wagon: str) -> str:
    """The anchor of a wagon's section: letters, digits, '.', '_', '-' kept, anything else as ~hhhhhh.

    One id per wagon id ('~' is never kept, so the encoding cannot collide), safe in an attribute
    and in a URL fragment.
    """
    out = [c if c.isascii() and (c.isalnum() or c in "._-") else f"~{ord(c):06x}" for c in wagon]
    return "wagon-" + "".join(out)


def _e(value: Any) -> str:
    return escape(str(value), quote=True)


def _fmt(value: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


def _badge(state: str) -> str:
    return f'<span class="b b-{state}">{_e(state.replace("_", " "))}</span>'


CSS = """
body{font:14px/1.4 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 24px 48px;color:#212121;background:#fff}
h1{font-size:22px;margin:18px 0 4px}h2{font-size:17px;margin:0 0 6px}
.muted{color:#666}.small{font-size:12px}
.b{display:inline-block;padding:1px 8px;border-radius:9px;font-weight:600;font-size:12px;color:#fff;white-space:nowrap}
.b-CONFIRMED{background:#c62828}.b-SUSPECTED{background:#ffb300;color:#212121}.b-SENSOR_FAULT{background:#7b1fa2}
.b-NORMAL{background:#2e7d32}.b-NO_DATA{background:#757575}
.k-SUSPECTED{color:#b36b00}.k-CONFIRMED{color:#c62828}.k-CLEARED{color:#2e7d32}.k-SENSOR_FAULT{color:#7b1fa2}.k-SENSOR_CLEARED{color:#546e7a}
.counts span{margin-right:10px}
table{border-collapse:collapse}
table.fleet{width:100%;margin:10px 0 18px}
.fleet th,.fleet td{border-bottom:1px solid #e0e0e0;padding:4px 6px;text-align:left;vertical-align:top}
.fleet th{position:sticky;top:0;background:#f5f5f5;cursor:pointer;font-size:12px}
.fleet td.n{text-align:right;white-space:nowrap}.fleet .small{white-space:nowrap}
.fleet td.id{min-width:8.5em;overflow-wrap:anywhere}.fleet td.notes{min-width:12em;overflow-wrap:anywhere}
.fleet ul,.w ul{margin:0;padding-left:16px}
.bar{display:inline-block;width:56px;height:8px;background:#e0e0e0;border-radius:4px;vertical-align:middle;overflow:hidden;margin-right:4px}
.bar i{display:block;height:100%;background:#00838f}.bar i.over{background:#c62828}
.list td,.list th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left;font-size:12px}
section.w{border-top:2px solid #e0e0e0;padding:12px 0 8px;margin-top:12px}
.facts{margin:2px 0 6px}
svg.plot{display:block;max-width:100%;height:auto;margin:6px 0}
svg text{font-size:11px;fill:#555}
.g{stroke:#ececec}.ax{stroke:#9e9e9e;fill:none}
.s,.t,.lw,.la{fill:none;stroke-linejoin:round;stroke-linecap:round}
.s{stroke:#1565c0;stroke-width:1.6}.t{stroke:#00838f;stroke-width:1.6}
.lw{stroke:#e69500;stroke-width:1.2;stroke-dasharray:6 4}.la{stroke:#c62828;stroke-width:1.2;stroke-dasharray:6 4}
.e{stroke-width:1.2}
.e-SUSPECTED{stroke:#e69500}.e-CONFIRMED{stroke:#c62828}.e-CLEARED{stroke:#2e7d32}.e-SENSOR_FAULT{stroke:#7b1fa2}.e-SENSOR_CLEARED{stroke:#546e7a}
text.el{font-size:10px;font-weight:600}
.el-SUSPECTED{fill:#b36b00}.el-CONFIRMED{fill:#c62828}.el-CLEARED{fill:#2e7d32}.el-SENSOR_FAULT{fill:#7b1fa2}.el-SENSOR_CLEARED{fill:#546e7a}
.m-SUSPECTED{fill:#ffe082}.m-CONFIRMED{fill:#ef9a9a}
.brk{fill:#eeeeee;stroke:none}.bk{stroke:#616161;stroke-width:1.2}.gd{stroke:#bdbdbd}
text.dl{fill:#333;font-weight:600}text.gl{font-size:10px;fill:#757575}
.legend span{margin-right:14px;white-space:nowrap}
.sw{display:inline-block;width:18px;height:0;border-top:2px solid;vertical-align:middle;margin-right:4px}
.sw.d{border-top-style:dashed}
"""

# Sorting by a clicked column; the page says everything without it (no content depends on it).
SCRIPT = """
document.querySelectorAll("table.fleet th").forEach(function(th,i){th.addEventListener("click",function(){
var tb=th.closest("table").tBodies[0],rows=Array.prototype.slice.call(tb.rows),d=th.dataset.dir==="a"?-1:1;
rows.sort(function(a,b){var x=a.cells[i].dataset.v,y=b.cells[i].dataset.v;
if(x===undefined||y===undefined){return d*a.cells[i].textContent.localeCompare(b.cells[i].textContent);}
return d*(parseFloat(x)-parseFloat(y));});
th.dataset.dir=d===1?"a":"d";rows.forEach(function(r){tb.appendChild(r);});});});
"""


def _diagnosis(d: Mapping[str, Any] | None) -> str:
    unknown = (None, "unknown")
    if d is None or (d["corner"] in unknown and d["kind"] in unknown):
        return '<span class="muted">unknown</span>'

    def part(name: str, confidence: float | None) -> str:
        if name in unknown:
            return '<span class="muted">unknown</span>'
        return _e(name) + ("" if confidence is None else f" ({confidence:.0%})")

    return f"{part(d['corner'], d['corner_confidence'])} · {part(d['kind'], d['kind_confidence'])}"


def _problems(p: Mapping[str, Sequence[str]]) -> str:
    if not p:
        return '<span class="muted">none</span>'
    return "<br>".join(f"{_e(ch)}: {_e(', '.join(ps))}" for ch, ps in p.items())


def _trend_cell(trend: float | None, alarm: float | None) -> tuple[str, str]:
    if trend is None:
        return "", '<span class="muted">–</span>'
    if alarm is None or alarm <= 0:
        return f"{trend:.6g}", _fmt(trend)
    frac = trend / alarm
    width = max(0.0, min(frac, 1.0)) * 100
    over = ' class="over"' if frac >= 1 else ""
    bar = f'<span class="bar" title="{frac:.0%} of the alarm level"><i{over} style="width:{width:.0f}%"></i></span>'
    return f"{frac:.6g}", f"{bar}{_fmt(trend)} / {_fmt(alarm)}"


def _fleet_relative(f: Mapping[str, Any] | None) -> str:
    if f is None:
        return '<span class="muted">–</span>'
    head = "<b>yes</b>" if f["stands_out"] else "no"
    why = f": {_e(f['why'])}" if f["why"] else ""
    extra = f"baseline distance {_fmt(f['baseline_distance'])}, trend rank {_fmt(f['trend_rank'])}"
    return f'<span title="{_e(extra)}">{head}{why}</span>'


def _notes(notes: Sequence[str]) -> str:
    if not notes:
        return ""
    return "<ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>"


def _last_event(ev: Mapping[str, Any] | None) -> tuple[str, str]:
    if ev is None:
        return "0", '<span class="muted">none</span>'
    kind = ev["kind"]
    cls = f"k-{kind}" if kind in EVENT_KINDS else ""
    return f"{ev['time_s']:.6f}", f'<span class="{cls}">{_e(kind)}</span><br><span class="small">{_e(ev["time_utc"])}</span>'


def _table(pages: Sequence[WagonPage]) -> str:
    head = ["Wagon", "Type", "State", "Attention", "Last event", "Diagnosis", "Sensor problems", "Trend / alarm", "Stands out", "Commissioned", "Days", "Windows judged / total", "Notes"]
    rows = []
    for page in pages:
        e = page.entry
        wagon = e["wagon"]
        ev_v, ev_html = _last_event(e["last_event"])
        tr_v, tr_html = _trend_cell(e["trend"], e["trend_alarm"])
        tr_attr = f' data-v="{tr_v}"' if tr_v else ""  # a wagon without a trend sorts by its text
        days_title = f"{e['first_day'] or '–'} to {e['last_day'] or '–'}"
        windows_title = f"{e['gated']} gated, {e['sensor_fault_windows']} with a sensor fault"
        commissioned = _e(", ".join(e["commissioned"])) if e["commissioned"] else '<span class="k-SUSPECTED">none</span>'
        cells = [
            f'<td class="id"><a href="#{_e(html_id(wagon))}">{_e(wagon)}</a></td>',
            f"<td>{_e(e['type'])}</td>",
            f'<td data-v="{len(STATES) - STATES.index(e["state"])}">{_badge(e["state"])}</td>',
            f'<td class="n" data-v="{e["attention"]:.6g}">{_fmt(e["attention"])}</td>',
            f'<td data-v="{ev_v}">{ev_html}</td>',
            f'<td>{_diagnosis(e["diagnosis"])}</td>',
            f"<td>{_problems(e['sensor_problems'])}</td>",
            f'<td class="n"{tr_attr}>{tr_html}</td>',
            f'<td>{_fleet_relative(e["fleet_relative"])}</td>',
            f"<td>{commissioned}</td>",
            f'<td class="n" data-v="{e["days"]}" title="{_e(days_title)}">{e["days"]}</td>',
            f'<td class="n" data-v="{e["judged"]}" title="{_e(windows_title)}">{e["judged"]} / {e["windows"]}</td>',
            f'<td class="notes">{_notes(e["notes"])}</td>',
        ]
        rows.append("<tr>" + "".join(cells) + "</tr>")
    ths = "".join(f"<th>{_e(h)}</th>" for h in head)
    return f'<table class="fleet" id="fleet"><thead><tr>{ths}</tr></thead><tbody>\n' + "\n".join(rows) + "\n</tbody></table>"


# The plot's layout, in viewBox pixels.
W_PX, LEFT_PX, RIGHT_PX = 1000.0, 58.0, 986.0
LANES_PX = (12.0, 24.0, 36.0)  # the baselines of the event labels' rows
MODE_TOP_PX, MODE_BOTTOM_PX = 42.0, 48.0
SCORE_TOP_PX, SCORE_BOTTOM_PX = 50.0, 210.0
GAP_LABEL_PX = 223.5  # the baseline of the gaps' lengths, in the free strip between the panels
TREND_TOP_PX, TREND_BOTTOM_PX = 230.0, 330.0
TICKS_PX, DATES_PX = 344.0, 358.0  # the baselines of the time labels and of the dates under them
H_PX = 364.0
# The broken time axis: an idle stretch longer than MAX_IDLE_S (a night, a stop between runs) is
# cut to GAP_PX, enough for its break mark and mostly for its length; shorter pauses keep their
# true width, so the runs of a day still read as a day.
MAX_IDLE_S = 600.0
GAP_PX = 24.0
GAP_CHAR_PX = 5.7  # a character of the gaps' 10 px labels


@dataclass
class _Plot:
    parts: list[str] = field(default_factory=list)
    points: int = 0


def _hop_s(time_s: NDArray[np.float64]) -> float:
    if time_s.size < 2:
        return DEFAULT_HOP_S
    diffs = np.diff(time_s)
    diffs = diffs[diffs > 0]
    return float(np.median(diffs)) if diffs.size else DEFAULT_HOP_S


def _panel(plot: _Plot, series: Series, names: tuple[str, str, str], top_px: float, bottom_px: float, axis: svg.BrokenAxis, label: str) -> None:
    value_name, warning_name, alarm_name = names
    values: NDArray[np.float64] = getattr(series, value_name)
    judged = series.judged & np.isfinite(values)
    time_s = series.time_s[judged]
    v = values[judged]
    warning = getattr(series, warning_name)[judged]
    alarm = getattr(series, alarm_name)[judged]
    levels = np.concatenate((warning[np.isfinite(warning)], alarm[np.isfinite(alarm)]))
    lo, hi = svg.log_range(v, [float(levels.min()), float(levels.max())] if levels.size else [])
    p = plot.parts
    for value, tick in svg.decade_ticks(lo, hi):
        y = float(svg.log_px(np.array([value]), lo, hi, top_px, bottom_px)[0])
        p.append(svg.line(LEFT_PX, y, RIGHT_PX, y, "g"))
        p.append(svg.text(LEFT_PX - 4, y + 4, tick, anchor="end"))
    p.append(svg.rect(LEFT_PX, top_px, RIGHT_PX - LEFT_PX, bottom_px - top_px, "ax"))
    _breaks(plot, axis, top_px, bottom_px)
    p.append(svg.text(LEFT_PX + 6, top_px + 13, label))
    if time_s.size == 0:
        p.append(svg.text((LEFT_PX + RIGHT_PX) / 2, (top_px + bottom_px) / 2, "no judged windows", anchor="middle"))
        return
    segments = svg.gap_segments(time_s, MAX_GAP_HOPS * _hop_s(series.time_s))
    n_segments = int(segments[-1]) + 1
    buckets = max(MAX_POINTS_PER_PANEL - n_segments, 100)
    # The buckets are columns of the drawn (broken) axis, not stretches of time: a run keeps its
    # share of the points whatever the nights around it.
    dx, dv, ds = svg.decimate_max(axis.px(time_s), v, segments, LEFT_PX, RIGHT_PX, buckets)
    for cls, level in (("lw", warning), ("la", alarm)):
        ok = np.isfinite(level)
        keep = svg.run_ends(level[ok], segments[ok])
        lt, lv, ls = time_s[ok][keep], level[ok][keep], segments[ok][keep]
        d = svg.path_d(axis.px(lt), svg.log_px(lv, lo, hi, top_px, bottom_px), ls)
        if d:
            p.append(f'<path class="{cls}" d="{d}"/>')
    p.append(f'<path class="{"s" if value_name == "score" else "t"}" d="{svg.path_d(dx, svg.log_px(dv, lo, hi, top_px, bottom_px), ds)}"/>')
    plot.points += int(dx.size)


def _breaks(plot: _Plot, axis: svg.BrokenAxis, top_px: float, bottom_px: float) -> None:
    # Each cut gap as a shaded band over the panel, interrupting its frame, with a double slash
    # across the frame's top and bottom edges (left out where many gaps leave too little room).
    for gap in axis.gaps:
        width = gap.right_px - gap.left_px
        tip = f"no data for {svg.duration_label(gap.duration_s)}: {svg.utc_label(gap.start_s)} to {svg.utc_label(gap.end_s)} (cut from the axis)"
        plot.parts.append(svg.rect(gap.left_px, top_px - 1, width, bottom_px - top_px + 2, "brk", tip))
        if width < 8.0:
            continue
        mid = (gap.left_px + gap.right_px) / 2
        for y in (top_px, bottom_px):
            for dx in (-2.5, 2.5):
                plot.parts.append(svg.line(mid + dx - 2.5, y + 4, mid + dx + 2.5, y - 4, "bk"))


def _time_axis(plot: _Plot, axis: svg.BrokenAxis) -> None:
    # Ticks at round UTC times on the data stretches, each day's date at its first data, and the
    # length of each cut gap where it fits.
    p = plot.parts
    for t, label in svg.axis_ticks(axis):
        x = float(axis.px(t))
        half = svg.CHAR_PX * len(label) / 2
        if x - half < LEFT_PX - 2 or x + half > W_PX:  # into the "UTC" on the left, or off the plot
            continue
        p.append(svg.line(x, SCORE_TOP_PX, x, TREND_BOTTOM_PX, "g"))
        p.append(svg.text(x, TICKS_PX, label, anchor="middle"))
    starts_px = set(np.round(axis.start_px, 6).tolist())
    for t, label in svg.day_labels(axis):
        x = float(axis.px(t))
        if round(x, 6) not in starts_px:  # a midnight within a run; after a cut night the band is the boundary
            p.append(svg.line(x, SCORE_TOP_PX, x, SCORE_BOTTOM_PX, "gd"))
            p.append(svg.line(x, TREND_TOP_PX, x, TREND_BOTTOM_PX, "gd"))
        p.append(svg.line(x, TREND_BOTTOM_PX, x, DATES_PX - 10, "gd"))
        p.append(svg.text(min(x + 2, W_PX - svg.CHAR_PX * len(label)), DATES_PX, label, cls="dl"))  # a last day near the end stays on the plot
    end_px = -math.inf
    for gap in axis.gaps:
        text = svg.duration_label(gap.duration_s)
        width = GAP_CHAR_PX * len(text)
        mid = (gap.left_px + gap.right_px) / 2
        if mid - width / 2 >= max(end_px + 4, LEFT_PX) and mid + width / 2 <= RIGHT_PX:
            p.append(svg.text(mid, GAP_LABEL_PX, text, cls="gl", anchor="middle"))
            end_px = mid + width / 2
    p.append(svg.text(LEFT_PX - 4, TICKS_PX, "UTC", anchor="end"))


def _mode_strip(plot: _Plot, series: Series, axis: svg.BrokenAxis) -> None:
    # The decision's mode after each window, as a thin band: when the wagon was suspected or in alarm.
    if series.time_s.size == 0:
        return
    x = axis.px(series.time_s)
    segments = svg.gap_segments(series.time_s, MAX_GAP_HOPS * _hop_s(series.time_s))
    change = np.ones(x.size, dtype=bool)
    change[1:] = (series.mode[1:] != series.mode[:-1]) | (segments[1:] != segments[:-1])
    starts = np.flatnonzero(change)
    ends = np.concatenate((starts[1:] - 1, [x.size - 1]))
    runs: list[list[Any]] = []  # [mode, x0, x1]
    for s, e in zip(starts.tolist(), ends.tolist(), strict=True):
        mode = str(series.mode[s])
        if mode not in ("SUSPECTED", "CONFIRMED"):
            continue
        x0, x1 = float(x[s]), max(float(x[e]), float(x[s]) + 1.0)
        if runs and runs[-1][0] == mode and x0 - runs[-1][2] < 1.0:
            runs[-1][2] = x1  # within a pixel of the last run of the same mode: one rectangle
        else:
            runs.append([mode, x0, x1])
    for mode, x0, x1 in runs:
        plot.parts.append(svg.rect(x0, MODE_TOP_PX, x1 - x0, MODE_BOTTOM_PX - MODE_TOP_PX, f"m-{mode}"))


def _event_marks(plot: _Plot, events: Sequence[EventMessage], axis: svg.BrokenAxis) -> None:
    lane_end = [-1e9] * len(LANES_PX)
    for ev in events:
        # At its true time: an event is a window's end, so it lies on the data; one that does not
        # (a stray line) is drawn at the start of the gap it falls in, never inside a cut band.
        x = float(axis.px(axis.snap(ev.time_s)))
        tip = f"{ev.kind} {svg.utc_label(ev.time_s)} (seq {ev.seq})"
        plot.parts.append(svg.line(x, MODE_TOP_PX, x, TREND_BOTTOM_PX, f"e e-{ev.kind}", tip))
        # A label in the first row where it does not overlap the one before; none if no row is free
        # (the line and its tooltip still say it).
        width = svg.CHAR_PX * len(ev.kind)
        anchor_right = x + width > RIGHT_PX
        start, end = (x - width - 2, x) if anchor_right else (x + 2, x + 2 + width)
        for lane, end_before in enumerate(lane_end):
            if start > end_before + 4:
                lane_end[lane] = end
                plot.parts.append(svg.text(x - 2 if anchor_right else x + 2, LANES_PX[lane], ev.kind, cls=f"el el-{ev.kind}", anchor="end" if anchor_right else ""))
                break


def _broken_axis(series: Series, events: Sequence[EventMessage]) -> svg.BrokenAxis | None:
    """The plot's broken time axis: from the series' windows (the events' times when there is no
    series), idle gaps over MAX_IDLE_S cut; None when there is no time at all."""
    time_s = series.time_s if series.time_s.size else np.array([m.time_s for m in events], dtype=np.float64)
    if time_s.size == 0:
        return None
    # Never cut a pause the line does not break at: a series with a long hop keeps its line whole.
    max_idle_s = max(MAX_IDLE_S, MAX_GAP_HOPS * _hop_s(series.time_s))
    return svg.broken_axis(time_s, LEFT_PX, RIGHT_PX, max_idle_s, GAP_PX)


def _plot(page: WagonPage) -> tuple[str, int]:
    s = page.series if page.series is not None else EMPTY_SERIES
    found = _broken_axis(s, page.events)
    # Without any time the panels are drawn empty on a placeholder axis, with no time labels.
    axis = found if found is not None else svg.broken_axis(np.zeros(1), LEFT_PX, RIGHT_PX, MAX_IDLE_S, GAP_PX)
    plot = _Plot()
    if found is not None:
        _time_axis(plot, axis)
    _mode_strip(plot, s, axis)
    _panel(plot, s, ("score", "warning", "alarm"), SCORE_TOP_PX, SCORE_BOTTOM_PX, axis, "fused score")
    _panel(plot, s, ("trend", "trend_warning", "trend_alarm"), TREND_TOP_PX, TREND_BOTTOM_PX, axis, "trend")
    _event_marks(plot, page.events, axis)
    label = f"fused score and trend of {page.entry['wagon']} over time"
    body = "".join(plot.parts)
    return (
        f'<svg class="plot" viewBox="0 0 {W_PX:g} {H_PX:g}" width="{W_PX:g}" height="{H_PX:g}" role="img" aria-label="{_e(label)}">{body}</svg>',
        plot.points,
    )


def _event_summary(m: EventMessage) -> str:
    parts = [f"{name} {_fmt(v)}" for name, v in m.indicators.items()]
    problems = m.details.get("problems")
    if isinstance(problems, dict):
        parts += [f"{ch}: {', '.join(str(p) for p in ps)}" for ch, ps in problems.items() if isinstance(ps, list)]
    return _e("; ".join(parts))


def _events_list(events: Sequence[EventMessage]) -> str:
    if not events:
        return '<p class="small muted">No events.</p>'
    shown = events[-MAX_EVENTS_LISTED:]
    more = f" (the last {len(shown)} listed)" if len(shown) < len(events) else ""
    rows = "".join(
        f'<tr><td>{m.seq}</td><td>{_e(svg.utc_label(m.time_s))}</td><td class="k-{m.kind}">{_e(m.kind)}</td><td>{_event_summary(m)}</td></tr>' for m in shown
    )
    return (
        f"<details><summary>{len(events)} event{'s' if len(events) != 1 else ''}{more}</summary>"
        f'<table class="list"><thead><tr><th>seq</th><th>time (UTC)</th><th>kind</th><th>values</th></tr></thead><tbody>{rows}</tbody></table></details>'
    )


def _section(page: WagonPage) -> tuple[str, int]:
    e = page.entry
    plot, points = _plot(page)
    facts = [
        f"{_e(e['type'])}",
        f"{e['days']} day{'s' if e['days'] != 1 else ''} ({_e(e['first_day'] or '–')} to {_e(e['last_day'] or '–')})",
        f"{e['judged']} of {e['windows']} windows judged ({e['gated']} gated, {e['sensor_fault_windows']} with a sensor fault)",
        f"diagnosis: {_diagnosis(e['diagnosis'])}",
        f"stands out: {_fleet_relative(e['fleet_relative'])}",
    ]
    note = f'<p class="small muted">Series: {_e(page.series_note)}.</p>' if page.series_note else ""
    return (
        f'<section class="w" id="{_e(html_id(e["wagon"]))}"><h2>{_e(e["wagon"])} {_badge(e["state"])}</h2>'
        f'<p class="facts small">{" · ".join(facts)} · <a href="#fleet">fleet table</a></p>'
        f"{_notes(e['notes'])}{note}{plot}{_events_list(page.events)}</section>",
        points,
    )


def _legend() -> str:
    items = [
        f'<span><i class="sw" style="border-color:{SCORE_COLOUR}"></i>fused score</span>',
        f'<span><i class="sw" style="border-color:{TREND_COLOUR}"></i>trend</span>',
        f'<span><i class="sw d" style="border-color:{WARNING_COLOUR}"></i>warning level</span>',
        f'<span><i class="sw d" style="border-color:{ALARM_COLOUR}"></i>alarm level</span>',
    ]
    items += [f'<span class="k-{k}">| {k}</span>' for k in EVENT_KINDS]
    return '<p class="legend small">' + "".join(items) + f" (events; log scales, UTC; an idle gap over {MAX_IDLE_S / 60:.0f} min is cut to a grey band with its length)</p>"


def render(judged: Judged, title: str | None = None, written_utc: datetime | None = None) -> tuple[str, int]:
    """The page's HTML and how many points its plots draw."""
    doc = judged.doc
    fleet = doc["fleet"]
    title = title if title is not None else (f"{fleet}: fleet report" if fleet else "Fleet report")
    written = (written_utc or datetime.now(UTC)).astimezone(UTC).strftime("%Y-%m-%d %H:%M:%SZ")
    counts = {s: sum(1 for p in judged.wagons if p.entry["state"] == s) for s in STATES}
    inputs = doc["inputs"]
    skipped = inputs["skipped"]
    skipped_rows = "".join(f"<tr><td>{_e(s['path'])}</td><td>{_e(s['reason'])}</td></tr>" for s in skipped)
    skipped_html = (
        f'<details><summary>{len(skipped)} input{"s" if len(skipped) != 1 else ""} skipped</summary>'
        f'<table class="list"><thead><tr><th>input</th><th>reason</th></tr></thead><tbody>{skipped_rows}</tbody></table></details>'
        if skipped
        else '<p class="small muted">No input skipped.</p>'
    )
    sections, points = [], 0
    for page in judged.wagons:
        html_section, n = _section(page)
        sections.append(html_section)
        points += n
    header = (
        f"<header><h1>{_e(title)}</h1>"
        f'<p class="muted small">Fleet {_e(fleet)} · judged {_e(doc["generated_utc"])} · page written {written}</p>'
        f'<p class="counts">{len(judged.wagons)} wagons: '
        + "".join(f"<span>{_badge(s)} {counts[s]}</span>" for s in STATES)
        + f'</p><p class="small">Inputs: {inputs["wagons"]} wagons, {inputs["recordings"]} recordings, {len(skipped)} skipped.</p>'
        f"{skipped_html}</header>"
    )
    page = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>\n{header}\n"
        f"<h2>Wagons by need of attention</h2>{_table(judged.wagons)}\n{_legend()}\n"
        + "\n".join(sections)
        + f"\n<script>{SCRIPT}</script>\n</body></html>\n"
    )
    return page, points


def write_report(judged_dir: Path | str, out_path: Path | str, title: str | None = None) -> ReportSummary:
    """Write the fleet's page for a JUDGED folder to out_path (atomically); ReportError for bad input."""
    judged = read_judged(judged_dir)
    page, points = render(judged, title)
    out = Path(out_path)
    data = page.encode("utf-8")
    tmp = out.with_name(f".{out.name}.tmp-{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, out)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ReportError(f"{out}: cannot be written ({exc.strerror or exc})") from None
    counts = {s: sum(1 for p in judged.wagons if p.entry["state"] == s) for s in STATES}
    return ReportSummary(
        path=out,
        wagons=len(judged.wagons),
        bytes=len(data),
        states=counts,
        events=judged.events,
        skipped_inputs=len(judged.doc["inputs"]["skipped"]),
        points=points,
    )
