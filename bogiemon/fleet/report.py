"""The fleet on one page: a JUDGED folder (docs/fleet-formats.md section 3) as one static HTML file.

The page is what a keeper opens and mails: no server, no network, nothing outside the file (the
plots are inline SVG drawn by fleet/svg.py, the style is inline, and the one tiny script only
sorts the table: the page is complete without it). Every text that comes from the data (ids,
notes, reasons, paths) is escaped: those files were not written by the keeper.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from html import escape
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bogiemon.judgement.events import SensorFaultDetails
from bogiemon.drivers.atomic import write_bytes_atomically
from bogiemon.fleet import svg
from bogiemon.fleet.paths import output_file, shown
from bogiemon.fleet.judged_files import EVENT_KINDS, STATES, Judged, ReportError, WagonPage, read_judged
from bogiemon.fleet.plot import (
    ALARM_COLOUR, EVENT_COLOURS, EVENT_TEXT_COLOURS, MAX_IDLE_S, SCORE_COLOUR, STATE_COLOURS, TREND_COLOUR, WARNING_COLOUR, wagon_plot,
)  # fmt: skip

if TYPE_CHECKING:  # pydantic's models are built only when events are read (read_judged)
    from bogiemon.daemon.messages import EventMessage

MAX_EVENTS_LISTED = 200  # per wagon section; the plot marks every event

@dataclass(frozen=True)
class ReportSummary:
    path: Path
    wagons: int
    bytes: int
    states: Mapping[str, int]  # wagons per state, every state listed
    events: int
    skipped_inputs: int
    points: int  # plotted points after decimation, all wagons and panels


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
.b-SUSPECTED{color:#212121}
.counts span{margin-right:10px}
table{border-collapse:collapse}
table.fleet{width:100%;margin:10px 0 18px}
.fleet th,.fleet td{border-bottom:1px solid #e0e0e0;padding:4px 6px;text-align:left;vertical-align:top}
.fleet th{position:sticky;top:0;background:#f5f5f5;cursor:pointer;font-size:12px}
.fleet td.n{text-align:right;white-space:nowrap}.fleet .small{white-space:nowrap}
.fleet td.id{min-width:8.5em;overflow-wrap:anywhere}.fleet td.notes{min-width:12em;overflow-wrap:anywhere}
.fleet ul,.w ul{margin:0;padding-left:16px}
.bar{display:inline-block;width:56px;height:8px;background:#e0e0e0;border-radius:4px;vertical-align:middle;overflow:hidden;margin-right:4px}
.bar i{display:block;height:100%}
.list td,.list th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left;font-size:12px}
section.w{border-top:2px solid #e0e0e0;padding:12px 0 8px;margin-top:12px}
.facts{margin:2px 0 6px}
svg.plot{display:block;max-width:100%;height:auto;margin:6px 0}
svg text{font-size:11px;fill:#555}
.g{stroke:#ececec}.ax{stroke:#9e9e9e;fill:none}
.s,.t,.lw,.la{fill:none;stroke-linejoin:round;stroke-linecap:round}
.s,.t{stroke-width:1.6}.lw,.la{stroke-width:1.2;stroke-dasharray:6 4}
.e{stroke-width:1.2}
text.el{font-size:10px;font-weight:600}
.m-suspected{fill:#ffe082}.m-confirmed{fill:#ef9a9a}
.brk{fill:#eeeeee;stroke:none}.bk{stroke:#616161;stroke-width:1.2}.gd{stroke:#bdbdbd}
text.dl{fill:#333;font-weight:600}text.gl{font-size:10px;fill:#757575}
.legend span{margin-right:14px;white-space:nowrap}
.sw{display:inline-block;width:18px;height:0;border-top:2px solid;vertical-align:middle;margin-right:4px}
.sw.d{border-top-style:dashed}
"""
# The colours, from the constants the plot and the tests use: one place to change them.
CSS += "".join(f".b-{k}{{background:{c}}}" for k, c in STATE_COLOURS.items()) + "\n"
CSS += "".join(f".k-{k}{{color:{c}}}.el-{k}{{fill:{c}}}" for k, c in EVENT_TEXT_COLOURS.items()) + "\n"
CSS += "".join(f".e-{k}{{stroke:{c}}}" for k, c in EVENT_COLOURS.items()) + "\n"
CSS += (f".s{{stroke:{SCORE_COLOUR}}}.t{{stroke:{TREND_COLOUR}}}.lw{{stroke:{WARNING_COLOUR}}}.la{{stroke:{ALARM_COLOUR}}}"
        f".bar i{{background:{TREND_COLOUR}}}.bar i.over{{background:{ALARM_COLOUR}}}\n")


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


def _event_summary(m: EventMessage) -> str:
    parts = [f"{name} {_fmt(v)}" for name, v in m.indicators.items()]
    details = m.details_record()
    if isinstance(details, SensorFaultDetails):
        parts += [f"{ch}: {', '.join(ps)}" for ch, ps in details.problems.items()]
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
    plot, points = wagon_plot(page)
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
    html = (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<title>{_e(title)}</title><style>{CSS}</style></head><body>\n{header}\n"
        f"<h2>Wagons by need of attention</h2>{_table(judged.wagons)}\n{_legend()}\n"
        + "\n".join(sections)
        + f"\n<script>{SCRIPT}</script>\n</body></html>\n"
    )
    return html, points


def write_report(judged_dir: Path | str, out_path: Path | str, title: str | None = None) -> ReportSummary:
    """Write the fleet's page for a JUDGED folder to out_path (atomically); ReportError for bad input."""
    out = output_file(out_path, ReportError, "the report", {"JUDGED": judged_dir})
    judged = read_judged(judged_dir)
    page, points = render(judged, title)
    # A lone surrogate a hostile JSON string escaped (\\udcff) has no UTF-8: it shows as '?'.
    data = page.encode("utf-8", "replace")
    try:
        write_bytes_atomically(out, data)
    except OSError as exc:
        raise ReportError(f"{shown(out)}: cannot be written ({exc.strerror or exc})") from None
    counts = {s.value: sum(1 for p in judged.wagons if p.entry["state"] == s) for s in STATES}
    return ReportSummary(
        path=out,
        wagons=len(judged.wagons),
        bytes=len(data),
        states=counts,
        events=judged.events,
        skipped_inputs=len(judged.doc["inputs"]["skipped"]),
        points=points,
    )
