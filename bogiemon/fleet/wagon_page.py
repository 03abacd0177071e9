"""A wagon's own page (wagons/<id>.html of a report): its line of the work list in full, what the
diagnosis and the sensors said, its fused score and trend over time, and its events.

The file name is the wagon id's (worklist.file_id): the same URL every day, to paste into a work
order. Nothing outside the page is asked for but the link back to the work list.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

from bogiemon.daemon.messages import EventMessage
from bogiemon.fleet import svg
from bogiemon.fleet.judged_files import EVENT_KINDS, WagonPage
from bogiemon.fleet.plot import ALARM_COLOUR, MAX_IDLE_S, SCORE_COLOUR, TREND_COLOUR, WARNING_COLOUR, wagon_plot
from bogiemon.fleet.style import WAGON_CSS, badge, e, fmt, page
from bogiemon.fleet.worklist import DEFAULT_BOGIE, WorkLine, best_diagnosis, bogie_of, utc

MAX_EVENTS_LISTED = 500  # the plot marks every event


def _event_values(m: EventMessage) -> str:
    parts = [f"{name} {fmt(v)}" for name, v in m.indicators.items()]
    for key in ("problems",):
        found = m.details.get(key)
        if isinstance(found, dict):
            parts += [f"{ch}: {', '.join(str(p) for p in ps)}" for ch, ps in found.items() if isinstance(ps, list)]
    diagnosis = m.details.get("diagnosis")
    if isinstance(diagnosis, dict) and diagnosis.get("best_match"):
        parts.append(str(diagnosis["best_match"]))
    return e("; ".join(parts))


def _events(events: Sequence[EventMessage], bogies: bool) -> str:
    if not events:
        return '<p class="small muted">No events.</p>'
    shown = events[-MAX_EVENTS_LISTED:]
    more = f" (the last {len(shown)} listed)" if len(shown) < len(events) else ""
    bogie_head = "<th>bogie</th>" if bogies else ""
    rows = "".join(
        f"<tr><td>{m.seq}</td><td>{e(svg.utc_label(m.time_s))}</td>" + (f"<td>{e(bogie_of(m))}</td>" if bogies else "")
        + f'<td class="k-{m.kind}">{e(m.kind)}</td><td>{_event_values(m)}</td></tr>'
        for m in shown
    )  # fmt: skip
    return (
        f"<h2>Events</h2><p class=\"small\">{len(events)} event{'s' if len(events) != 1 else ''}{more}</p>"
        f'<table class="list"><thead><tr><th>seq</th><th>time (UTC)</th>{bogie_head}<th>kind</th><th>values</th></tr></thead><tbody>{rows}</tbody></table>'
    )


def _legend() -> str:
    items = [
        f'<span><i class="sw" style="border-color:{SCORE_COLOUR}"></i>fused score</span>',
        f'<span><i class="sw" style="border-color:{TREND_COLOUR}"></i>trend</span>',
        f'<span><i class="sw d" style="border-color:{WARNING_COLOUR}"></i>warning level</span>',
        f'<span><i class="sw d" style="border-color:{ALARM_COLOUR}"></i>alarm level</span>',
    ]
    items += [f'<span class="k-{k}">| {k}</span>' for k in EVENT_KINDS]
    return '<p class="legend small">' + " ".join(items) + f" (events; log scales, UTC; an idle gap over {MAX_IDLE_S / 60:.0f} min is cut to a grey band with its length)</p>"


def _diagnosis(d: Mapping[str, Any] | None) -> str:
    if not d:
        return ""
    confidence = d.get("corner_confidence")
    sure = f" ({confidence:.0%} that the corner is one of them)" if isinstance(confidence, int | float) and d.get("corners") else ""
    corner = " or ".join(d["corners"]) if isinstance(d.get("corners"), list) and d["corners"] else "not told"
    match = f"; {d['best_match']}" if d.get("best_match") else ""
    return e(f"corner: {corner}{sure}{match}")


def render(wp: WagonPage, line: WorkLine, title: str) -> tuple[str, int]:
    """The wagon's page and how many points its plot draws."""
    entry = wp.entry
    plot, points = wagon_plot(wp)
    period = (
        f"{entry['days']} day{'s' if entry['days'] != 1 else ''} ({entry['first_day'] or '–'} to {entry['last_day'] or '–'}): "
        f"{entry['judged']} of {entry['windows']} windows judged, {entry['gated']} gated, {entry['sensor_fault_windows']} held by a sensor problem"
    )
    corners = entry.get("sensor_corners") or {}
    rows = [
        ("What to do", e(line.action)),
        ("Since", e(utc(line.since_s)) or "–"),
        ("How sure", e(f"{line.sure.word} ({line.sure.figure}): {line.sure.explained}" if line.sure.figure else line.sure.explained)),
        ("Changed", e(f"{line.changed}{'; ' + line.changed_text if line.changed_text else ''}")),
        ("Last data", e(utc(line.last_data_s)) + (' <span class="stale">stale</span>' if line.stale else "")),
        ("Period", e(period)),
        ("Diagnosis", _diagnosis(best_diagnosis(entry.get("diagnosis"), (entry.get("diagnosis_now") or {}).get(DEFAULT_BOGIE)))),
        ("Sensors", e(", ".join(f"{ch} at {c}" for ch, c in corners.items()))),
        ("Type", e(f"{entry['type']}; commissioned for {', '.join(entry['commissioned']) or 'no load state'}")),
    ]
    facts = "".join(f"<dt>{name}</dt><dd>{value}</dd>" for name, value in rows if value)
    notes = "".join(f"<li>{e(n)}</li>" for n in line.notes)
    note = f'<p class="small muted">Series: {e(wp.series_note)}.</p>' if wp.series_note else ""
    bogies = len({bogie_of(m) for m in wp.events}) > 1
    body = (
        f'<p class="small"><a href="../index.html">work list</a> · {e(title)}</p>'
        f"<h1>{e(entry['wagon'])} {badge(line.state.value)}</h1>"
        f'<dl class="line">{facts}</dl>' + (f"<ul>{notes}</ul>" if notes else "")
        + f"<h2>Fused score and trend</h2>{_legend()}{note}{plot}{_events(wp.events, bogies)}"
    )  # fmt: skip
    return page(f"{entry['wagon']}: {title}", WAGON_CSS, body), points
