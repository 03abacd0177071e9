"""One verdict per window: sensor health, gating, load state, judgement, limits, mode and events,
from one call, onboard and offline alike.

The Monitor (daemon/monitor.py: `run` and `replay`), `fleet judge` and the lab's evaluation all
judge a window with WindowJudge.judge and read what it concluded from the WindowVerdict it returns;
none of them restates a rule of it. WindowJudge holds the decision, sensor and coverage state and
counts what became of each window; it saves and restores that state as a plain dict. No store, no
sinks (the Monitor adds those).
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from collections.abc import Mapping
from typing import Any

from bogiemon.judgement.coverage import CoverageState, CoverageTracker
from bogiemon.judgement.decision import Decider, DecisionSettings, DecisionState, Judgement
from bogiemon.judgement.rules import Level
from bogiemon.judgement.diagnosis import diagnose
from bogiemon.judgement.events import Event, SuspensionHint
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.health import WindowHealth, assess_window
from bogiemon.judgement.models import LoadDiscriminant, LoadModel, LoadSignature, excitation_of, finite_or_none
from bogiemon.judgement.rules import Threshold
from bogiemon.judgement.running import LoadChoice, choose_load
from bogiemon.judgement.sensor_tracker import HealthState, HealthTracker
from bogiemon.judgement.vocabulary import LoadSetting, LoadState, Mode
from bogiemon.detection import BogieGeometry, ProcessingSettings, WindowIndicators
from bogiemon.detection.features import WindowFeatures
from bogiemon.drivers.base import ALL_OK, SensorStatus

Status = tuple[SensorStatus, SensorStatus, SensorStatus]


@dataclass(frozen=True)
class MonitorSettings:
    processing: ProcessingSettings
    geometry: BogieGeometry
    health: HealthSettings
    decision: DecisionSettings
    load: LoadSetting  # a fixed load state, or auto (estimated per window)
    config_hash: str
    sensor_clear_after_windows: int = 3
    load_model: LoadModel | None = None
    # The load states the wagon was commissioned in: with them, load "auto" takes the state on the
    # window's side of the line between them, and a window running outside the commissioning's
    # excitation is judged with a margin, or not at all far outside it (judgement/running.py).
    load_states: tuple[LoadSignature, ...] = ()
    load_discriminant: LoadDiscriminant | None = None  # with both states: the wagon's own line between them
    # Running left unjudged this long (unlike the commissioning) is said: NOT_JUDGED (judgement/coverage.py).
    not_judged_after_s: float = 7200.0

    def __post_init__(self) -> None:
        if self.load is LoadSetting.AUTO and self.load_model is None:
            raise ValueError("load 'auto' needs the load model")


class Outcome(enum.Enum):
    """What became of a window: every window is exactly one of these."""

    JUDGED = "judged"
    GATED = "gated"  # the wagon stood, stopped or started, or ran too gently (WindowHealth.gate)
    UNFAMILIAR = "unfamiliar"  # its running unlike the commissioning's (judgement/running.py): between its load states, or far outside its excitation
    SENSOR = "sensor"  # a sensor problem in it, or a sensor fault not yet cleared


@dataclass(frozen=True)
class WindowVerdict:
    """Everything the daemon concluded about one window."""

    window: WindowIndicators
    status: Status  # the sensors' status bits over it
    health: WindowHealth
    judgement: Judgement | None  # None when the window was not judged
    mode: Mode  # the decision's mode after it
    events: tuple[Event, ...]  # decided on it (committed and reported by the Monitor)
    load: LoadState | None = None  # the load state it was judged in
    p_full: float | None = None  # the estimated probability of full load (load "auto" without commissioning)
    # Not judged for its running: why (judgement/running.py LoadChoice.unjudged).
    unfamiliar: str | None = None
    # The window's spectral features as the judgement computed them (None: not that far), for
    # readers that need more of them (the back office's fleet evidence reads the couplings).
    features: WindowFeatures | None = None

    @property
    def outcome(self) -> Outcome:
        if self.judgement is not None:
            return Outcome.JUDGED
        if self.health.gate is not None:
            return Outcome.GATED
        if self.unfamiliar is not None:
            return Outcome.UNFAMILIAR
        return Outcome.SENSOR


@dataclass
class WindowCounts:
    """What became of the windows judged so far: windows == judged + gated + sensor_fault_windows."""

    windows: int = 0
    judged: int = 0
    # Not judged for the running: the wagon stood, stopped or started, ran too gently, or unlike
    # the commissioning (unfamiliar, counted here too).
    gated: int = 0
    unfamiliar: int = 0  # of the gated: running unlike the commissioning (judgement/running.py)
    sensor_fault_windows: int = 0  # held by the sensors: a problem in it, or a sensor fault not yet cleared

    def count(self, outcome: Outcome) -> None:
        self.windows += 1
        if outcome is Outcome.JUDGED:
            self.judged += 1
        elif outcome is Outcome.SENSOR:
            self.sensor_fault_windows += 1
        else:
            self.gated += 1
            self.unfamiliar += outcome is Outcome.UNFAMILIAR


class SavedStateError(ValueError):
    """A saved judge state that does not decode (written by something else than a judge)."""


@dataclass(frozen=True)
class Prepared:
    """A window half judged (WindowJudge.prepare): its health, the sensor events, and when its
    sensors allow judging it, its features and load state (choice None: not judgeable)."""

    window: WindowIndicators
    status: Status
    health: WindowHealth
    events: tuple[Event, ...]
    features: WindowFeatures | None = None
    choice: LoadChoice | None = None
    # Judged through noise only the floor saw: the sensors' state is advanced in conclude(), once
    # the decision says what the couplings showed.
    through_noise: bool = False

    @property
    def judgeable(self) -> bool:
        """Its sensors are sound and the running allows a judgement (a load state was chosen)."""
        return self.choice is not None and self.choice.load is not None


class WindowJudge:
    """Sensor health, gating, load state and the suspension decision for one window at a time.

    counts: where the windows' outcomes are counted (the Monitor's counters, which count blocks
    and events beside them); a fresh WindowCounts by default.
    """

    def __init__(
        self, settings: MonitorSettings, decision: DecisionState | None = None, health: HealthState | None = None,
        coverage: CoverageState | None = None, counts: WindowCounts | None = None,
    ) -> None:  # fmt: skip
        self.settings = settings
        self.decider = self._decider(settings, decision)
        self.health = HealthTracker(settings.config_hash, settings.sensor_clear_after_windows, health)
        self.coverage = self._coverage(settings, coverage)
        self.counts = counts if counts is not None else WindowCounts()

    @classmethod
    def restore(cls, settings: MonitorSettings, saved: Mapping[str, Any] | None, counts: WindowCounts | None = None) -> WindowJudge:
        """A judge carrying on from state_dict()'s output (None or empty: a fresh one);
        SavedStateError when it does not decode."""
        saved = saved or {}
        try:
            decision, health = DecisionState.from_dict(saved.get("decision")), HealthState.from_dict(saved.get("health"))
            coverage = CoverageState.from_dict(saved.get("coverage"))
        except (KeyError, ValueError, TypeError, AttributeError) as exc:
            raise SavedStateError(f"the saved judge state does not decode ({exc!r})") from None
        return cls(settings, decision, health, coverage, counts)

    def state_dict(self) -> dict[str, Any]:
        """The decision, sensor and coverage state as plain JSON-able values (restore() reads it)."""
        return {"decision": self.decider.state.as_dict(), "health": self.health.state.as_dict(), "coverage": self.coverage.state.as_dict()}

    @staticmethod
    def _coverage(settings: MonitorSettings, state: CoverageState | None) -> CoverageTracker:
        return CoverageTracker(settings.config_hash, settings.processing.hop_s, settings.not_judged_after_s, state)

    @staticmethod
    def _decider(settings: MonitorSettings, state: DecisionState | None) -> Decider:
        return Decider(settings.decision, settings.config_hash, state, geometry=settings.geometry, hop_s=settings.processing.hop_s)

    def reconfigure(self, settings: MonitorSettings) -> None:
        """Apply new settings; the decision and sensor state carry over."""
        self.settings = settings
        self.decider = self._decider(settings, self.decider.state)
        self.health = HealthTracker(settings.config_hash, settings.sensor_clear_after_windows, self.health.state)
        self.coverage = self._coverage(settings, self.coverage.state)

    @property
    def mode(self) -> Mode:
        return self.decider.state.mode

    def judge(self, window: WindowIndicators, status: Status = ALL_OK, gaps_last_hour: int = 0) -> WindowVerdict:
        """The window's verdict, its outcome counted."""
        return self.conclude(self.prepare(window, status, gaps_last_hour))

    def prepare(self, window: WindowIndicators, status: Status = ALL_OK, gaps_last_hour: int = 0) -> Prepared:
        """The first half of judge(): the sensors' health (their state advanced), the features and
        the load state, up to the decision; a wagon's judge (judgement/wagon.py) reads both bogies'
        before either's decision. Every prepared window must be concluded, once, in order."""
        s = self.settings
        health = assess_window(window, s.health, status, gaps_last_hour, s.geometry)
        # Noise the floor alone saw cannot move the couplings judged (judgement/health.py, "A SENSOR
        # FAULT NEVER HIDES A SUSPENSION FAULT"): the suspension is judged on them, and the sensor's
        # state advanced once the decision is made, its SENSOR_FAULT saying what the couplings said.
        if s.health.judge_through_floor_noise and health.couplings_readable and not self.health.holds_judgement:
            return self._with_load(window, status, health, (), through_noise=True)
        events = self.health.update(window, health)
        # Nothing is judged until a sensor fault has cleared: a faulty channel can pass a single
        # window's checks (noise that the track's own excitation hides) and still couple the modes.
        if not health.judgeable or self.health.holds_judgement:
            return Prepared(window, status, health, tuple(events))
        return self._with_load(window, status, health, tuple(events))

    def _with_load(self, window: WindowIndicators, status: Status, health: WindowHealth, events: tuple[Event, ...], through_noise: bool = False) -> Prepared:
        s = self.settings
        features = WindowFeatures(window.spectra, s.geometry) if window.spectra is not None else None
        load_vector = finite_or_none(features.load) if features is not None else None
        choice = choose_load(s.load, load_vector, excitation_of(window), s.load_states, s.load_discriminant, s.load_model)
        return Prepared(window, status, health, events, features, choice, through_noise)

    def conclude(self, prepared: Prepared, extra: Mapping[str, tuple[float, Threshold]] | None = None) -> WindowVerdict:
        """The second half of judge(): the decision (with `extra` judged values beside the window's
        own, Decider.update), the sensors' state where it waited for it, the coverage, the outcome counted."""
        verdict = self._decide(prepared, extra)
        if prepared.through_noise:
            sensor = self.health.update(prepared.window, prepared.health, holds=False, suspension=self._one_corner(verdict))
            verdict = dataclasses.replace(verdict, events=(*sensor, *verdict.events))
        unfamiliar = verdict.unfamiliar if verdict.outcome is Outcome.UNFAMILIAR else None
        said = self.coverage.update(prepared.window, verdict.judgement is not None, unfamiliar)
        self.counts.count(verdict.outcome)
        return dataclasses.replace(verdict, events=verdict.events + tuple(said)) if said else verdict

    def _decide(self, p: Prepared, extra: Mapping[str, tuple[float, Threshold]] | None) -> WindowVerdict:
        events = list(p.events)

        def verdict(**judged: Any) -> WindowVerdict:
            return WindowVerdict(p.window, p.status, p.health, judged.pop("judgement", None), self.mode, tuple(events), **judged)

        if p.choice is None:
            return verdict()
        if p.choice.load is None:
            return verdict(unfamiliar=p.choice.unjudged, features=p.features)
        judgement, decided = self.decider.update(p.window, p.choice.load, p.choice.context(), p.features, p.choice.level_margin, extra)
        events += decided
        return verdict(judgement=judgement, load=p.choice.load, p_full=p.choice.p_full, features=p.features)

    def _one_corner(self, verdict: WindowVerdict) -> SuspensionHint | None:
        """What a judged window's couplings say of a one-corner suspension fault: the diagonal pair
        its shift's pitch-roll sign names, when the window is at warning level or above (None else)."""
        j, load = verdict.judgement, verdict.load
        baseline = self.settings.decision.baselines.get(load) if load is not None else None
        if j is None or load is None or baseline is None or j.shift is None or j.worst < Level.WARNING:
            return None
        found = diagnose([j.shift], baseline, load)
        if not found.corners:
            return None
        score, _, alarm = j.headline()
        return SuspensionHint(tuple(c.value for c in found.corners), score, alarm, found.best_match)
