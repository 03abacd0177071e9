"""Sensor health and gating: decide whether a window may be judged at all, and why not.

A stuck or dead channel creates exactly the asymmetry the indicators look for, so every window
is checked here first. A window is judged only when the wagon runs with enough excitation and
every sensor looks healthy; otherwise it is gated (standstill, weak excitation) or the sensors
are at fault (a SENSOR_FAULT, never a suspension alarm).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

import numpy as np

from bogiemon.daemon.events import DEFAULT_SEVERITY, Event, EventKind
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.base import SensorStatus

CHANNELS = ("a1", "a2", "a3")


class SensorProblem(enum.Enum):
    FLAT = "flat"  # no dynamic signal while the others move: dead, disconnected or frozen
    STUCK = "stuck"  # the converter repeats its last value
    CLIPPING = "clipping"  # samples at the converter's full scale
    NOISY = "noisy"  # far more signal than the other channels, or than a bogie frame gives
    OVER_RANGE = "over_range"  # the sensor's own over-range bit
    SENSOR_FAULT_BIT = "sensor_fault_bit"  # the sensor's own fault bit
    DROPOUTS = "dropouts"  # the source loses samples too often


class Gate(enum.Enum):
    STANDSTILL = "standstill"  # every channel quiet: the wagon stands
    WEAK_EXCITATION = "weak_excitation"  # moving, but too little excitation to judge


@dataclass(frozen=True)
class HealthSettings:
    standstill_rms_mps2: float = 0.05  # every channel below this: the wagon stands
    min_excitation_rms_mps2: float = 0.3  # median channel RMS needed to judge the suspension
    flat_rms_mps2: float = 0.02  # a channel below this while another moves is flat
    stuck_repeat_fraction: float = 0.2  # share of samples equal to the previous one
    clip_level_mps2: float = 155.0  # |a| at or above this is clipping (16 g full scale = 156.9)
    clipped_fraction: float = 1e-4  # share of clipped samples that makes a channel unusable
    noise_ratio: float = 4.0  # a channel's RMS over the median of the three
    max_rms_mps2: float = 50.0  # no bogie frame in service gives this much RMS
    max_gaps_per_hour: int = 6  # more gaps than this in the last hour: dropouts


@dataclass(frozen=True)
class WindowHealth:
    """The health verdict for one window."""

    gate: Gate | None
    problems: dict[str, tuple[SensorProblem, ...]]  # channel (or "source") -> problems

    @property
    def sensors_ok(self) -> bool:
        return not self.problems

    @property
    def judgeable(self) -> bool:
        return self.gate is None and self.sensors_ok


def assess_window(
    window: WindowIndicators,
    settings: HealthSettings,
    status: tuple[SensorStatus, SensorStatus, SensorStatus] = (SensorStatus.OK,) * 3,
    gaps_last_hour: int = 0,
) -> WindowHealth:
    rms = np.array(window.rms_mps2)
    stats = window.channels
    problems: dict[str, list[SensorProblem]] = {}

    def flag(channel: str, problem: SensorProblem) -> None:
        problems.setdefault(channel, []).append(problem)

    standstill = bool(np.all(rms < settings.standstill_rms_mps2))
    median_rms = float(np.median(rms))
    for c, name in enumerate(CHANNELS):
        if SensorStatus.SENSOR_FAULT in status[c]:
            flag(name, SensorProblem.SENSOR_FAULT_BIT)
        if SensorStatus.OVER_RANGE in status[c]:
            flag(name, SensorProblem.OVER_RANGE)
        if stats.clipped_fraction[c] >= settings.clipped_fraction:  # counted at clip_level_mps2 by the core
            flag(name, SensorProblem.CLIPPING)
        if rms[c] > settings.max_rms_mps2 or (median_rms > 0 and rms[c] > settings.noise_ratio * median_rms):
            flag(name, SensorProblem.NOISY)
        if not standstill:  # a quiet channel is only suspicious while another one moves
            if rms[c] < settings.flat_rms_mps2:
                flag(name, SensorProblem.FLAT)
            if stats.repeat_fraction[c] >= settings.stuck_repeat_fraction:
                flag(name, SensorProblem.STUCK)
    if gaps_last_hour > settings.max_gaps_per_hour:
        flag("source", SensorProblem.DROPOUTS)

    gate = None
    if standstill:
        gate = Gate.STANDSTILL
    elif median_rms < settings.min_excitation_rms_mps2:
        gate = Gate.WEAK_EXCITATION
    return WindowHealth(gate=gate, problems={k: tuple(v) for k, v in problems.items()})


@dataclass
class HealthState:
    reported: dict[str, list[str]]  # the problems of the last SENSOR_FAULT, empty when healthy
    clean_windows: int = 0

    def as_dict(self) -> dict[str, object]:
        return {"reported": self.reported, "clean_windows": self.clean_windows}

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> HealthState:
        if not data:
            return cls(reported={})
        return cls(reported={k: list(v) for k, v in data["reported"].items()}, clean_windows=int(data["clean_windows"]))


class HealthTracker:
    """Turns per-window health verdicts into SENSOR_FAULT and SENSOR_CLEARED events.

    A fault is reported when problems appear or change; it clears after clear_after_windows
    consecutive windows without problems in which the wagon moved (at standstill a flat or
    stuck channel cannot be told from a quiet one).
    """

    def __init__(self, config_hash: str, clear_after_windows: int = 3, state: HealthState | None = None) -> None:
        self.config_hash = config_hash
        self.clear_after_windows = clear_after_windows
        self.state = state or HealthState(reported={})

    def update(self, window: WindowIndicators, health: WindowHealth) -> list[Event]:
        s = self.state
        current = {ch: sorted(p.value for p in problems) for ch, problems in health.problems.items()}
        details = {"window_start_s": window.start_s, "window_end_s": window.end_s, "rms_mps2": list(window.rms_mps2)}
        if current:
            s.clean_windows = 0
            if current != s.reported:
                s.reported = current
                return [self._event(window, EventKind.SENSOR_FAULT, {**details, "problems": current})]
            return []
        if s.reported and health.gate is not Gate.STANDSTILL:
            s.clean_windows += 1
            if s.clean_windows >= self.clear_after_windows:
                previous, s.reported, s.clean_windows = s.reported, {}, 0
                return [self._event(window, EventKind.SENSOR_CLEARED, {**details, "cleared": previous})]
        return []

    def _event(self, window: WindowIndicators, kind: EventKind, details: dict[str, object]) -> Event:
        return Event(time_s=window.end_s, kind=kind, severity=DEFAULT_SEVERITY[kind], config_hash=self.config_hash, details=details)
