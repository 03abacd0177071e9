"""The monitor is never silent: running that stays unjudged for long is said as an event.

A window whose running the commissioning never met may be left unjudged (judgement/verdict.py):
rightly for a window, wrongly for hours. Every window of running left unjudged for that reason
adds its hop to the running time since the last judged window; once that reaches not_judged_after_s
(decision.not_judged_after_h, 2 h by default) a NOT_JUDGED event says so, with what the windows
were unlike, and once a window is judged again JUDGED_AGAIN ends it. A standing wagon (gated) or
a sensor fault (its own SENSOR_FAULT) adds nothing: the first is no running, the second is said.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from bogiemon.judgement.events import Event, JudgedAgainDetails, NotJudgedDetails
from bogiemon.detection import WindowIndicators


@dataclass
class CoverageState:
    unjudged_running_s: float = 0.0  # running not judged since the last judged window
    reported: bool = False  # a NOT_JUDGED is in force
    since_s: float | None = None  # the end of the last judged window (None: none yet)

    def as_dict(self) -> dict[str, Any]:
        return {"unjudged_running_s": self.unjudged_running_s, "reported": self.reported, "since_s": self.since_s}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> CoverageState:
        if not data:  # a state saved before this tracker: none of it yet
            return cls()
        since = data.get("since_s")
        return cls(float(data["unjudged_running_s"]), bool(data["reported"]), None if since is None else float(since))


class CoverageTracker:
    """Turns the windows' outcomes into NOT_JUDGED and JUDGED_AGAIN events (module docstring)."""

    def __init__(self, config_hash: str, hop_s: float, not_judged_after_s: float, state: CoverageState | None = None) -> None:
        self.config_hash = config_hash
        self.hop_s = hop_s
        self.not_judged_after_s = not_judged_after_s
        self.state = state or CoverageState()

    def update(self, window: WindowIndicators, judged: bool, unfamiliar: str | None) -> list[Event]:
        """judged: the window was judged; unfamiliar: why it was running left unjudged, unlike the
        commissioning (judgement/running.py; None: it was not)."""
        s = self.state
        if judged:
            s.unjudged_running_s, s.since_s = 0.0, window.end_s
            if s.reported:
                s.reported = False
                return [Event.of(window.end_s, JudgedAgainDetails(window_start_s=window.start_s, window_end_s=window.end_s), self.config_hash)]
            return []
        if unfamiliar is None:
            return []
        s.unjudged_running_s += self.hop_s
        if s.reported or s.unjudged_running_s < self.not_judged_after_s:
            return []
        s.reported = True
        hours = s.unjudged_running_s / 3600.0
        message = (
            f"not judged for the last {hours:.1f} h of running: the wagon is unlike its commissioning "
            "(its load, track or speed, or a change of the wagon itself); inspect it, or commission it again"
        )
        said = NotJudgedDetails(
            window_start_s=window.start_s, window_end_s=window.end_s, message=message, unjudged_running_s=s.unjudged_running_s,
            last_judged_s=s.since_s, unlike=unfamiliar,
        )  # fmt: skip
        return [Event.of(window.end_s, said, self.config_hash)]
