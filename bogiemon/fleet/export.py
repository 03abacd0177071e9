"""The work list as data: worklist.csv for a spreadsheet or a maintenance system, worklist.json
for a program (and for the next report, which compares with the moment this one covered)."""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bogiemon.drivers.files import FileKind, read_untrusted
from bogiemon.fleet.worklist import WorkLine

WORKLIST_FORMAT = 1
WORKLIST_JSON = FileKind(
    name="previous work list", description="worklist.json is the JSON `bogiemon fleet report` writes", max_bytes=256 << 20,
    too_large="worklist.json is a fleet's work list: is this the right folder?",
)  # fmt: skip
# A cell a spreadsheet would run as a formula (=, +, -, @, or a tab or CR before one): written
# with a leading apostrophe, which the spreadsheet shows as text (OWASP's rule for CSV injection).
# Ids, types and notes come from files a keeper did not write.
FORMULA_START = ("=", "+", "-", "@", "\t", "\r")


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, list | tuple):
        value = "; ".join(str(v) for v in value)
    if isinstance(value, int | float):
        return str(value)
    text = str(value)
    return "'" + text if text.startswith(FORMULA_START) else text


def worklist_csv(lines: Sequence[WorkLine]) -> str:
    """The lines as CSV, one row per wagon in the page's order, a header of the JSON's names."""
    out = io.StringIO()
    rows = [ln.as_dict() for ln in lines]
    fields = list(rows[0]) if rows else list(WorkLine.__dataclass_fields__)
    writer = csv.writer(out, lineterminator="\r\n")
    writer.writerow(fields)
    for row in rows:
        writer.writerow([_cell(row[f]) for f in fields])
    return out.getvalue()


def worklist_json(lines: Sequence[WorkLine], fleet: str, written_utc: str, data_until_s: float | None, compared_with: str) -> str:
    doc = {
        "format": WORKLIST_FORMAT, "fleet": fleet, "written_utc": written_utc, "data_until_s": data_until_s, "compared_with": compared_with,
        "wagons": [ln.as_dict() for ln in lines],
    }  # fmt: skip
    return json.dumps(doc, indent=1, allow_nan=False, ensure_ascii=False) + "\n"


def previous_data_until(path: Path) -> float | None:
    """The moment the previous report's data reached (its worklist.json), or None: no such file,
    or one this report cannot use (a damaged or foreign file is no reason to refuse today's)."""
    try:
        doc = json.loads(read_untrusted(path, WORKLIST_JSON, ValueError).decode("utf-8"))
    except (ValueError, UnicodeDecodeError, RecursionError):
        return None
    value = doc.get("data_until_s") if isinstance(doc, dict) and doc.get("format") == WORKLIST_FORMAT else None
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value) else None
