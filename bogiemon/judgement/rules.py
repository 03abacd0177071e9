"""The daemon's decision rules as plain functions: one copy, for the service and the offline lab.

The service's Decider (judgement/decision.py) and `bogiemon calibrate` (daemon/calibrate.py) call
these on each window; the lab (bogiemon.lab: the study, the robustness evaluation, the model
fitting) calls the same functions on whole runs, so what it measures is what a gateway does.

- LEVELS: a deviation from healthy is at ALARM when it reaches the alarm level, else at WARNING
  when it reaches the warning level (>=, so a level is part of its band).
- CONFIRMATION, k of n: a fault is confirmed once confirm_k of the last confirm_n judged windows
  are at alarm (fewer than n at the start, as the history fills); SUSPICION once suspicion_k (one
  fewer, at least one) of them are at warning or above.
- THE THRESHOLD RULE of calibrate, per indicator, with d = x - median and sigma = 1.4826 * MAD:

      warning = max(z(p_warning) * sigma, the (1 - p_warning) quantile of |d|)
      alarm   = max(z(p_alarm) * sigma, ALARM_MARGIN * the largest |d| seen, warning)

  z(p) the two-sided normal quantile of a per-window false-alarm rate p.
- THE TREND's weight per judged window: an exponentially weighted mean with a time constant of
  tau_s of running, one window every hop_s.
"""

from __future__ import annotations

import enum
import math
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from statistics import NormalDist
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

ALARM_MARGIN = 1.1  # the alarm level stays this far above the largest healthy deviation seen
MAD_TO_SIGMA = 1.4826  # the MAD of a normal distribution times this is its standard deviation


class Level(enum.IntEnum):
    OK = 0
    WARNING = 1
    ALARM = 2

    @classmethod
    def of(cls, deviation: float, warning: float, alarm: float) -> Level:
        """The level of a deviation from healthy against its warning and alarm levels."""
        return cls(int(level_of(deviation, warning, alarm)))


def level_of(deviation: ArrayLike, warning: float, alarm: float) -> Any:
    """Level.of for a scalar or an array of deviations (the level's int value; NaN is OK)."""
    d = np.asarray(deviation, dtype=np.float64)
    return np.where(d >= alarm, int(Level.ALARM), np.where(d >= warning, int(Level.WARNING), int(Level.OK)))


@dataclass(frozen=True)
class Threshold:
    """Levels for |value - center| of one indicator."""

    warning: float
    alarm: float
    center: float = 0.0

    def __post_init__(self) -> None:
        if not 0 < self.warning <= self.alarm:
            raise ValueError(f"need 0 < warning <= alarm, got warning={self.warning}, alarm={self.alarm}")

    def level(self, value: float) -> Level:
        return Level.of(abs(value - self.center), self.warning, self.alarm)

    def widened(self, factor: float) -> Threshold:
        """The same center with both levels x factor (>= 1)."""
        return self if factor == 1.0 else Threshold(self.warning * factor, self.alarm * factor, self.center)

    def levels(self, values: ArrayLike) -> NDArray[np.int64]:
        """The level of each value (an array of Level values)."""
        return np.asarray(level_of(np.abs(np.asarray(values, dtype=np.float64) - self.center), self.warning, self.alarm))


@dataclass(frozen=True)
class ThresholdFit(Threshold):
    """A Threshold learned from healthy windows by the threshold rule, with what it was learned from."""

    robust_sigma: float = 0.0  # 1.4826 * MAD of the healthy values
    max_deviation: float = 0.0  # the largest |x - median| among them
    n_windows: int = 0


def two_sided_z(rate: float) -> float:
    """The normal quantile beyond which |N(0, 1)| lies with probability `rate`.

    The standard library's inverse normal CDF (Wichura's AS241, about 1e-16 relative error; equal
    to scipy.special.ndtri within 1e-12 over the rates a threshold uses, tests/judgement): a
    gateway that calibrates needs no scipy.
    """
    return -NormalDist().inv_cdf(rate / 2)


def fit_threshold(values: ArrayLike, warning_rate: float, alarm_rate: float) -> ThresholdFit:
    """The threshold rule (module docstring) on one indicator's healthy values."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        raise ValueError("the threshold rule needs at least one healthy value")
    median = float(np.median(x))
    deviation = np.abs(x - median)
    sigma = MAD_TO_SIGMA * float(np.median(deviation))
    largest = float(deviation.max())
    warning = max(two_sided_z(warning_rate) * sigma, float(np.quantile(deviation, 1 - warning_rate)), np.finfo(float).tiny)
    alarm = max(two_sided_z(alarm_rate) * sigma, ALARM_MARGIN * largest, warning)
    return ThresholdFit(warning=warning, alarm=alarm, center=median, robust_sigma=sigma, max_deviation=largest, n_windows=int(x.size))


def suspicion_k(confirm_k: int) -> int:
    """How many of the last confirm_n judged windows at a warning level raise SUSPECTED: one fewer
    than CONFIRMED asks at the alarm level (at least one), so that a fault building up is suspected
    a window before it is confirmed, and a single window is never enough unless confirm_k is 1."""
    return max(1, confirm_k - 1)


def confirms(recent_alarms: Iterable[bool], confirm_k: int) -> bool:
    """k of n: the history of the last confirm_n judged windows holds at least confirm_k alarms."""
    return sum(bool(a) for a in recent_alarms) >= confirm_k


def first_confirmation(alarms: Iterable[bool], confirm_k: int, confirm_n: int) -> int | None:
    """The index of the first window at which the k-of-n rule confirms; None if it never does."""
    recent: deque[bool] = deque(maxlen=confirm_n)
    for i, alarm in enumerate(alarms):
        recent.append(bool(alarm))
        if confirms(recent, confirm_k):
            return i
    return None


def sustained_level(scores: Iterable[float], confirm_k: int, confirm_n: int) -> float:
    """The highest alarm level at which the k-of-n rule would confirm on these scores: the largest
    value that confirm_k of some confirm_n consecutive scores reach (fewer at the start, as the
    history fills); -inf for fewer than confirm_k scores."""
    recent: deque[float] = deque(maxlen=confirm_n)
    best = -math.inf
    for score in scores:
        recent.append(float(score))
        if len(recent) >= confirm_k:
            best = max(best, sorted(recent, reverse=True)[confirm_k - 1])
    return best


def trend_weight(hop_s: float, tau_s: float) -> float:
    """The weight of one judged window in the trend's exponentially weighted mean."""
    return 1.0 - math.exp(-hop_s / tau_s)
