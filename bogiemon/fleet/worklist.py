"""The work list: per wagon one line a maintenance planner acts on, from a JUDGED folder.

A line says what to do in plain words (which bogie, which axle boxes or which sensor, by when),
since when the wagon is in its state, how sure the system is (a word and the figure behind it),
what changed since a moment (the previous report, a date), how fresh the wagon's data are, and the
period's history (sensor faults and alarms that came and went, not only what holds now).

Everything is read off the wagon's events (replayed per bogie: `replay`), its record in
wagons.json and its series: nothing of the decision is restated, only put in words. The bogie an
event is about is read in one place (`bogie_of`): an event without one is about bogie "1", the only
bogie a one-bogie gateway watches; a two-bogie wagon's events name theirs, and its line names
every bogie that needs work.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from bogiemon.daemon.messages import EventMessage
from bogiemon.judgement.events import EventKind
from bogiemon.fleet.judged_files import STATES, WagonPage, WagonState

DEFAULT_BOGIE = "1"
# By when each state's work is due, in days: a keeper's maintenance rule, not the detector's. A
# confirmed broken spring is a running-safety matter (the wagon may run to the next yard, not
# for weeks); a suspicion is looked at at the next scheduled stop; a sensor is a gateway matter.
DUE_DAYS = {WagonState.CONFIRMED: 2, WagonState.SUSPECTED: 14, WagonState.SENSOR_FAULT: 7, WagonState.NOT_JUDGED: 14, WagonState.NO_DATA: 7}
# A wagon whose newest data are this much older than the fleet's newest is stale: its gateway has
# stopped recording or uploading. Two days: a wagon parked over a weekend still uploads the
# recorder's periodic snapshots, but a day without a single one is already worth a look.
STALE_AFTER_S = 2 * 86_400.0
# The trend's share of its alarm level that reads "clear" rather than "confirmed" (the alarm level
# is set so that no healthy wagon of the fitting fleet crossed it: three times it is far outside).
CLEAR_RATIO = 3.0

# A sensor's problems in a fitter's words (judgement/health.py SensorProblem's values).
PROBLEM_WORDS = {
    "flat": "reads nothing (dead or disconnected)",
    "stuck": "repeats one value (frozen converter)",
    "clipping": "hits the end of its range",
    "noisy": "reads noise",
    "over_range": "reports over-range",
    "sensor_fault_bit": "reports its own fault",
    "dropouts": "loses samples",
    "inverted": "reads upside down (mounted or wired so)",
    "swapped": "is wired to another corner than configured",
}


def bogie_of(message: EventMessage) -> str:
    """The bogie an event is about: its own `bogie` (bogie "1" when a one-bogie gateway's message
    names none: daemon/messages.py). The one place that reads it."""
    return message.bogie or DEFAULT_BOGIE


@dataclass
class BogieState:
    """One bogie's standing after its events up to a time (each field from the events alone)."""

    mode: str = "NORMAL"  # NORMAL, SUSPECTED or CONFIRMED (the decision's mode)
    mode_since_s: float | None = None  # the event that set the mode (None: normal from the start)
    diagnosis: Mapping[str, Any] | None = None  # the CONFIRMED event's
    sensors: dict[str, list[str]] = field(default_factory=dict)  # channel -> problems, while reported
    sensors_since_s: float | None = None
    # The corners a SENSOR_FAULT said the couplings pointed at (a one-corner suspension fault told
    # beside the sensor: judgement/health.py), while the fault is reported.
    sensor_suspension: tuple[str, ...] = ()
    not_judged_since_s: float | None = None  # a NOT_JUDGED in force since

    @property
    def state(self) -> WagonState:
        """The bogie's state in the page's words, by judge.state_of's precedence."""
        if self.mode == "CONFIRMED":
            return WagonState.CONFIRMED
        if self.sensors:
            return WagonState.SENSOR_FAULT
        if self.not_judged_since_s is not None:
            return WagonState.NOT_JUDGED
        return WagonState(self.mode)


def replay(events: Iterable[EventMessage], until_s: float = math.inf) -> dict[str, BogieState]:
    """Each bogie's state after its events at or before until_s (events in time order)."""
    out: dict[str, BogieState] = {}
    for m in events:
        if m.time_s > until_s:
            break
        s = out.setdefault(bogie_of(m), BogieState())
        if m.kind in ("SUSPECTED", "CONFIRMED"):
            if s.mode != m.kind:
                s.mode, s.mode_since_s = m.kind, m.time_s
            if m.kind == "CONFIRMED":
                diagnosis = m.details.get("diagnosis")
                s.diagnosis = diagnosis if isinstance(diagnosis, dict) else None
        elif m.kind == "CLEARED":
            s.mode, s.mode_since_s, s.diagnosis = "NORMAL", m.time_s, None
        elif m.kind == "SENSOR_FAULT":
            reported = m.details.get("reported") or m.details.get("problems") or {}
            if not s.sensors:
                s.sensors_since_s = m.time_s
            s.sensors = {str(ch): [str(p) for p in ps] for ch, ps in reported.items() if isinstance(ps, list)} or {"?": []}
            suspension = m.details.get("suspension")
            corners = suspension.get("corners") if isinstance(suspension, dict) else None
            if isinstance(corners, list) and corners and all(isinstance(c, str) for c in corners):
                s.sensor_suspension = tuple(corners)
        elif m.kind == "SENSOR_CLEARED":
            s.sensors, s.sensors_since_s, s.sensor_suspension = {}, None, ()
        elif m.kind == "NOT_JUDGED":
            s.not_judged_since_s = m.time_s
        elif m.kind == "JUDGED_AGAIN":
            s.not_judged_since_s = None
    return out


def wagon_state(bogies: Mapping[str, BogieState], has_data: bool) -> WagonState:
    """The most urgent of the bogies' states (NO_DATA without any window)."""
    if not has_data:
        return WagonState.NO_DATA
    return min((b.state for b in bogies.values()), key=STATES.index, default=WagonState.NORMAL)


# ---------------------------------------------------------------------------------------------
# The line


@dataclass(frozen=True)
class Sure:
    word: str  # "clear", "confirmed", "possible", "healthy", "sensor", ... or "" (nothing to say)
    figure: str  # e.g. "22x alarm"
    explained: str  # the figure in a sentence (the page's hover text and the CSV's column)


@dataclass(frozen=True)
class WorkLine:
    """One wagon's line of the work list (the page's row, the CSV's row, worklist.json's entry)."""

    wagon: str
    type: str
    state: WagonState
    bogies: tuple[str, ...]  # the bogies the action names (empty: nothing to do on a bogie)
    action: str  # what to do, in one sentence
    due_days: int | None  # within how many days (None: nothing due)
    since_s: float | None  # since when the wagon is in its state
    sure: Sure
    changed: str  # "new", "worse", "better", "same" (against the state at the comparison time)
    changed_text: str  # e.g. "was NORMAL; 2 new events"
    last_data_s: float | None
    stale: bool
    sensor_fault_windows: int
    windows: int
    judged: int
    sensor_faults: int  # SENSOR_FAULT events in the period (those that cleared too)
    suspicions: int  # SUSPECTED events in the period
    alarms: int  # CONFIRMED events in the period
    commissioned: tuple[str, ...]
    notes: tuple[str, ...]  # what else is true of it, each said once and never the action again

    @property
    def page(self) -> str:
        """The wagon's own page, relative to the report's folder (a stable name per wagon id)."""
        return f"wagons/{file_id(self.wagon)}.html"

    def as_dict(self) -> dict[str, Any]:
        return {
            "wagon": self.wagon, "type": self.type, "state": self.state.value, "bogies": list(self.bogies), "action": self.action,
            "due_days": self.due_days, "since_utc": utc(self.since_s), "how_sure": self.sure.word, "how_sure_figure": self.sure.figure,
            "how_sure_means": self.sure.explained, "changed": self.changed, "changed_text": self.changed_text,
            "last_data_utc": utc(self.last_data_s), "stale": self.stale, "sensor_fault_windows": self.sensor_fault_windows,
            "windows": self.windows, "judged": self.judged, "sensor_faults": self.sensor_faults, "suspicions": self.suspicions,
            "alarms": self.alarms, "commissioned": list(self.commissioned), "notes": list(self.notes), "page": self.page,
        }  # fmt: skip


def file_id(wagon: str) -> str:
    """A wagon id as a file name and URL fragment: letters, digits, '.', '_', '-' kept, anything
    else as ~hhhhhh (one name per id: '~' is never kept), never starting with a dot."""
    out = "".join(c if c.isascii() and (c.isalnum() or c in "._-") else f"~{ord(c):06x}" for c in wagon)
    return "~00002e" + out[1:] if out.startswith(".") else out


def utc(time_s: float | None) -> str:
    return "" if time_s is None else time.strftime("%Y-%m-%d %H:%MZ", time.gmtime(time_s))


def best_diagnosis(at_alarm: Mapping[str, Any] | None, now: Mapping[str, Any] | None) -> Mapping[str, Any] | None:
    """The diagnosis a line tells: the one from all the running since the alarm (the judge's
    diagnosis_now) when it names a pair, else the alarm's own."""
    return now if now is not None and now.get("corners") else at_alarm


def _corner_words(diagnosis: Mapping[str, Any] | None) -> str:
    corners = diagnosis.get("corners") if diagnosis else None
    if isinstance(corners, list) and corners and all(isinstance(c, str) for c in corners):
        return f"{' or '.join(corners)} axle box"
    return "all four axle boxes (the corner is not told)"


def _sensor_words(bogie: str, channel: str, problems: Sequence[str], corners: Mapping[str, str]) -> str:
    said = ", ".join(PROBLEM_WORDS.get(p, p) for p in problems) or "is at fault"
    if channel == "source":
        return f"the gateway's link to the sensors of bogie {bogie} {said}"
    where = f" ({corners[channel]} axle box)" if channel in corners else ""
    return f"sensor {channel} of bogie {bogie}{where} {said}"


def _bogie_list(bogies: Sequence[str]) -> str:
    return "bogie " + " and ".join(bogies) if len(bogies) <= 1 else "bogies " + ", ".join(bogies[:-1]) + " and " + bogies[-1]


def action(state: WagonState, bogies: Mapping[str, BogieState], entry: Mapping[str, Any], stale_since_s: float | None) -> tuple[str, tuple[str, ...], int | None]:
    """What to do, in one sentence, the bogies it names and within how many days."""
    corners = entry.get("sensor_corners") or {}
    pointed = any(b.sensors and b.sensor_suspension for b in bogies.values())
    # A sensor whose couplings point at a corner is as urgent as the spring they point at.
    due = DUE_DAYS[WagonState.CONFIRMED] if pointed else DUE_DAYS.get(state)
    within = f", within {due} days" if due else ""
    confirmed = sorted(b for b, s in bogies.items() if s.mode == "CONFIRMED")
    suspected = sorted(b for b, s in bogies.items() if s.mode == "SUSPECTED")
    faulty = sorted(b for b, s in bogies.items() if s.sensors)
    parts: list[str] = []
    named: list[str] = []
    if confirmed:
        now = entry.get("diagnosis_now") or {}
        where = "; ".join(f"bogie {b}, {_corner_words(best_diagnosis(bogies[b].diagnosis, now.get(b)))}" for b in confirmed)
        parts.append(f"Inspect the primary springs of {where}{within}")
        named += confirmed
    for b in faulty:
        sensors = "; ".join(_sensor_words(b, ch, ps, corners) for ch, ps in sorted(bogies[b].sensors.items()))
        pair = bogies[b].sensor_suspension
        if b in confirmed:  # the spring first; the sensor once it is fixed
            said = f"{sensors}, as a broken spring at its corner makes it: check it once the spring is fixed" if pair else f"also check the sensor: {sensors}"
        elif pair:  # a sensor fault never told alone when the couplings point at a corner
            said = (f"inspect the primary springs of bogie {b}, {' or '.join(pair)} axle box, and the sensor: {sensors}; "
                    f"the couplings moved as a broken spring there moves them")  # fmt: skip
        else:
            said = f"check the sensor: {sensors}; fix its cable or mounting"
        parts.append(said + ("" if parts else within))
        named += [b] if b not in named else []
    if suspected and not confirmed:
        where = _bogie_list(suspected)
        head = "also look" if parts else "Look"
        parts.append(f"{head} at the primary springs of {where} at its next scheduled stop{'' if parts[:-1] else within}")
        named += [b for b in suspected if b not in named]
    relative = entry.get("fleet_relative") or {}
    if relative.get("stands_out") and not confirmed and not suspected:
        head = "also look" if parts else "Look"
        parts.append(f"{head} at the primary springs of bogie {DEFAULT_BOGIE} at its next scheduled stop: it stands out of its sisters")
        named += [DEFAULT_BOGIE] if DEFAULT_BOGIE not in named else []
    if state is WagonState.NOT_JUDGED and not parts:
        parts.append(f"Running unlike its commissioning: inspect the wagon, or commission it again{within}")
    if state is WagonState.NO_DATA:
        parts.append(f"No data: check the gateway's power and upload{within}")
    elif stale_since_s is not None:
        parts.append(f"{'no' if parts else 'No'} data since {utc(stale_since_s)}: check the gateway's power and upload")
    if not parts:
        parts.append("Nothing to do")
    text = "; ".join(parts)
    if not named and state not in (WagonState.NO_DATA, WagonState.NOT_JUDGED):
        due = None
    return text[0].upper() + text[1:] + ".", tuple(named), due


def how_sure(state: WagonState, entry: Mapping[str, Any]) -> Sure:
    """A word and its figure: the trend against its alarm level, or the sensor's share of windows."""
    trend, alarm = entry.get("trend"), entry.get("trend_alarm")
    ratio = trend / alarm if isinstance(trend, int | float) and isinstance(alarm, int | float) and alarm > 0 else None
    if state is WagonState.SENSOR_FAULT:
        bad, total = int(entry.get("sensor_fault_windows", 0)), int(entry.get("windows", 0))
        return Sure("sensor", f"{bad}/{total} windows",
                    f"{bad} of the period's {total} windows were held by a sensor problem (not judged for the suspension)")  # fmt: skip
    if state is WagonState.NO_DATA:
        return Sure("", "", "no windows: nothing to be sure of")
    if ratio is None:
        return Sure("unknown", "", "no trend yet: the wagon has no judged window against a baseline")
    figure = f"{ratio:.2g}x alarm" if ratio < 10 else f"{ratio:.0f}x alarm"
    meaning = (
        f"the trend of the fused score ({trend:.3g}) is {ratio:.2g} times its alarm level ({alarm:.3g}); the alarm level is set on "
        "healthy wagons so that none crosses it"
    )
    if state is WagonState.CONFIRMED:
        return Sure("clear" if ratio >= CLEAR_RATIO else "confirmed", figure, meaning)
    if state is WagonState.SUSPECTED:
        return Sure("possible", figure, meaning)
    return Sure("healthy" if ratio < 1 else "watch", figure, meaning)


def change(before: WagonState, now: WagonState, new_events: int) -> tuple[str, str]:
    """The change of state against the comparison time, in a word and a few."""
    events = f"{new_events} new event{'s' if new_events != 1 else ''}" if new_events else ""
    if before is now:
        return "same", events
    word = "worse" if STATES.index(now) < STATES.index(before) else "better"
    if before is WagonState.NO_DATA:
        word = "new"
    return word, f"was {before.value.replace('_', ' ')}" + (f"; {events}" if events else "")


def work_line(page: WagonPage, compare_s: float, fleet_newest_s: float | None) -> WorkLine:
    """The wagon's line; changes are against its state at compare_s (from its own events)."""
    e = page.entry
    events = page.events
    last_data_s = e.get("last_data_s")
    has_data = int(e["windows"]) > 0
    bogies = replay(events)
    state = WagonState(e["state"])  # the judge's; the replay agrees with it (tested) and adds the bogies
    stale = bool(last_data_s is not None and fleet_newest_s is not None and fleet_newest_s - last_data_s > STALE_AFTER_S)
    text, named, due = action(state, bogies, e, last_data_s if stale else None)
    first_s = page.series.time_s[0] if page.series is not None and page.series.time_s.size else None
    before = wagon_state(replay(events, compare_s), has_data and (first_s is None or first_s <= compare_s))
    changed, changed_text = change(before, state, sum(1 for m in events if m.time_s > compare_s))
    in_force = [b for b in bogies.values() if b.state is state]
    since = min((s for s in (_since(state, b) for b in in_force) if s is not None), default=None)
    kinds = [m.kind for m in events]
    notes = tuple(dict.fromkeys(n for n in e["notes"] if n and n not in text))
    return WorkLine(
        wagon=e["wagon"], type=e["type"], state=state, bogies=named, action=text, due_days=due,
        since_s=since if since is not None else first_s, sure=how_sure(state, e), changed=changed, changed_text=changed_text,
        last_data_s=last_data_s, stale=stale, sensor_fault_windows=int(e["sensor_fault_windows"]), windows=int(e["windows"]),
        judged=int(e["judged"]), sensor_faults=kinds.count(EventKind.SENSOR_FAULT), suspicions=kinds.count(EventKind.SUSPECTED),
        alarms=kinds.count(EventKind.CONFIRMED), commissioned=tuple(e["commissioned"]), notes=notes,
    )  # fmt: skip


def _since(state: WagonState, b: BogieState) -> float | None:
    if state is WagonState.SENSOR_FAULT:
        return b.sensors_since_s
    if state is WagonState.NOT_JUDGED:
        return b.not_judged_since_s
    return b.mode_since_s
