"""The soak's schedule: the phases of its data timeline (healthy, faults, sensor faults, a
standstill) and the actions on the daemon (gaps, reloads, restarts), for the day and --short.
"""

from __future__ import annotations

from dataclasses import dataclass

FS_HZ = 500.0
T0_S = 1.8e9  # data time of the first sample, Unix seconds
HOUR_S = 3600.0


@dataclass(frozen=True)
class Phase:
    """A stretch of the data timeline: healthy, a suspension fault, a sensor fault, a standstill."""

    kind: str  # "healthy", "fault", "stuck", "dead", "dropouts", "standstill"
    start_s: float  # data time from the soak's start
    duration_s: float
    channel: int | None = None  # stuck/dead: the channel (0..2)

    @property
    def end_s(self) -> float:
        return self.start_s + self.duration_s

    @property
    def is_sensor_phase(self) -> bool:
        return self.kind in ("stuck", "dead", "dropouts")

    def label(self) -> str:
        where = f" a{self.channel + 1}" if self.channel is not None else ""
        return f"{self.kind}{where} {self.start_s / HOUR_S:05.2f}-{self.end_s / HOUR_S:05.2f} h"


@dataclass(frozen=True)
class Action:
    """Something done to the daemon or its data at a data time."""

    at_s: float
    kind: str  # "gap" (samples lost), "restart", "reload", "bad-reload"
    lost_s: float = 0.0  # gap and restart: seconds of data that never reach the daemon


@dataclass(frozen=True)
class Schedule:
    phases: tuple[Phase, ...]
    actions: tuple[Action, ...]

    @property
    def duration_s(self) -> float:
        return self.phases[-1].end_s


def _phases(spec: list[tuple[str, float, int | None]]) -> tuple[Phase, ...]:
    out, t = [], 0.0
    for kind, hours, channel in spec:
        out.append(Phase(kind, t, hours * HOUR_S, channel))
        t += hours * HOUR_S
    return tuple(out)


def _dropout_gaps(phase: Phase, every_s: float = 300.0, lost_s: float = 2.0) -> list[Action]:
    """Frequent dropouts: a short loss every 5 min, 12 an hour, above health.max_gaps_per_hour."""
    return [Action(phase.start_s + k * every_s, "gap", lost_s) for k in range(1, int(phase.duration_s // every_s) + 1)]


def day_schedule() -> Schedule:
    """24 simulated hours; hours of the actions are data time from the start."""
    phases = _phases([
        ("healthy", 2.0, None), ("fault", 0.75, None), ("healthy", 2.25, None), ("stuck", 0.5, 1),
        ("healthy", 1.5, None), ("standstill", 1 / 3, None), ("healthy", 5 / 3, None), ("fault", 1.0, None),
        ("healthy", 2.0, None), ("dropouts", 1.0, None), ("healthy", 2.0, None), ("dead", 0.5, 2),
        ("healthy", 2.5, None), ("fault", 0.5, None), ("healthy", 5.5, None),
    ])  # fmt: skip
    h = HOUR_S
    actions = [
        Action(1.0 * h, "gap", 3.0), Action(2.5 * h, "restart", 5.0), Action(3.5 * h, "reload"),
        Action(6.0 * h, "restart", 5.0), Action(8.0 * h, "gap", 10.0), Action(9.5 * h, "reload"),
        Action(11.0 * h, "bad-reload"), Action(15.25 * h, "restart", 5.0), Action(16.0 * h, "reload"),
        Action(20.0 * h, "restart", 5.0), Action(22.0 * h, "gap", 60.0),
    ]  # fmt: skip
    dropouts = next(p for p in phases if p.kind == "dropouts")
    return Schedule(phases, tuple(sorted(actions + _dropout_gaps(dropouts), key=lambda a: a.at_s)))


def short_schedule() -> Schedule:
    """About 6 simulated hours with one of everything: for trying the soak out, not for its figures."""
    phases = _phases([
        ("healthy", 0.75, None), ("fault", 0.5, None), ("healthy", 0.5, None), ("stuck", 0.25, 1),
        ("healthy", 0.25, None), ("standstill", 0.25, None), ("healthy", 0.25, None), ("dropouts", 1.0, None),
        ("healthy", 1.25, None), ("dead", 0.25, 2), ("healthy", 0.5, None),
    ])  # fmt: skip
    h = HOUR_S
    actions = [
        Action(0.5 * h, "gap", 3.0), Action(1.0 * h, "restart", 5.0), Action(1.5 * h, "reload"),
        Action(2.05 * h, "bad-reload"), Action(5.1 * h, "restart", 5.0), Action(5.5 * h, "reload"),
    ]  # fmt: skip
    dropouts = next(p for p in phases if p.kind == "dropouts")
    return Schedule(phases, tuple(sorted(actions + _dropout_gaps(dropouts), key=lambda a: a.at_s)))
