"""Counting the wagon judge's evaluation against issue 33's targets (lab/sister/evaluate.py's runs).

Every figure is a count: runs, windows, events. A fault run counts as confirmed when its first
CONFIRMED after the fault's onset comes within FAULT_HORIZON_S of it AND names the faulty bogie;
one that names the other bogie counts against "the bogie named right". The corner is read from
that event's diagnosis (the corners it names, config naming) against the run's true corner.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

from bogiemon.judgement.events import ConfirmedDetails
from bogiemon.lab.sister.evaluate import Configuration, JudgedRun
from bogiemon.lab.sister.plan import BROKEN

FAULT_HORIZON_S = 600.0
BROKEN_FULL = tuple(c for c in BROKEN if ".full." in c[0])
BROKEN_TARE = tuple(c for c in BROKEN if ".tare." in c[0])


@dataclass(frozen=True)
class Count:
    num: int
    den: int

    @property
    def share(self) -> float:
        return self.num / self.den if self.den else float("nan")

    def text(self) -> str:
        return f"{self.num}/{self.den}" if self.den else "-"


@dataclass(frozen=True)
class Healthy:
    runs: int
    hours: float
    confirmed: int  # CONFIRMED events
    suspected_runs: int  # runs with a SUSPECTED on either bogie
    windows: int
    judged: int  # windows judged, both bogies counted

    @property
    def judged_share(self) -> float:
        return self.judged / self.windows if self.windows else float("nan")


def healthy(runs: Sequence[JudgedRun]) -> Healthy:
    return Healthy(
        runs=len(runs),
        hours=sum(r.run.run.duration_s for r in runs) / 3600.0,
        confirmed=sum(e.kind == "CONFIRMED" for r in runs for e in r.events),
        suspected_runs=sum(any(e.kind == "SUSPECTED" for e in r.events) for r in runs),
        windows=sum(sum(r.windows) for r in runs),
        judged=sum(sum(r.judged) for r in runs),
    )


def _first(r: JudgedRun) -> tuple[str | None, float | None]:
    """(the bogie, the delay after the onset) of the run's first CONFIRMED after the onset."""
    event = r.confirmed_after(r.run.run.onset_s)
    return (None, None) if event is None else (event.bogie, event.time_s - r.run.run.onset_s)


def confirmed(runs: Sequence[JudgedRun], horizon_s: float = FAULT_HORIZON_S) -> Count:
    """Fault runs confirmed on their own bogie within the horizon."""
    hits = 0
    for r in runs:
        bogie, delay = _first(r)
        hits += bogie == str(r.run.run.bogie) and delay is not None and delay <= horizon_s
    return Count(hits, len(runs))


def named_right(runs: Sequence[JudgedRun]) -> Count:
    """Of the fault runs confirmed after the onset, those whose first CONFIRMED names the right bogie."""
    named = [(b, r) for r in runs for b, _ in [_first(r)] if b is not None]
    return Count(sum(b == str(r.run.run.bogie) for b, r in named), len(named))


def corners(runs: Sequence[JudgedRun], inside: bool) -> Count:
    """Of the fault runs confirmed on their bogie, those whose diagnosis names the true corner
    among its corners (inside) or names corners without it (outside)."""
    n = hits = 0
    for r in runs:
        event = r.confirmed_after(r.run.run.onset_s)
        if event is None or event.bogie != str(r.run.run.bogie):
            continue
        n += 1
        d = event.details
        named = tuple(c.value for c in d.diagnosis.corners) if isinstance(d, ConfirmedDetails) and d.diagnosis is not None else ()
        true = r.run.run.corner.value if r.run.run.corner else None
        hits += (true in named) if inside else (bool(named) and true not in named)
    return Count(hits, n)


def select(c: Configuration, role: str, commissioning: str | None = None, cells: Sequence[tuple[str, float]] | None = None) -> list[JudgedRun]:
    out = []
    for r in c.runs:
        spec = r.run.run
        if spec.role != role or (commissioning is not None and r.commissioning != commissioning):
            continue
        if cells is not None and (spec.key, spec.severity) not in cells:
            continue
        out.append(r)
    return out


@dataclass(frozen=True)
class SensorRuns:
    """Runs with one sensor of one bogie damaged: how many; how many had a suspension event
    (SUSPECTED or CONFIRMED) on either bogie, how many on the other, healthy bogie (the sister must
    never blame it), and how many reported the sensor fault on the damaged bogie."""

    runs: int
    suspension: int
    other_bogie: int
    reported: int


def sensor_runs(runs: Sequence[JudgedRun]) -> SensorRuns:
    def damaged(r: JudgedRun) -> str:
        return str(r.run.run.bogie)

    suspension = [r for r in runs if any(e.kind in ("SUSPECTED", "CONFIRMED") for e in r.events)]
    other = [r for r in runs if any(e.kind in ("SUSPECTED", "CONFIRMED") and e.bogie != damaged(r) for e in r.events)]
    reported = [r for r in runs if any(e.kind == "SENSOR_FAULT" and e.bogie == damaged(r) for e in r.events)]
    return SensorRuns(len(runs), len(suspension), len(other), len(reported))


@dataclass(frozen=True)
class Target:
    name: str
    goal: float
    at_most: bool
    measure: Callable[[Configuration], Count]


def _own(c: Configuration) -> str:
    return "even" if c.mode == "commissioned" else "none"


def _healthy_count(attr: str) -> Callable[[Configuration], Count]:
    def measure(c: Configuration) -> Count:
        h = healthy(select(c, "healthy", _own(c)))
        return {"confirmed": Count(h.confirmed, h.runs), "suspected": Count(h.suspected_runs, h.runs), "judged": Count(h.judged, h.windows)}[attr]

    return measure


TARGETS: tuple[Target, ...] = (
    Target("healthy: CONFIRMED events (per runs)", 0.0, True, _healthy_count("confirmed")),
    Target("healthy runs with a SUSPECTED", 0.01, True, _healthy_count("suspected")),
    Target("healthy windows judged (both bogies)", 0.98, False, _healthy_count("judged")),
    Target("broken spring, full load, either bogie: confirmed on it within 10 min", 15 / 16, False, lambda c: confirmed(select(c, "fault", _own(c), BROKEN_FULL))),
    Target("broken outer spring, tare, either bogie: confirmed on it within 10 min", 1.0, False, lambda c: confirmed(select(c, "fault", _own(c), BROKEN_TARE))),
    Target("every fault case, either bogie: confirmed on it within 10 min", 0.80, False, lambda c: confirmed(select(c, "fault", _own(c)))),
    Target("confirmed faults: the bogie named right", 0.98, False, lambda c: named_right(select(c, "fault", _own(c)))),
    Target("confirmed broken springs: the corner among the named", 0.90, False, lambda c: corners(select(c, "fault", _own(c), BROKEN), True)),
    Target("confirmed broken springs: the corner outside the named", 0.05, True, lambda c: corners(select(c, "fault", _own(c), BROKEN), False)),
)


def met(target: Target, count: Count) -> bool | None:
    if not count.den:
        return None
    return count.share <= target.goal if target.at_most else count.share >= target.goal
