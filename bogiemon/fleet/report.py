"""`bogiemon fleet report`: a JUDGED folder (docs/fleet-formats.md section 3) as the keeper's work list.

The report is a folder a keeper opens and mails, with no server and nothing from the network:

    REPORT/index.html         the work list: one line per wagon, most urgent first (worklist_page.py)
    REPORT/worklist.csv       the same lines for a spreadsheet or a maintenance system
    REPORT/worklist.json      the same lines for a program; the next report compares with it
    REPORT/wagons/<id>.html   each wagon's page: its line in full, plot and events (wagon_page.py)

What changed is told against a moment: `since` (a date), else the moment the previous report in
REPORT covered (its worklist.json), else the last day of data. Each wagon's state then is replayed
from its own events (worklist.replay), so the comparison needs no earlier JUDGED folder.
"""

from __future__ import annotations

import datetime as dt
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from bogiemon.drivers.atomic import write_bytes_atomically
from bogiemon.fleet import wagon_page, worklist_page
from bogiemon.fleet.export import previous_data_until, worklist_csv, worklist_json
from bogiemon.fleet.judged_files import STATES, Judged, ReportError, read_judged
from bogiemon.fleet.paths import make_room, output_folder, shown
from bogiemon.fleet.worklist import WorkLine, file_id, utc, work_line

DAY_S = 86_400.0
PAGES = "wagons"


@dataclass(frozen=True)
class ReportSummary:
    path: Path  # the folder
    wagons: int
    bytes: int  # of index.html
    states: Mapping[str, int]  # wagons per state, every state listed
    events: int
    skipped_inputs: int
    points: int  # plotted points after decimation, all wagons' pages
    changed: int  # wagons whose state changed since the moment compared with
    compared_with: str

    @property
    def index(self) -> Path:
        return self.path / "index.html"


def since_time(text: str) -> float:
    """A --since date (YYYY-MM-DD, or YYYY-MM-DDTHH:MM[:SS], UTC) as Unix seconds; ReportError if not one."""
    try:
        moment = dt.datetime.fromisoformat(text)
    except ValueError:
        raise ReportError(f"--since {shown(text, 40)!r}: expected a date, YYYY-MM-DD or YYYY-MM-DDTHH:MM (UTC)") from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.UTC)
    return moment.timestamp()


def work_lines(judged: Judged, compare_s: float) -> list[WorkLine]:
    """Every wagon's line, in the JUDGED folder's order of need."""
    newest = max((float(p.entry["last_data_s"]) for p in judged.wagons if p.entry.get("last_data_s") is not None), default=None)
    return [work_line(p, compare_s, newest) for p in judged.wagons]


def _moment(out: Path, since: str | None, newest_s: float | None) -> tuple[float, str]:
    """The moment changes are told against, and its words."""
    if since is not None:
        return since_time(since), f"since {since} (UTC)"
    previous = previous_data_until(out / "worklist.json")
    if previous is not None:
        return previous, f"since the previous report (its data until {utc(previous)})"
    if newest_s is None:
        return 0.0, "since the start"
    return newest_s - DAY_S, f"over the last day of data (since {utc(newest_s - DAY_S)})"


def _write(out: Path, path: Path, text: str) -> int:
    # A lone surrogate a hostile JSON string escaped (\\udcff) has no UTF-8: it shows as '?'.
    data = text.encode("utf-8", "replace")
    try:
        make_room(path, out)  # a folder or a symlink where a page or wagons/ must be: REPORT is the report's own
        write_bytes_atomically(path, data)
    except OSError as exc:
        raise ReportError(f"{shown(path)}: cannot be written ({exc.strerror or exc})") from None
    return len(data)


def write_report(judged_dir: Path | str, out_dir: Path | str, title: str | None = None, since: str | None = None,
                 written_utc: dt.datetime | None = None) -> ReportSummary:  # fmt: skip
    """Write the report folder for a JUDGED folder (each file atomically); ReportError for bad input."""
    if str(out_dir).lower().endswith((".html", ".htm")) and not Path(out_dir).is_dir():
        raise ReportError(f"{shown(out_dir)}: the report is a folder (index.html, worklist.csv, a page per wagon): name a folder")
    if since is not None:
        since_time(since)  # refused before anything is written
    judged = read_judged(judged_dir)
    out = output_folder(out_dir, ReportError, "the report", {"JUDGED": judged_dir})
    fleet = judged.doc["fleet"]
    title = title if title is not None else (f"{fleet}: work list" if fleet else "Fleet work list")
    written = (written_utc or dt.datetime.now(dt.UTC)).astimezone(dt.UTC).strftime("%Y-%m-%d %H:%MZ")
    newest = max((float(p.entry["last_data_s"]) for p in judged.wagons if p.entry.get("last_data_s") is not None), default=None)
    compare_s, compare = _moment(out, since, newest)
    lines = work_lines(judged, compare_s)
    pages = out / PAGES
    points = 0
    kept = set()
    for wp, line in zip(judged.wagons, lines, strict=True):
        html, n = wagon_page.render(wp, line, title)
        points += n
        name = f"{file_id(line.wagon)}.html"
        kept.add(name)
        _write(out, pages / name, html)
    for stale in pages.glob("*.html") if pages.is_dir() and not pages.is_symlink() else ():  # a wagon no longer in the fleet: its old page would mislead
        if stale.name not in kept and stale.is_file() and not stale.is_symlink():
            os.unlink(stale)
    size = _write(out, out / "index.html", worklist_page.render(lines, judged.doc, title, written, compare, newest, since is not None))
    _write(out, out / "worklist.csv", worklist_csv(lines))
    _write(out, out / "worklist.json", worklist_json(lines, fleet, written, newest, compare))
    counts = {s.value: sum(1 for ln in lines if ln.state is s) for s in STATES}
    return ReportSummary(
        path=out, wagons=len(lines), bytes=size, states=counts, events=judged.events, skipped_inputs=len(judged.doc["inputs"]["skipped"]),
        points=points, changed=sum(1 for ln in lines if ln.changed != "same"), compared_with=compare,
    )  # fmt: skip
