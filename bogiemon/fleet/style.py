"""The report's look, written once: the style sheet of the work list and of the wagons' pages,
and the small helpers both write their HTML with (escaping, badges, numbers)."""

from __future__ import annotations

import math
from html import escape
from typing import Any

from bogiemon.fleet.plot import (
    ALARM_COLOUR, EVENT_COLOURS, EVENT_TEXT_COLOURS, SCORE_COLOUR, STATE_COLOURS, TREND_COLOUR, WARNING_COLOUR,
)  # fmt: skip

# Below this width the work list's rows become cards (a tablet held upright, a phone).
NARROW_PX = 1000


def e(value: Any) -> str:
    """Text from the data, escaped for an element or an attribute: those files were not written by the keeper."""
    return escape(str(value), quote=True)


def fmt(value: float | None, digits: int = 3) -> str:
    if value is None or not math.isfinite(value):
        return "–"
    return f"{value:.{digits}g}"


def badge(state: str) -> str:
    return f'<span class="b b-{e(state)}">{e(state.replace("_", " "))}</span>'


BASE_CSS = """
body{font:14px/1.4 system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:0 16px 48px;color:#212121;background:#fff}
h1{font-size:22px;margin:16px 0 4px}h2{font-size:17px;margin:14px 0 6px}
a{color:#1565c0}.muted{color:#666}.small{font-size:12px}
.b{display:inline-block;padding:1px 8px;border-radius:9px;font-weight:600;font-size:12px;color:#fff;white-space:nowrap}
.b-SUSPECTED{color:#212121}
.stale{color:#c62828;font-weight:600}
.list td,.list th{padding:2px 8px;border-bottom:1px solid #eee;text-align:left;font-size:12px;vertical-align:top}
.legend span{margin-right:14px;white-space:nowrap}
dl.legend{font-size:12px;margin:8px 0;max-width:70em}dl.legend dt{font-weight:600;margin-top:4px}dl.legend dd{margin:0 0 0 1.5em}
"""
BASE_CSS += "".join(f".b-{k}{{background:{c}}}" for k, c in STATE_COLOURS.items()) + "\n"
BASE_CSS += "".join(f".k-{k}{{color:{c}}}" for k, c in EVENT_TEXT_COLOURS.items()) + "\n"

WORK_CSS = f"""
.filters{{display:flex;flex-wrap:wrap;gap:6px 12px;align-items:center;margin:8px 0}}
.filters input[type=search]{{min-width:16em;padding:3px 6px}}
.counts button{{border:0;background:none;padding:0;margin-right:10px;cursor:pointer;font:inherit}}
table.work{{border-collapse:collapse;width:100%}}
.work th,.work td{{border-bottom:1px solid #e0e0e0;padding:4px 6px;text-align:left;vertical-align:top}}
.work th{{position:sticky;top:0;background:#f5f5f5;cursor:pointer;font-size:12px}}
.work td.id{{min-width:9.5em;overflow-wrap:anywhere;font-weight:600}}.work td.act{{min-width:18em}}
.nw{{white-space:nowrap}}
.work .nt{{font-size:12px;color:#666;margin-top:2px}}
.sure{{border-bottom:1px dotted #888;cursor:help}}
.ch-worse,.ch-new{{color:#c62828;font-weight:600}}.ch-better{{color:#2e7d32;font-weight:600}}
@media (max-width:{NARROW_PX}px){{
 table.work,.work tbody,.work tr,.work td{{display:block;width:auto}}
 .work thead{{display:none}}
 .work tr{{border:1px solid #e0e0e0;border-radius:6px;margin:0 0 8px;padding:4px 6px}}
 .work td{{border:0;padding:1px 0}}
 .work td.id,.work td.st{{display:inline-block;margin-right:8px}}
 .work td[data-l]{{display:inline-block;margin-right:14px}}
 .work td[data-l]::before{{content:attr(data-l) ": ";color:#666;font-size:12px}}
 .work td:empty{{display:none}}
}}
"""

WAGON_CSS = f"""
.facts{{margin:2px 0 6px}}
.line dt{{font-weight:600;float:left;clear:left;width:8.5em}}.line dd{{margin:0 0 2px 9em}}
svg.plot{{display:block;max-width:100%;height:auto;margin:6px 0}}
svg text{{font-size:11px;fill:#555}}
.g{{stroke:#ececec}}.ax{{stroke:#9e9e9e;fill:none}}
.s,.t,.lw,.la{{fill:none;stroke-linejoin:round;stroke-linecap:round}}
.s,.t{{stroke-width:1.6}}.lw,.la{{stroke-width:1.2;stroke-dasharray:6 4}}
.e{{stroke-width:1.2}}
text.el{{font-size:10px;font-weight:600}}
.m-suspected{{fill:#ffe082}}.m-confirmed{{fill:#ef9a9a}}
.brk{{fill:#eeeeee;stroke:none}}.bk{{stroke:#616161;stroke-width:1.2}}.gd{{stroke:#bdbdbd}}
text.dl{{fill:#333;font-weight:600}}text.gl{{font-size:10px;fill:#757575}}
.sw{{display:inline-block;width:18px;height:0;border-top:2px solid;vertical-align:middle;margin-right:4px}}
.sw.d{{border-top-style:dashed}}
.s{{stroke:{SCORE_COLOUR}}}.t{{stroke:{TREND_COLOUR}}}.lw{{stroke:{WARNING_COLOUR}}}.la{{stroke:{ALARM_COLOUR}}}
"""
WAGON_CSS += "".join(f".el-{k}{{fill:{c}}}" for k, c in EVENT_TEXT_COLOURS.items()) + "\n"
WAGON_CSS += "".join(f".e-{k}{{stroke:{c}}}" for k, c in EVENT_COLOURS.items()) + "\n"


def page(title: str, css: str, body: str, script: str = "") -> str:
    """A whole page: nothing outside it but the links the keeper follows."""
    return (
        '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width,initial-scale=1">'
        f"<title>{e(title)}</title><style>{BASE_CSS}{css}</style></head><body>\n{body}\n"
        + (f"<script>{script}</script>\n" if script else "")
        + "</body></html>\n"
    )
