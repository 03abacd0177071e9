"""What `fleet judge` concluded of one wagon (fleet/judge.py writes it; fleet/evidence.py and the
page read it): a record, in a module of its own so that its readers need not load the judge."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, TypedDict

import pyarrow as pa

from bogiemon.fleet.layout import Issue
from bogiemon.judgement.events import Event
from bogiemon.judgement.vocabulary import Mode


class MeanEvidence(TypedDict):
    """A load state's mean coupling vectors on the first and last day, and their windows."""

    first_day: list[float]
    last_day: list[float]
    first_day_windows: int
    last_day_windows: int


@dataclass(frozen=True)
class WagonJudged:
    wagon_id: str
    events: tuple[tuple[int, Event], ...]  # (seq, event) in commit order
    series: pa.Table
    mode: Mode
    sensor_reported: dict[str, list[str]]
    not_judged: bool  # a NOT_JUDGED in force at the end: running left unjudged for long
    unjudged_running_s: float
    windows: int
    judged: int
    gated: int
    sensor_fault_windows: int
    trend: float | None  # the latest judged window's trend and its alarm level
    trend_alarm: float | None
    days: tuple[str, ...]
    evidence: dict[str, MeanEvidence]  # load -> first/last day mean coupling vector, windows
    issues: tuple[Issue, ...]
    last_data_s: float | None = None  # the end of its newest window
    # The alarm in force at the end: its diagnosis from all the running since (fleet/judge.py).
    diagnosis_now: dict[str, Any] | None = None
