"""The work list's page (index.html of a report): one line per wagon, most urgent first, searchable.

The page is one file with its style and a small script inline: nothing outside it is asked for
but the wagons' own pages, which its rows link to. The script only filters and sorts; without it
every line is shown, in the order of need. Below NARROW_PX (style.py) the rows become cards, so
that the page reads on a tablet held upright without scrolling sideways. Every text from the data
is escaped: those files were not written by the keeper.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from bogiemon.fleet.judged_files import STATES
from bogiemon.fleet.style import WORK_CSS, badge, e, page
from bogiemon.fleet.worklist import STALE_AFTER_S, WorkLine, utc

# Filter and sort; the page says everything without it.
SCRIPT = """
(function(){
var tb=document.getElementById("work").tBodies[0],rows=Array.prototype.slice.call(tb.rows);
var text=rows.map(function(r){return r.textContent.toLowerCase();});
function el(i){return document.getElementById(i);}
var q=el("q"),fs=el("fs"),ft=el("ft"),fc=el("fc"),fx=el("fx"),n=el("n");
function apply(){var s=q.value.trim().toLowerCase(),k=0;
rows.forEach(function(r,i){var d=r.dataset;var ok=(!s||text[i].indexOf(s)>=0)&&(!fs.value||d.state===fs.value)&&
(!ft.value||d.type===ft.value)&&(!fc.value||d.comm===fc.value)&&(!fx.checked||d.changed!=="same");
r.hidden=!ok;if(ok){k++;}});n.textContent=k;}
[q,fs,ft,fc,fx].forEach(function(x){x.addEventListener("input",apply);x.addEventListener("change",apply);});
document.querySelectorAll(".counts button").forEach(function(b){b.addEventListener("click",function(){fs.value=b.dataset.state;apply();});});
document.querySelectorAll("table.work th").forEach(function(th,i){th.addEventListener("click",function(){
var d=th.dataset.dir==="a"?-1:1;rows.sort(function(a,b){var x=a.cells[i].dataset.v,y=b.cells[i].dataset.v;
if(x===undefined||y===undefined){return d*a.cells[i].textContent.localeCompare(b.cells[i].textContent);}return d*(parseFloat(x)-parseFloat(y));});
th.dataset.dir=d===1?"a":"d";rows.forEach(function(r){tb.appendChild(r);});});});
apply();
})();
"""
COMMISSIONED = {"both": "full and tare", "full": "full only", "tare": "tare only", "none": "not commissioned"}
HEAD = ("Wagon", "State", "What to do", "Since", "How sure", "Changed", "Last data", "Sensor faults", "Alarms", "Type", "Commissioned")


def commissioned_key(loads: Sequence[str]) -> str:
    """The commissioned filter's value of a wagon: both, full, tare or none."""
    has = set(loads)
    return "both" if {"full", "tare"} <= has else "full" if "full" in has else "tare" if "tare" in has else "none"


def _nw(text: str) -> str:
    return f'<span class="nw">{e(text)}</span>' if text else ""


def _row(line: WorkLine) -> str:
    notes = "".join(f'<div class="nt">{e(n)}</div>' for n in line.notes)
    sure = line.sure
    sure_html = (
        f'<span class="sure" title="{e(sure.explained)}">{e(sure.word)}{" · " + e(sure.figure) if sure.figure else ""}</span>' if sure.word else ""
    )
    changed = f'<span class="ch-{e(line.changed)}">{e(line.changed)}</span>' + (f" <span class=\"small\">{e(line.changed_text)}</span>" if line.changed_text else "")
    data = _nw(utc(line.last_data_s)) + (' <span class="stale">stale</span>' if line.stale else "")
    sensor = f"{line.sensor_faults} ({line.sensor_fault_windows} of {line.windows} windows)" if line.sensor_faults or line.sensor_fault_windows else ""
    alarms = ", ".join(p for p in (f"{line.alarms} confirmed" if line.alarms else "", f"{line.suspicions} suspected" if line.suspicions else "") if p)
    comm = commissioned_key(line.commissioned)
    state_rank = len(STATES) - STATES.index(line.state)
    cells = [
        f'<td class="id"><a href="{e(line.page)}">{e(line.wagon)}</a></td>',
        f'<td class="st" data-v="{state_rank}">{badge(line.state.value)}</td>',
        f'<td class="act">{e(line.action)}{notes}</td>',
        f'<td class="n" data-l="since" data-v="{line.since_s or 0:.0f}">{_nw(utc(line.since_s))}</td>',
        f'<td data-l="how sure">{sure_html}</td>',
        f'<td data-l="changed" data-v="{("same", "better", "new", "worse").index(line.changed)}">{changed}</td>',
        f'<td class="n" data-l="last data" data-v="{line.last_data_s or 0:.0f}">{data}</td>',
        f'<td data-l="sensor faults" data-v="{line.sensor_fault_windows}">{sensor}</td>',
        f'<td data-l="alarms" data-v="{line.alarms * 1000 + line.suspicions}">{alarms}</td>',
        f'<td data-l="type">{e(line.type)}</td>',
        f'<td data-l="commissioned">{e(", ".join(line.commissioned)) or "none"}</td>',
    ]
    attrs = f'data-state="{line.state.value}" data-type="{e(line.type)}" data-comm="{comm}" data-changed="{e(line.changed)}"'
    return f"<tr {attrs}>" + "".join(cells) + "</tr>"


def _options(values: Sequence[str], labels: Mapping[str, str] | None = None) -> str:
    return "".join(f'<option value="{e(v)}">{e((labels or {}).get(v, v))}</option>' for v in values)


def _legend(compare: str) -> str:
    return (
        '<dl class="legend"><dt>How sure</dt><dd>A word and the figure behind it (hover it for the sentence): for a suspension, '
        "the trend of the wagon's fused score as a multiple of its alarm level (\"22x alarm\": 22 times the level that no healthy "
        "wagon of the fitting fleet crossed; clear from 3x); for a sensor, how many of the period's windows its problem held "
        "back from the judgement.</dd>"
        f"<dt>Changed</dt><dd>The state now against the state {e(compare)}, from the wagon's own events: worse, better, new "
        "(no data then) or same, and the events since.</dd>"
        f"<dt>Last data</dt><dd>The end of the wagon's newest window; stale when it lies more than {STALE_AFTER_S / 86400:.0f} days "
        "before the fleet's newest: its gateway stopped recording or uploading.</dd>"
        "<dt>Sensor faults, Alarms</dt><dd>In the whole period judged, those that cleared too: sensor faults reported (and the "
        "windows they held back), alarms confirmed and suspected.</dd></dl>"
    )


def render(
    lines: Sequence[WorkLine], doc: Mapping[str, Any], title: str, written: str, compare: str, data_until_s: float | None, changed_only: bool
) -> str:
    """The work list's page."""
    counts = {s: sum(1 for ln in lines if ln.state is s) for s in STATES}
    changed = sum(1 for ln in lines if ln.changed != "same")
    skipped = doc["inputs"]["skipped"]
    skipped_rows = "".join(f"<tr><td>{e(s['path'])}</td><td>{e(s['reason'])}</td></tr>" for s in skipped)
    skipped_html = (
        f'<details><summary>{len(skipped)} input{"s" if len(skipped) != 1 else ""} skipped</summary>'
        f'<table class="list"><thead><tr><th>input</th><th>reason</th></tr></thead><tbody>{skipped_rows}</tbody></table></details>'
        if skipped else ""
    )  # fmt: skip
    types = sorted({ln.type for ln in lines})
    header = (
        f"<header><h1>{e(title)}</h1>"
        f'<p class="muted small">Fleet {e(doc["fleet"])} · data until {e(utc(data_until_s)) or "–"} · judged {e(doc["generated_utc"])} · '
        f"page written {e(written)} · "
        f'<a href="worklist.csv" download>CSV</a> · <a href="worklist.json">JSON</a></p>'
        f'<p class="counts">{len(lines)} wagons: '
        + "".join(f'<button type="button" data-state="{s.value}">{badge(s.value)} {counts[s]}</button>' for s in STATES if counts[s])
        + f'</p><p class="small">{changed} changed {e(compare)}. Inputs: {doc["inputs"]["wagons"]} wagons, {doc["inputs"]["recordings"]} '
        f"recordings, {len(skipped)} skipped.</p>{skipped_html}</header>"
    )
    filters = (
        '<form class="filters" role="search" onsubmit="return false">'
        '<input type="search" id="q" placeholder="Search wagon, action, sensor, corner" aria-label="search">'
        f'<select id="fs" aria-label="state"><option value="">every state</option>{_options([s.value for s in STATES if counts[s]])}</select>'
        f'<select id="ft" aria-label="type"><option value="">every type</option>{_options(types)}</select>'
        f'<select id="fc" aria-label="commissioned"><option value="">commissioned or not</option>{_options(list(COMMISSIONED), COMMISSIONED)}</select>'
        f'<label><input type="checkbox" id="fx"{" checked" if changed_only else ""}> changed only</label>'
        f'<span class="small muted"><span id="n">{len(lines)}</span> shown</span></form>'
    )
    ths = "".join(f"<th>{e(h)}</th>" for h in HEAD)
    table = f'<table class="work" id="work"><thead><tr>{ths}</tr></thead><tbody>\n' + "\n".join(_row(ln) for ln in lines) + "\n</tbody></table>"
    return page(title, WORK_CSS + ".work tr[hidden]{display:none}\n", f"{header}\n{filters}\n{table}\n{_legend(compare)}", SCRIPT)
