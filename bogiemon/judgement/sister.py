"""The sister evidence: each bogie of a wagon the other's healthy reference (issue 33).

The other bogie runs on the same rails at the same speed a fraction of a second later, under the
same carbody and load: a reference that shares every running condition from the first kilometre.
What a window's features owe to the track and the speed, both bogies show alike; what a broken
spring changes, only its own bogie shows. Per pair of aligned windows:

    d = f(bogie 2) - f(bogie 1)           over SisterPrior.features (chosen in lab/sister: where the
                                          difference is the better reference, measured per feature)
    z = L (d - center),  score = |z|^2    against the wagon's own healthy difference (commissioning:
                                          learn_baseline) or, uncommissioned, the prior's population

The center is the wagon's own mean difference: what its two ends differ by when healthy (their
tolerances, their sensors, a load carried unevenly, which end leads). Uncommissioned, the prior's
spread adds the differences between wagons of both simulator models' training fleets, whose
loaded wagons carry their loads unevenly (config/sister_model.toml states them).

WHICH BOGIE. The difference says that the ends differ, not which one moved. Each bogie's own
coupling vector against its own healthy baseline (the fused score's, judgement/decision.py) says
which: a one-corner fault couples its own frame's modes (pitch-roll, bounce-roll) and leaves the
sister's alone (tests/simulator/test_two_bogies.py), so the bogie whose own score exceeds the
other's BLAME_RATIO times is named, and none otherwise. A pair where either window is not
judgeable (a sensor problem, a sensor fault not yet cleared, a gate, no load state) gives no
sister evidence at all: a sensor fault on one bogie never reads as a fault of the other.

Pure functions and frozen records (detection, drivers.base and judgement only).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from bogiemon.detection import BogieGeometry, WindowIndicators
from bogiemon.detection.features import COUPLING_NAMES, LOAD_NAMES, WindowFeatures
from bogiemon.judgement.commissioning import shrunk_covariance
from bogiemon.judgement.events import INDICATOR_FIELDS, SisterDetails
from bogiemon.judgement.health import assess_window
from bogiemon.judgement.models import ModelError, whitening_of
from bogiemon.judgement.rules import Level, Threshold
from bogiemon.judgement.settings import HealthSettings

SISTER_MODEL_FILE = "sister_model.toml"
SISTER_SCORE = "sister_score"  # the sister evidence's judged value in judgements and events
# A bogie is named when its own score exceeds the other's this many times (module docstring).
BLAME_RATIO = 2.0
# Log amplitudes: the track's roughness and the speed scale both bogies' alike.
AMPLITUDES = {
    "log_i1": "i1", "log_i2": "i2", "log_rms_bounce": "rms_bounce_mps2", "log_rms_pitch": "rms_pitch_radps2", "log_rms_roll": "rms_roll_radps2",
}  # fmt: skip
VOCABULARY: tuple[str, ...] = (*COUPLING_NAMES, *LOAD_NAMES, *AMPLITUDES, *INDICATOR_FIELDS)


def feature_vector(window: WindowIndicators, features: WindowFeatures | None, names: Sequence[str]) -> NDArray[np.float64] | None:
    """The named features (VOCABULARY) of one bogie's window; None when one is not finite (a mode
    without power, a window without spectra)."""
    out = np.empty(len(names))
    for i, name in enumerate(names):
        if name in AMPLITUDES:
            value = float(getattr(window, AMPLITUDES[name]))
            out[i] = math.log(value) if value > 0 else math.nan
        elif name in INDICATOR_FIELDS:
            out[i] = float(getattr(window, name))
        elif features is None:
            return None
        elif name in COUPLING_NAMES:
            out[i] = features.coupling[COUPLING_NAMES.index(name)]
        else:
            out[i] = features.load[LOAD_NAMES.index(name)]
    return out if bool(np.all(np.isfinite(out))) else None


@dataclass(frozen=True)
class SisterBaseline:
    """A healthy reference of the difference between the bogies: center, whitening L (L^T L =
    covariance^-1) and the levels of the score |L (d - center)|^2."""

    name: str  # "commissioned" (this wagon's) or "prior" (both models' training fleets)
    features: tuple[str, ...]
    center: NDArray[np.float64]
    whitening: NDArray[np.float64]
    warning: float
    alarm: float

    @property
    def threshold(self) -> Threshold:
        return Threshold(self.warning, self.alarm)

    def whiten(self, d: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.whitening @ (d - self.center)

    def score(self, d: NDArray[np.float64]) -> float:
        z = self.whiten(d)
        return float(z @ z)


@dataclass(frozen=True)
class SisterPrior:
    """The shipped part for one load (config/sister_model.toml): the spread of a wagon's healthy
    difference around its own mean (within), the levels of a commissioned wagon's score, and the
    population's center and spread (within plus between wagons) with their levels; the guard's
    spread of a commissioning's mean difference and its refusal margin (commissioning_guard), and a
    one-bogie commissioning's margin from the fused model's population (one_bogie_guard)."""

    features: tuple[str, ...]
    within_covariance: NDArray[np.float64]
    warning: float
    alarm: float
    calibration_median_score: float
    population_center: NDArray[np.float64]
    population_covariance: NDArray[np.float64]
    population_warning: float
    population_alarm: float
    between_covariance: NDArray[np.float64]
    guard_margin_sd: float
    # A one-bogie commissioning's margin from the fused model's population (one_bogie_guard).
    population_guard_margin_sd: float = math.inf
    window_s: float = 120.0
    hop_s: float = 10.0

    def baseline(self) -> SisterBaseline:
        """The uncommissioned wagon's reference: the population's."""
        return SisterBaseline(
            "prior", self.features, self.population_center, whitening_of(self.population_covariance), self.population_warning, self.population_alarm
        )


@dataclass(frozen=True)
class SisterModel:
    """The prior per load state ("full", "tare"), with where it came from."""

    loads: Mapping[str, SisterPrior]
    provenance: str = ""


def _matrix(value: Any, n: int, what: str) -> NDArray[np.float64]:
    m = np.asarray(value, dtype=np.float64)
    if m.shape != (n, n) or not np.all(np.isfinite(m)):
        raise ModelError(f"{what}: needs a finite {n} x {n} matrix")
    return m


def parse_sister_model(text: str, source: str) -> SisterModel:
    """The model of a sister_model.toml's text; ModelError naming the source and the field."""
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{source}: not TOML: {exc}") from None
    loads: dict[str, SisterPrior] = {}
    for load in ("full", "tare"):
        section = data.get(load)
        if not isinstance(section, dict):
            continue
        where = f"{source} [{load}]"
        try:
            names = tuple(str(n) for n in section["features"])
            unknown = [n for n in names if n not in VOCABULARY]
            if unknown or not names:
                raise ModelError(f"{where}: features {unknown or '(none)'} are not sister features")
            p = len(names)
            loads[load] = SisterPrior(
                features=names,
                within_covariance=_matrix(section["within_covariance"], p, f"{where} within_covariance"),
                warning=float(section["warning"]),
                alarm=float(section["alarm"]),
                calibration_median_score=float(section["calibration_median_score"]),
                population_center=np.asarray(section["population_center"], dtype=np.float64).reshape(p),
                population_covariance=_matrix(section["population_covariance"], p, f"{where} population_covariance"),
                population_warning=float(section["population_warning"]),
                population_alarm=float(section["population_alarm"]),
                between_covariance=_matrix(section["between_covariance"], p, f"{where} between_covariance"),
                guard_margin_sd=float(section["guard_margin_sd"]),
                population_guard_margin_sd=float(section.get("population_guard_margin_sd", math.inf)),
                window_s=float(section.get("window_s", 120.0)),
                hop_s=float(section.get("hop_s", 10.0)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, ModelError):
                raise
            raise ModelError(f"{where}: missing or malformed field ({exc!r})") from None
        if not 0 < loads[load].warning <= loads[load].alarm or not 0 < loads[load].population_warning <= loads[load].population_alarm:
            raise ModelError(f"{where}: needs 0 < warning <= alarm")
    if not loads:
        raise ModelError(f"{source}: no [full] or [tare] section")
    return SisterModel(loads, str(data.get("provenance", "")))


def load_sister_model(path: str | Path | None = None) -> SisterModel:
    """The shipped prior (config/sister_model.toml), or the file at `path`."""
    if path is None:
        text = resources.files("bogiemon.config").joinpath(SISTER_MODEL_FILE).read_text(encoding="utf-8")
        return parse_sister_model(text, SISTER_MODEL_FILE)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as exc:
        raise ModelError(f"{path}: cannot read the sister model: {exc.strerror or exc}") from None
    return parse_sister_model(text, str(path))


def pair_differences(
    windows_1: Sequence[WindowIndicators], windows_2: Sequence[WindowIndicators], geometry: BogieGeometry, names: Sequence[str], health: HealthSettings
) -> NDArray[np.float64]:
    """(n, len(names)) the differences (bogie 2 minus bogie 1) of a commissioning's aligned window
    pairs whose windows are both judgeable (no gate, no sensor problem: judgement/health.py) and
    whose features are all finite; what learn_baseline and commissioning_guard read."""
    by_start = {round(w.start_s, 3): w for w in windows_2}
    rows = []
    for w1 in windows_1:
        w2 = by_start.get(round(w1.start_s, 3))
        if w2 is None or not (assess_window(w1, health, geometry=geometry).judgeable and assess_window(w2, health, geometry=geometry).judgeable):
            continue
        x = [feature_vector(w, WindowFeatures(w.spectra, geometry) if w.spectra is not None else None, names) for w in (w1, w2)]
        if x[0] is not None and x[1] is not None:
            rows.append(x[1] - x[0])
    return np.array(rows) if rows else np.empty((0, len(names)))


def learn_baseline(pairs: ArrayLike, prior: SisterPrior) -> SisterBaseline:
    """A commissioned wagon's sister baseline from its healthy window pairs' differences (each
    over prior.features): their mean; their covariance shrunk towards the prior's within-wagon one
    by p / (p + n_eff), n_eff the independent windows (they overlap by window_s / hop_s); the
    prior's levels, raised by how much wider this wagon scatters than the training wagons did
    (its median in-sample score over theirs), never lowered: the fused score's rule
    (judgement/commissioning.py) for a commissioning of few runs."""
    rows = np.asarray(pairs, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != len(prior.features) or rows.shape[0] < 2:
        raise ValueError(f"learning a sister baseline needs at least 2 window pairs of {len(prior.features)} features")
    center = rows.mean(axis=0)
    covariance, _ = shrunk_covariance(rows, prior.within_covariance, rows.shape[0] / (prior.window_s / prior.hop_s))
    whitening = whitening_of(covariance)
    z = (rows - center) @ whitening.T
    median = float(np.median(np.einsum("ij,ij->i", z, z)))
    factor = max(1.0, median / prior.calibration_median_score)
    return SisterBaseline("commissioned", prior.features, center, whitening, prior.warning * factor, prior.alarm * factor)


def attribute(own_1: float, own_2: float, ratio: float = BLAME_RATIO) -> int | None:
    """The bogie (1 or 2) whose own coupling score exceeds the other's `ratio` times; None when
    neither does or either is unknown (module docstring, WHICH BOGIE)."""
    if not (math.isfinite(own_1) and math.isfinite(own_2)):
        return None
    if own_2 > ratio * own_1:
        return 2
    if own_1 > ratio * own_2:
        return 1
    return None


@dataclass(frozen=True)
class SisterEvidence:
    """One window pair's sister evidence: its score against the baseline, its level, the bogie it
    names (None: neither clearly) and each bogie's own coupling score that named it."""

    score: float
    level: Level
    blamed: int | None
    own_scores: tuple[float, float]
    shift: NDArray[np.float64]  # the whitened difference z
    baseline: SisterBaseline

    def extra_for(self, bogie: int) -> dict[str, tuple[float, Threshold]]:
        """The judged values this evidence adds to bogie `bogie`'s decision (Decider.update's
        extra): the score with its limit for the bogie it names, nothing for the other."""
        return {SISTER_SCORE: (self.score, self.baseline.threshold)} if self.blamed == bogie else {}

    def details(self) -> SisterDetails:
        """What an event states of it."""
        return SisterDetails(
            score=self.score, warning=self.baseline.warning, alarm=self.baseline.alarm, baseline=self.baseline.name,
            blamed=self.blamed, own_scores=self.own_scores,
        )  # fmt: skip


def sister_evidence(
    d: NDArray[np.float64], baseline: SisterBaseline, own_1: float, own_2: float, ratio: float = BLAME_RATIO
) -> SisterEvidence:
    """The evidence of one judgeable window pair: d the difference of its features (bogie 2 minus
    bogie 1, over baseline.features); own_1, own_2 each bogie's own coupling score."""
    z = baseline.whiten(d)
    score = float(z @ z)
    level = baseline.threshold.level(score)
    return SisterEvidence(score, level, attribute(own_1, own_2, ratio), (own_1, own_2), z, baseline)


# --------------------------------------------------------------------------------------------
# The commissioning guard


@dataclass(frozen=True)
class GuardVerdict:
    """Whether a commissioning may stand: how far what it recorded stands from the prior, in
    standard deviations of a healthy commissioning's (the Mahalanobis distance), against the margin
    no healthy training commissioning reached. bogie: the one that stands out (None: one bogie)."""

    refused: bool
    distance_sd: float
    margin_sd: float
    windows: int
    bogie: int | None = None
    other: int | None = None

    def message(self) -> str:
        """The line the calibrate command prints when it refuses."""
        if self.bogie is not None and self.other is not None:
            return (
                f"bogie {self.bogie} already differs from bogie {self.other} by {self.distance_sd:.1f} standard deviations "
                f"(a healthy wagon's stay within {self.margin_sd:.1f}): inspect its primary springs before commissioning; --force to accept"
            )
        return (
            f"the bogie already stands {self.distance_sd:.1f} standard deviations from the population's healthy couplings "
            f"(a healthy wagon's stay within {self.margin_sd:.1f}): inspect its primary springs before commissioning; --force to accept"
        )


def mean_distance_sd(rows: ArrayLike, center: NDArray[np.float64], between: NDArray[np.float64], within: NDArray[np.float64], overlap: float) -> float:
    """The Mahalanobis distance of rows' mean from center, the mean's healthy covariance being the
    spread between wagons plus the within-wagon spread over the independent windows."""
    x = np.asarray(rows, dtype=np.float64)
    n_eff = max(1.0, x.shape[0] / overlap)
    delta = x.mean(axis=0) - center
    return float(math.sqrt(max(0.0, float(delta @ np.linalg.solve(between + within / n_eff, delta)))))


def commissioning_guard(
    pairs: ArrayLike, prior: SisterPrior, own_distances_sd: tuple[float, float] | None = None, margin_sd: float | None = None
) -> GuardVerdict:
    """The guard of a two-bogie commissioning: its window pairs' differences (over prior.features)
    against the population's. own_distances_sd: each bogie's own distance from the population's
    couplings (population_distance_sd), which names the bogie that stands out (bogie 2 when neither
    is known)."""
    rows = np.asarray(pairs, dtype=np.float64)
    margin = prior.guard_margin_sd if margin_sd is None else margin_sd
    distance = mean_distance_sd(rows, prior.population_center, prior.between_covariance, prior.within_covariance, prior.window_s / prior.hop_s)
    bogie = 1 if own_distances_sd is not None and own_distances_sd[0] > own_distances_sd[1] else 2
    return GuardVerdict(distance > margin, distance, margin, int(rows.shape[0]), bogie, 3 - bogie)


def population_distance_sd(couplings: ArrayLike, center: NDArray[np.float64], covariance: NDArray[np.float64]) -> float:
    """How far one bogie's commissioning stands from the population's healthy couplings (the fused
    model's population center and covariance, config/fused_model.toml): the Mahalanobis distance of
    its windows' mean coupling vector in units of the population's window spread."""
    x = np.asarray(couplings, dtype=np.float64)
    delta = x.mean(axis=0) - center
    return float(math.sqrt(max(0.0, float(delta @ np.linalg.solve(covariance, delta)))))


def one_bogie_guard(couplings: ArrayLike, center: NDArray[np.float64], covariance: NDArray[np.float64], margin_sd: float) -> GuardVerdict:
    """The guard of a one-bogie commissioning against the population prior (its margin: the
    sister model's population_guard_margin_sd, fitted on the training fleets)."""
    distance = population_distance_sd(couplings, center, covariance)
    return GuardVerdict(distance > margin_sd, distance, margin_sd, int(np.asarray(couplings).shape[0]))


def judgeable_couplings(windows: Sequence[WindowIndicators], geometry: BogieGeometry, health: HealthSettings) -> NDArray[np.float64]:
    """(n, 10) the coupling vectors of a bogie's judgeable windows (no gate, no sensor problem,
    every coupling finite): what a commissioning's guard averages."""
    rows = []
    for w in windows:
        if w.spectra is None or not assess_window(w, health, geometry=geometry).judgeable:
            continue
        x = WindowFeatures(w.spectra, geometry).coupling
        if bool(np.all(np.isfinite(x))):
            rows.append(x)
    return np.array(rows) if rows else np.empty((0, len(COUPLING_NAMES)))


def guard_wagon(
    windows_1: Sequence[WindowIndicators], windows_2: Sequence[WindowIndicators], geometry: BogieGeometry, health: HealthSettings,
    prior: SisterPrior, population_center: NDArray[np.float64], population_covariance: NDArray[np.float64],
) -> GuardVerdict:
    """The guard of a two-bogie commissioning of one load, from its windows as recorded (the
    calibrate command's call): the sister guard's verdict, the bogie named by each bogie's own
    distance from the fused model's population (its center and window covariance)."""
    rows = pair_differences(windows_1, windows_2, geometry, prior.features, health)
    if len(rows) < 2:
        raise ValueError("the guard needs at least 2 judgeable window pairs")
    own = [judgeable_couplings(w, geometry, health) for w in (windows_1, windows_2)]
    distances = tuple(population_distance_sd(x, population_center, population_covariance) if len(x) else 0.0 for x in own)
    return commissioning_guard(rows, prior, (distances[0], distances[1]))


def guard_bogie(
    windows: Sequence[WindowIndicators], geometry: BogieGeometry, health: HealthSettings, prior: SisterPrior,
    population_center: NDArray[np.float64], population_covariance: NDArray[np.float64],
) -> GuardVerdict:
    """The guard of a one-bogie commissioning of one load, from its windows as recorded: its mean
    couplings against the fused model's population, the margin the sister prior states."""
    rows = judgeable_couplings(windows, geometry, health)
    if len(rows) < 2:
        raise ValueError("the guard needs at least 2 judgeable windows")
    return one_bogie_guard(rows, population_center, population_covariance, prior.population_guard_margin_sd)
