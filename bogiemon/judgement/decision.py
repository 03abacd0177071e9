"""The suspension decision: a level per judged window, a trend over hours, k-of-n confirmation,
hysteresis, diagnosis.

Two methods give each window its level (`decision.method`):

- "fused" (the default): the Mahalanobis distance of the window's coupling vector (pitch-roll and
  bounce-roll coherency in octave bands, detection/features.py) from a healthy baseline,
  score = |z|^2 with z = L (x - center). The center is the wagon's own, learned by `bogiemon
  calibrate` from its healthy recordings; the spread L is shipped (config/fused_model.toml). A
  wagon without calibration is judged against the fleet's population baseline, with the fleet's
  wider spread: far less sensitive (docs/robust/README.md has the numbers).
  The same whitened shifts feed THE TREND: an exponentially weighted mean of z over the judged
  windows with a time constant of trend_tau_s of running, trend = |mean|^2. A healthy wagon's
  couplings move with track and speed (its own tolerances couple the modes differently in
  each condition), and a fault's shift is as large as that movement in any one window; across
  many conditions the healthy movement averages out and a standing fault does not. So a window
  alarm catches a gross fault within minutes, the trend a moderate one within hours.
- "thresholds": the paper's indicators one by one, each against a warning and an alarm level on
  |value - center| (the raw I1..I4 or the normalised I1n..I4n, per load). No trend.

A CONFIRMED event carries what triggered it ("windows" or "trend") and a diagnosis
(judgement/diagnosis.py): the likely corner and kind of the fault from the coupling shift that
confirmed it (the alarm windows', or the trend's mean), or "unknown".

State machine, advanced once per judged window (gated windows and windows with a sensor
problem are not judged and change nothing):

    NORMAL    --k - 1 of the last n judged windows at or above a warning
                level, or the trend at its warning level-->                SUSPECTED  (event SUSPECTED)
    NORMAL or SUSPECTED --k of the last n judged windows at or above an
                          alarm level, or the trend at its alarm level-->  CONFIRMED  (event CONFIRMED)

SUSPECTED asks for persistence too, one window fewer than CONFIRMED (judgement/rules.py suspicion_k;
at least one), at the lower level: one window at a warning level is the healthy wagon's scatter
(about one window in a hundred on a stretch of track unlike its commissioning's) and, taken alone,
raised SUSPECTED in 13 to 19 % of healthy 10-minute runs (docs/robust/transfer); a suspicion sends
nobody to a siding, but one raised every few runs teaches a keeper to ignore it. A fault that
builds up is suspected a window before it is confirmed.
    SUSPECTED or CONFIRMED --clear_after consecutive judged windows below
                          every warning level, the trend below its own-->  NORMAL     (event CLEARED)

A threshold applies to the deviation |value - center| of one indicator; the warning level is
below the alarm level, and clearing needs every value back below warning: that gap is the
hysteresis. The state is a plain dict so the service can store it with each event.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, TypedDict

import numpy as np

from numpy.typing import NDArray

from bogiemon.judgement.diagnosis import NO_EVIDENCE, Diagnosis, diagnose
from bogiemon.judgement.events import INDICATOR_FIELDS, ClearedDetails, ConfirmedDetails, Event, KOfN, RunningContext, SuspectedDetails, Trigger
from bogiemon.judgement.models import Baseline, finite_or_none
from bogiemon.judgement.rules import Level, Threshold, confirms, suspicion_k, trend_weight
from bogiemon.judgement.vocabulary import LoadState, Method, Mode
from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import WindowFeatures

FUSED_SCORE = "fused_score"  # the fused method's value in judgements and events
FUSED_TREND = "fused_trend"  # its trend


@dataclass(frozen=True)
class DecisionSettings:
    thresholds: Mapping[LoadState, Mapping[str, Threshold]]  # load state -> indicator field -> threshold
    confirm_k: int = 3
    confirm_n: int = 5
    clear_after_windows: int = 6
    method: Method = Method.THRESHOLDS
    # Per load state the fused score's healthy baseline in force: needed by "fused"; with
    # "thresholds" they add the diagnosis.
    baselines: Mapping[LoadState, Baseline] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        if not 1 <= self.confirm_k <= self.confirm_n:
            raise ValueError(f"need 1 <= confirm_k <= confirm_n, got {self.confirm_k} of {self.confirm_n}")
        if self.method not in tuple(Method):
            raise ValueError(f"unknown decision method '{self.method}': use one of {', '.join(Method)}")
        if self.method is Method.FUSED and not self.baselines:
            raise ValueError("the fused method needs its baselines")
        for load, per_indicator in self.thresholds.items():
            unknown = set(per_indicator) - set(INDICATOR_FIELDS)
            if unknown:
                raise ValueError(f"thresholds.{load}: unknown indicators {sorted(unknown)}")


@dataclass(frozen=True)
class Judgement:
    """What one judged window showed: each judged value (indicators, or the fused score) and its
    level against its limit; and the window's whitened coupling shift when a baseline was at hand
    (for diagnosis)."""

    values: Mapping[str, float]
    levels: Mapping[str, Level]
    limits: Mapping[str, Threshold]  # of every value judged (the fused trend's too): what the events and displays state
    shift: NDArray[np.float64] | None = None
    baseline: str | None = None  # "calibrated" or "population": the fused baseline in force
    # The judged value farthest from healthy as a fraction of its alarm level (>= 1: alarm):
    # one number per window, comparable across methods (the evaluation's figures use it).
    alarm_ratio: float = math.nan
    trend: float = math.nan  # the fused trend after this window (NaN: no trend)
    trend_level: Level = Level.OK
    level_margin: float = 1.0  # the window's limits were raised by this (judgement/running.py)

    @property
    def worst(self) -> Level:
        """The worst level of the window's own values (not the trend's)."""
        return max(self.levels.values(), default=Level.OK)

    def with_values(self, extra: Mapping[str, tuple[float, Threshold]]) -> Judgement:
        """The judgement with more judged values (name -> (value, its limit)), e.g. the sister's
        evidence (judgement/sister.py): their levels count as the window's own do."""
        values, levels, limits = dict(self.values), dict(self.levels), dict(self.limits)
        ratios = [self.alarm_ratio] if math.isfinite(self.alarm_ratio) else []
        for name, (value, limit) in extra.items():
            values[name], limits[name] = value, limit
            levels[name] = limit.level(value) if math.isfinite(value) else Level.OK
            ratios += [abs(value - limit.center) / limit.alarm] if math.isfinite(value) else []
        ratio = max(ratios, default=math.nan)
        return dataclasses.replace(self, values=values, levels=levels, limits=limits, alarm_ratio=ratio)

    def at_or_above(self, level: Level) -> dict[str, float]:
        return {name: self.values[name] for name, lv in self.levels.items() if lv >= level}

    def headline(self) -> tuple[float, float, float]:
        """(value, warning, alarm) for a display of the window: the fused score against its levels,
        or (thresholds) the worst indicator's share of its alarm level against 1, with no warning
        level of its own (NaN)."""
        if FUSED_SCORE in self.values:
            limit = self.limits[FUSED_SCORE]
            return self.values[FUSED_SCORE], limit.warning, limit.alarm
        return self.alarm_ratio, math.nan, 1.0


@dataclass
class DecisionState:
    mode: Mode = Mode.NORMAL
    recent_alarms: deque[bool] = field(default_factory=deque)
    clean_streak: int = 0
    # The whitened coupling shifts of the recent windows at alarm level (None: no shift known),
    # aligned with recent_alarms' alarm entries: what a diagnosis at confirmation averages.
    recent_shifts: deque[NDArray[np.float64] | None] = field(default_factory=deque)
    # Per load state: the trend's weighted mean of z and the fingerprint of the baseline it was
    # accumulated against (a new calibration restarts it from healthy, zero).
    trend_mean: dict[str, NDArray[np.float64]] = field(default_factory=dict)
    trend_baseline: dict[str, str] = field(default_factory=dict)
    # The last confirm_n judged windows at or above a warning level (SUSPECTED's k - 1 of n).
    recent_warnings: deque[bool] = field(default_factory=deque)

    def as_dict(self) -> dict[str, Any]:
        return {
            "mode": self.mode.value,
            "recent_alarms": list(self.recent_alarms),
            "clean_streak": self.clean_streak,
            "recent_shifts": [None if v is None else v.tolist() for v in self.recent_shifts],
            "trend_mean": {k: v.tolist() for k, v in self.trend_mean.items()},
            "trend_baseline": dict(self.trend_baseline),
            "recent_warnings": list(self.recent_warnings),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any] | None) -> DecisionState:
        if not data:
            return cls()
        # States saved by older versions lack the shifts and the trend: they start empty.
        shifts = deque(None if v is None else np.asarray(v, dtype=np.float64) for v in data.get("recent_shifts", []))
        return cls(
            Mode(data["mode"]),
            deque(bool(v) for v in data["recent_alarms"]),
            int(data["clean_streak"]),
            shifts,
            {str(k): np.asarray(v, dtype=np.float64) for k, v in data.get("trend_mean", {}).items()},
            {str(k): str(v) for k, v in data.get("trend_baseline", {}).items()},
            deque(bool(v) for v in data.get("recent_warnings", [])),  # older states: none yet
        )


class _Stated(TypedDict):
    """What every suspension event states of its window (DecisionDetails' fields)."""

    window_start_s: float
    window_end_s: float
    load: LoadState
    thresholds: Mapping[str, Threshold]
    method: Method
    running: RunningContext | None
    baseline: str | None
    trend: float | None


class Decider:
    """Turns judged windows into SUSPECTED, CONFIRMED and CLEARED events.

    geometry: the sensors' corners (the coupling vector of a window that comes without its
    features); hop_s: the time between windows (the trend's weight per judged window).
    """

    def __init__(
        self, settings: DecisionSettings, config_hash: str, state: DecisionState | None = None, *, geometry: BogieGeometry, hop_s: float
    ) -> None:
        self.settings = settings
        self.config_hash = config_hash
        self.geometry = geometry
        self.hop_s = hop_s
        self.state = state or DecisionState()
        # A reload may shrink n: keep only what still fits.
        self.state.recent_alarms = deque(self.state.recent_alarms, maxlen=settings.confirm_n)
        self.state.recent_shifts = deque(self.state.recent_shifts, maxlen=settings.confirm_n)
        self.state.recent_warnings = deque(self.state.recent_warnings, maxlen=settings.confirm_n)

    def judge(self, window: WindowIndicators, load: LoadState, features: WindowFeatures | None = None, level_margin: float = 1.0) -> Judgement:
        """The window's values and levels in a load state (without the trend); features: the
        window's, if already at hand; level_margin: its levels x this (running outside the
        commissioning's excitation, judgement/running.py), the limits stated as they were applied."""
        baseline = self.settings.baselines.get(load)
        x = None
        if baseline is not None and window.spectra is not None:
            x = finite_or_none((features or WindowFeatures(window.spectra, self.geometry)).coupling)
        shift = None if baseline is None or x is None else baseline.whiten(x)
        name = None if baseline is None else baseline.name
        if self.settings.method is Method.FUSED:
            if baseline is None:
                raise KeyError(f"no fused baseline for load state '{load}'")
            limits = self._limits(load, level_margin)
            if shift is None:  # no spectra, or a mode without power: nothing to judge by
                return Judgement({FUSED_SCORE: math.nan}, {FUSED_SCORE: Level.OK}, limits, None, name, level_margin=level_margin)
            score, limit = float(shift @ shift), limits[FUSED_SCORE]
            level = Level.of(score, limit.warning, limit.alarm)
            return Judgement({FUSED_SCORE: score}, {FUSED_SCORE: level}, limits, shift, name, score / limit.alarm, level_margin=level_margin)
        if load not in self.settings.thresholds:
            raise KeyError(f"no thresholds for load state '{load}'")
        thresholds = self._limits(load, level_margin)
        values = {n: float(getattr(window, n)) for n in thresholds}
        levels = {n: thresholds[n].level(v) if math.isfinite(v) else Level.OK for n, v in values.items()}
        ratios = [abs(v - thresholds[n].center) / thresholds[n].alarm for n, v in values.items() if math.isfinite(v)]
        return Judgement(values, levels, thresholds, shift, name, max(ratios, default=math.nan), level_margin=level_margin)

    def update(
        self, window: WindowIndicators, load: LoadState, context: RunningContext | None = None, features: WindowFeatures | None = None,
        level_margin: float = 1.0, extra: Mapping[str, tuple[float, Threshold]] | None = None,
    ) -> tuple[Judgement, list[Event]]:  # fmt: skip
        """Advance the state machine with one judgeable window; return its judgement and events.

        context: how the load state was decided, for the events (judgement/running.py); level_margin:
        see judge; extra: more judged values with their limits (Judgement.with_values), which
        count towards the same k-of-n confirmation as the window's own.
        """
        judgement = self._with_trend(self.judge(window, load, features, level_margin), load)
        if extra:
            judgement = judgement.with_values(extra)
        s, cfg = self.state, self.settings
        alarm = judgement.worst >= Level.ALARM
        s.recent_alarms.append(alarm)
        s.recent_shifts.append(judgement.shift if alarm else None)
        s.recent_warnings.append(judgement.worst >= Level.WARNING)
        warned = judgement.worst >= Level.WARNING or judgement.trend_level >= Level.WARNING
        suspected = confirms(s.recent_warnings, suspicion_k(cfg.confirm_k)) or judgement.trend_level >= Level.WARNING
        s.clean_streak = 0 if warned else s.clean_streak + 1
        events: list[Event] = []
        stated = _Stated(
            window_start_s=window.start_s, window_end_s=window.end_s, load=load, thresholds=dict(judgement.limits), method=cfg.method,
            running=context, baseline=judgement.baseline, trend=judgement.trend if math.isfinite(judgement.trend) else None,
        )  # fmt: skip

        by_windows = confirms(s.recent_alarms, cfg.confirm_k)
        by_trend = judgement.trend_level >= Level.ALARM
        if s.mode is not Mode.CONFIRMED and (by_windows or by_trend):
            s.mode = Mode.CONFIRMED
            if by_windows:
                fired = judgement.at_or_above(Level.ALARM) or judgement.at_or_above(Level.WARNING)
                diagnosis = self.diagnosis(load)
            else:
                fired = {FUSED_TREND: judgement.trend}
                diagnosis = self.trend_diagnosis(load)
            confirmed = ConfirmedDetails(
                **stated, trigger=Trigger.WINDOWS if by_windows else Trigger.TREND, alarm_windows=KOfN(sum(s.recent_alarms), len(s.recent_alarms)),
                diagnosis=diagnosis.stated(),
            )  # fmt: skip
            events.append(Event.of(window.end_s, confirmed, self.config_hash, fired))
        elif s.mode is Mode.NORMAL and suspected:
            s.mode = Mode.SUSPECTED
            fired = judgement.at_or_above(Level.WARNING) or {FUSED_TREND: judgement.trend}
            suspicion = SuspectedDetails(**stated, warning_windows=KOfN(sum(s.recent_warnings), len(s.recent_warnings)))
            events.append(Event.of(window.end_s, suspicion, self.config_hash, fired))
        elif s.mode is not Mode.NORMAL and s.clean_streak >= cfg.clear_after_windows:
            previous = s.mode
            s.mode = Mode.NORMAL
            s.recent_alarms.clear()
            s.recent_shifts.clear()
            s.recent_warnings.clear()
            events.append(Event.of(window.end_s, ClearedDetails(**stated, cleared=previous), self.config_hash, judgement.values))
        return judgement, events

    def _with_trend(self, judgement: Judgement, load: LoadState) -> Judgement:
        """Advance the load state's trend with the window's shift; the judgement with the trend."""
        baseline = self.settings.baselines.get(load)
        if self.settings.method is not Method.FUSED or baseline is None:
            return judgement
        s = self.state
        mean = s.trend_mean.get(load)
        if s.trend_baseline.get(load) != baseline.fingerprint or mean is None or mean.size != baseline.center.size:
            mean = np.zeros(baseline.center.size)  # a new baseline: healthy until shown otherwise
            s.trend_baseline[load] = baseline.fingerprint
        if judgement.shift is not None:
            # A window judged with a margin adds its shift shrunk as its levels were raised: the
            # trend sees it as the window's own level did (score / margin = |shift / sqrt(margin)|^2).
            shift = judgement.shift / math.sqrt(judgement.level_margin)
            mean = mean + trend_weight(self.hop_s, baseline.trend_tau_s) * (shift - mean)
        s.trend_mean[load] = mean
        trend = float(mean @ mean)
        level = Level.of(trend, baseline.levels.trend_warning, baseline.levels.trend_alarm)
        return dataclasses.replace(judgement, trend=trend, trend_level=level)

    def diagnosis(self, load: LoadState) -> Diagnosis:
        """The diagnosis from the alarm windows of the current history (NO_EVIDENCE without them)."""
        baseline = self.settings.baselines.get(load)
        shifts = [v for v in self.state.recent_shifts if v is not None]
        if baseline is None or not shifts:
            return NO_EVIDENCE
        return diagnose(shifts, baseline, load)

    def trend_diagnosis(self, load: LoadState) -> Diagnosis:
        """The diagnosis from the trend's mean shift: many windows' evidence in one vector."""
        baseline = self.settings.baselines.get(load)
        mean = self.state.trend_mean.get(load)
        if baseline is None or mean is None:
            return NO_EVIDENCE
        return diagnose([mean], baseline, load, trend=True)

    def _limits(self, load: LoadState, level_margin: float = 1.0) -> dict[str, Threshold]:
        """The limits of the values judged in a load state, the window's raised by level_margin
        (the trend's never: it is the shifts that a margin shrinks for it)."""
        if self.settings.method is Method.FUSED:
            lv = self.settings.baselines[load].levels
            return {
                FUSED_SCORE: Threshold(lv.warning * level_margin, lv.alarm * level_margin),
                FUSED_TREND: Threshold(lv.trend_warning, lv.trend_alarm),
            }
        return {n: t.widened(level_margin) for n, t in self.settings.thresholds[load].items()}
