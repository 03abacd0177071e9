"""The sensors' state across windows: per-window health verdicts in, SENSOR_FAULT and SENSOR_CLEARED
events out (judgement/health.py judges each window)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bogiemon.judgement.events import Event, EventDetails, Problems, SensorClearedDetails, SensorFaultDetails, SuspensionHint
from bogiemon.judgement.health import WindowHealth
from bogiemon.detection import WindowIndicators


@dataclass
class HealthState:
    reported: dict[str, list[str]]  # the problems of the last SENSOR_FAULT, empty when healthy
    clean_windows: int = 0
    # Whether a problem reported holds the suspension's judgement back (every one but noise the
    # floor alone saw: judgement/health.py); and whether a SENSOR_FAULT said the couplings moved as
    # a one-corner suspension fault moves them.
    holding: bool = True
    suspension: bool = False

    def as_dict(self) -> dict[str, object]:
        return {"reported": self.reported, "clean_windows": self.clean_windows, "holding": self.holding, "suspension": self.suspension}

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> HealthState:
        if not data:
            return cls(reported={})
        # A state saved before "holding" was kept holds the judgement back, as it then did.
        return cls(reported={k: list(v) for k, v in data["reported"].items()}, clean_windows=int(data["clean_windows"]),
                   holding=bool(data.get("holding", True)), suspension=bool(data.get("suspension", False)))  # fmt: skip


class HealthTracker:
    """Turns per-window health verdicts into SENSOR_FAULT and SENSOR_CLEARED events.

    A fault is reported when a problem appears that is not reported yet (a channel, or a new
    problem on one); while it lasts the reported set only grows, so a problem that comes and
    goes from window to window (a dead channel seen as flat, then flat and stuck) is one event,
    not one per change. It clears after clear_after_windows consecutive windows without problems
    that were not gated: at standstill a flat or stuck channel cannot be told from a quiet one,
    and the coherence and layout checks run only on windows of steady, excited running.
    """

    def __init__(self, config_hash: str, clear_after_windows: int = 3, state: HealthState | None = None) -> None:
        self.config_hash = config_hash
        self.clear_after_windows = clear_after_windows
        self.state = state or HealthState(reported={})

    @property
    def faulted(self) -> bool:
        """A SENSOR_FAULT is reported and not yet cleared."""
        return bool(self.state.reported)

    @property
    def holds_judgement(self) -> bool:
        """A sensor fault is reported that holds the suspension's judgement back until it clears."""
        return self.faulted and self.state.holding

    def update(self, window: WindowIndicators, health: WindowHealth, holds: bool = True, suspension: SuspensionHint | None = None) -> list[Event]:
        """The window's sensor events. holds: whether its problems hold the suspension's judgement
        back; suspension: what its couplings said of a one-corner suspension fault, told in the
        SENSOR_FAULT beside the sensor (a fault already reported is told again when this is new)."""
        s = self.state
        current = {ch: sorted(p.value for p in problems) for ch, problems in health.problems.items()}
        if current:
            s.clean_windows = 0
            s.holding = (s.holding and bool(s.reported)) or holds
            grown = {ch: sorted(set(s.reported.get(ch, [])) | set(ps)) for ch, ps in {**s.reported, **current}.items()}
            told = suspension is not None and not s.suspension
            if grown != s.reported or told:
                s.reported = grown
                s.suspension = s.suspension or told
                found = SensorFaultDetails(
                    window_start_s=window.start_s, window_end_s=window.end_s, rms_mps2=tuple(window.rms_mps2), problems=_stated(current),
                    reported=_stated(grown), suspension=suspension,
                )  # fmt: skip
                return [self._event(window, found)]
            return []
        if s.reported and health.gate is None:
            s.clean_windows += 1
            if s.clean_windows >= self.clear_after_windows:
                previous, s.reported, s.clean_windows, s.holding, s.suspension = s.reported, {}, 0, True, False
                cleared = SensorClearedDetails(window_start_s=window.start_s, window_end_s=window.end_s, rms_mps2=tuple(window.rms_mps2), cleared=_stated(previous))
                return [self._event(window, cleared)]
        return []

    def _event(self, window: WindowIndicators, details: EventDetails) -> Event:
        return Event.of(window.end_s, details, self.config_hash)


def _stated(problems: dict[str, list[str]]) -> Problems:
    return {ch: tuple(names) for ch, names in problems.items()}
