"""Fitting the shipped models (judgement/models.py) on a training fleet of simulated wagons.

    runs = [TrainingRun(...), ...]                 # the evaluation's training runs (lab/robust)
    files = fit_models(runs, geometry, health, processing, confirm_k=3, confirm_n=5, description=..., calibration_runs=12)
    write_models(files, "config")                  # load_model.toml, fused_model.toml

`bogiemon evaluate --fit-models DIR` runs this on the training fleet of docs/robust (wagons and
runs disjoint from the evaluation's). Every rule is stated here, fixed before the evaluation:

LOAD MODEL: a logistic regression of full against tare on four log band-power shares, each with a
physical reason: bounce at 4-8 Hz (the loaded carbody's stuck bounce mode, 6.8 Hz; empty, 19 Hz)
and at 16-32 Hz (the heavy carbody holds the frame's bounce: little of it left at full load), roll
at 2-4 Hz (the empty carbody's roll modes, 3.2 to 3.8 Hz; loaded, 0.9 Hz) and at 32-64 Hz. Features
standardised, an L2 penalty of 1e-3, Newton's method; every training window, healthy or faulty.

FUSED MODEL, per load: the calibrated wagon's spread is the covariance of the training wagons'
healthy coupling vectors around each wagon's own mean (pooled). Its levels come out of sample:
each training wagon is commissioned on its first healthy runs (as many as the evaluation fleet's
commissioning) by the daemon's own rule (judgement/commissioning.py fit_spread: its own shrunk spread,
the other training wagons' as the prior) and its other healthy runs are scored against that
baseline, divided by the level factor the commissioning applies, in order, as one stretch of
running; a run's sustained score is
the largest value that k of n consecutive windows reach (judgement/rules.py sustained_level: the
highest level k of n confirms at); the alarm level is the larger of 1.1 x the largest sustained
score and the level an exponential tail fitted to the upper quarter of the runs' sustained scores
exceeds once in TARGET_RUNS_PER_ALARM runs. SUSPECTED asks for one window fewer of n at the warning
level (judgement/rules.py suspicion_k), so the warning level is the larger of the largest value that
many windows sustain and the tail's level once in TARGET_RUNS_PER_WARNING runs, on the runs'
values at that count (never above the alarm level). The trend (the exponentially weighted
mean of the whitened shifts, time constant TREND_TAU_S of running, carried from run to run) gets
its levels by the same rule on each run's largest trend value. The population baseline (a wagon
without calibration) is the same with the center and covariance of the whole fleet, scored
leave-one-wagon-out.

No fault signatures: the diagnosis reads the corner from the geometry (judgement/diagnosis.py). The
fault runs still train the load model, whose windows include faulty ones as a wagon's will.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.atomic import write_text_atomically
from bogiemon.daemon import tomlout
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.health import assess_window
from bogiemon.judgement.commissioning import fit_spread
from bogiemon.judgement.models import (
    FUSED_MODEL_FILE,
    LOAD_MODEL_FILE,
    FusedModel,
    Levels,
    coupling_features,
    whitening_of,
)
from bogiemon.judgement.rules import ALARM_MARGIN, suspicion_k, sustained_level, trend_weight
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import BogieGeometry, ProcessingSettings, WindowIndicators
from bogiemon.detection.features import COUPLING_NAMES, LOAD_NAMES, load_vector

LOAD_FEATURES = ("bounce_share_3", "bounce_share_5", "roll_share_2", "roll_share_6")
LOAD_L2 = 1e-3
TARGET_RUNS_PER_ALARM = 6000.0  # about one false alarm per 1000 h of 10-minute runs
TARGET_RUNS_PER_WARNING = 600.0  # about one SUSPECTED per 100 h: a tenth of issue 16's 1 % of runs
# The trend's time constant: long enough to span several track sections and speeds (a healthy
# wagon's couplings move with them), short enough to confirm a standing fault within an hour.
TREND_TAU_S = 1800.0


@dataclass(frozen=True)
class TrainingRun:
    """One run of the training fleet: which wagon, what was on it, and its windows."""

    wagon: str
    load: str
    key: str  # "healthy" or a fault case key, e.g. "type_a.full.rear_outer"
    windows: Sequence[WindowIndicators]


# --------------------------------------------------------------------------------------------
# Numerics


def fit_logistic(x: NDArray[np.float64], y: NDArray[np.float64], l2: float = LOAD_L2, iterations: int = 50) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float]:
    """(mean, scale, weights, bias) of an L2-penalised logistic regression on standardised x."""
    mean, scale = x.mean(axis=0), x.std(axis=0)
    z = np.column_stack([(x - mean) / scale, np.ones(len(x))])
    w = np.zeros(z.shape[1])
    penalty = l2 * np.r_[np.ones(z.shape[1] - 1), 0.0]
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(z @ w, -50, 50)))
        gradient = z.T @ (p - y) / len(y) + penalty * w
        hessian = (z * (p * (1 - p))[:, None]).T @ z / len(y) + np.diag(penalty)
        step = np.linalg.solve(hessian, gradient)
        w -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return mean, scale, w[:-1], float(w[-1])


def tail_level(run_maxima: Sequence[float], runs_per_event: float) -> float:
    """The level an exponential tail fitted to the upper quarter of run_maxima exceeds once in
    runs_per_event runs (maximum likelihood: the mean excess over the quarter's threshold)."""
    x = np.sort(np.asarray(run_maxima, dtype=np.float64))
    threshold = float(np.quantile(x, 0.75))
    excess = x[x > threshold] - threshold
    if excess.size < 3:
        return float(x.max())
    scale = float(excess.mean())
    p_over = excess.size / x.size
    return threshold + scale * math.log(p_over * runs_per_event)


def _score(x: NDArray[np.float64], center: NDArray[np.float64], whitening: NDArray[np.float64]) -> NDArray[np.float64]:
    z = (x - center) @ whitening.T
    return np.einsum("ij,ij->i", z, z)


@dataclass(frozen=True)
class _Levels:
    warning: float
    alarm: float
    largest_sustained: float
    tail: float
    runs: int
    windows: int


def score_levels(score_runs: Sequence[NDArray[np.float64]], confirm_k: int, confirm_n: int) -> _Levels:
    """Levels of a score judged k of n (SUSPECTED: suspect_k of n): from each run's sustained scores."""
    suspect_k = suspicion_k(confirm_k)
    confirming = [sustained_level(s, confirm_k, confirm_n) for s in score_runs if len(s) >= confirm_k]
    suspecting = [sustained_level(s, suspect_k, confirm_n) for s in score_runs if len(s) >= suspect_k]
    return _levels_of(confirming, score_runs, suspecting)


def _levels_of(maxima: Sequence[float], score_runs: Sequence[NDArray[np.float64]], warning_maxima: Sequence[float] | None = None) -> _Levels:
    """The levels from each run's largest sustained value (maxima); the warning level from
    warning_maxima where SUSPECTED asks for fewer windows than CONFIRMED (None: the same)."""
    everything = np.concatenate(score_runs)
    tail = tail_level(maxima, TARGET_RUNS_PER_ALARM)
    alarm = max(ALARM_MARGIN * max(maxima), tail)
    suspect = maxima if warning_maxima is None else warning_maxima
    warning = min(max(max(suspect), tail_level(suspect, TARGET_RUNS_PER_WARNING)), alarm)
    return _Levels(warning, alarm, max(maxima), tail, len(maxima), len(everything))


def trend_runs(z_runs: Sequence[NDArray[np.float64]], hop_s: float, tau_s: float = TREND_TAU_S) -> list[NDArray[np.float64]]:
    """Per run, the trend |m|^2 after each window, m the weighted mean of the whitened shifts z
    carried from run to run (as the Decider does; from zero, a freshly commissioned wagon)."""
    weight = trend_weight(hop_s, tau_s)
    m = np.zeros(z_runs[0].shape[1]) if z_runs else np.zeros(0)
    out = []
    for z in z_runs:
        values = np.empty(len(z))
        for i, row in enumerate(z):
            m = m + weight * (row - m)
            values[i] = float(m @ m)
        out.append(values)
    return out


# --------------------------------------------------------------------------------------------
# The fits


def _judged(windows: Sequence[WindowIndicators], geometry: BogieGeometry, health: HealthSettings) -> list[WindowIndicators]:
    return [w for w in windows if assess_window(w, health, geometry=geometry).judgeable]


def fit_load_model(runs: Sequence[TrainingRun], geometry: BogieGeometry, health: HealthSettings) -> dict[str, Any]:
    index = [LOAD_NAMES.index(f) for f in LOAD_FEATURES]
    rows, labels = [], []
    for run in runs:
        for w in _judged(run.windows, geometry, health):
            assert w.spectra is not None
            rows.append(load_vector(w.spectra, geometry)[index])
            labels.append(1.0 if run.load == "full" else 0.0)
    x, y = np.array(rows), np.array(labels)
    mean, scale, weights, bias = fit_logistic(x, y)
    p = 1.0 / (1.0 + np.exp(-(((x - mean) / scale) @ weights + bias)))
    accuracy = float(np.mean((p >= 0.5) == (y == 1.0)))
    return {
        "features": list(LOAD_FEATURES),
        "mean": [float(v) for v in mean],
        "scale": [float(v) for v in scale],
        "weights": [float(v) for v in weights],
        "bias": bias,
        "training_windows": int(len(y)),
        "training_accuracy": accuracy,
        "training_smallest_margin": float(np.min(np.abs(p - 0.5))),
    }


def _vectors(windows: Sequence[WindowIndicators], geometry: BogieGeometry) -> NDArray[np.float64]:
    rows = [coupling_features(w, geometry) for w in windows]
    return np.array([r for r in rows if r is not None]).reshape(-1, len(COUPLING_NAMES))


def _prior(load: LoadState, covariance: NDArray[np.float64], processing: ProcessingSettings, calibration_median_score: float) -> FusedModel:
    """The fused model a commissioning starts from, with unit levels (only its spread and its
    calibration median matter to fit_spread's baseline and level factor)."""
    n = covariance.shape[0]
    unit = Levels(1.0, 1.0, 1.0, 1.0)
    return FusedModel(
        load, COUPLING_NAMES, processing.window_s, processing.hop_s, covariance, unit, TREND_TAU_S,
        np.zeros(n), covariance, unit, calibration_median_score,
    )  # fmt: skip


def fit_fused(
    runs: Sequence[TrainingRun],
    geometry: BogieGeometry,
    health: HealthSettings,
    confirm_k: int,
    confirm_n: int,
    processing: ProcessingSettings,
    calibration_runs: int,
) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for load in ("full", "tare"):
        by_wagon: dict[str, list[NDArray[np.float64]]] = {}
        for run in runs:
            if run.load == load and run.key == "healthy":
                by_wagon.setdefault(run.wagon, []).append(_vectors(_judged(run.windows, geometry, health), geometry))
        wagons = sorted(by_wagon)
        residuals = {w: np.concatenate(v) - np.concatenate(v).mean(axis=0) for w, v in by_wagon.items()}
        within = np.cov(np.concatenate(list(residuals.values())).T)
        whitening = whitening_of(within)
        calibration_medians = []
        for wagon in wagons:
            cal = np.concatenate(by_wagon[wagon][:calibration_runs])
            calibration_medians.append(float(np.median(_score(cal, cal.mean(axis=0), whitening))))
        # Calibrated wagons, out of sample, as the daemon commissions them: each training wagon's
        # first runs are its commissioning (judgement/commissioning.py fit_spread, with the spread of
        # the other training wagons as its prior, as a wagon outside the training fleet gets it),
        # the rest are scored against the baseline it learns, in units of the level factor it
        # applies: the shipped levels are what that factor multiplies.
        scored, trends = [], []
        for wagon in wagons:
            cal_runs, rest = by_wagon[wagon][:calibration_runs], by_wagon[wagon][calibration_runs:]
            others = np.concatenate([residuals[o] for o in wagons if o != wagon]) if len(wagons) > 1 else residuals[wagon]
            prior = _prior(LoadState(load), np.cov(others.T), processing, float(np.median(calibration_medians)))
            bounds = np.cumsum([0] + [len(v) for v in cal_runs])
            fit = fit_spread(
                np.concatenate(cal_runs), [list(range(a, b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)], prior, processing.hop_s,
                confirm_k, confirm_n,
            )  # fmt: skip
            own = whitening_of(fit.covariance)
            scored += [_score(v, fit.center, own) / fit.level_factor for v in rest]
            trends += trend_runs([(v - fit.center) @ own.T for v in rest], processing.hop_s)
        calibrated = score_levels(scored, confirm_k, confirm_n)
        calibrated_trend = _levels_of([float(t.max()) for t in trends if len(t)], trends)
        # The population, leave one wagon out.
        everything = np.concatenate([np.concatenate(v) for v in by_wagon.values()])
        pop_scored, pop_trends = [], []
        for wagon in wagons:
            others = np.concatenate([np.concatenate(by_wagon[o]) for o in wagons if o != wagon])
            w_out = whitening_of(np.cov(others.T))
            pop_scored += [_score(v, others.mean(axis=0), w_out) for v in by_wagon[wagon]]
            pop_trends += trend_runs([(v - others.mean(axis=0)) @ w_out.T for v in by_wagon[wagon]], processing.hop_s)
        population = score_levels(pop_scored, confirm_k, confirm_n)
        population_trend = _levels_of([float(t.max()) for t in pop_trends if len(t)], pop_trends)
        out[load] = {
            "features": list(COUPLING_NAMES),
            "window_s": processing.window_s,
            "hop_s": processing.hop_s,
            "covariance": within.tolist(),
            "warning": calibrated.warning,
            "alarm": calibrated.alarm,
            "trend_tau_s": TREND_TAU_S,
            "trend_warning": calibrated_trend.warning,
            "trend_alarm": calibrated_trend.alarm,
            "calibration_median_score": float(np.median(calibration_medians)),
            "population_center": [float(v) for v in everything.mean(axis=0)],
            "population_covariance": np.cov(everything.T).tolist(),
            "population_warning": population.warning,
            "population_alarm": population.alarm,
            "population_trend_warning": population_trend.warning,
            "population_trend_alarm": population_trend.alarm,
            "evidence": {
                "wagons": len(wagons),
                "calibrated_scored_runs": calibrated.runs,
                "calibrated_scored_windows": calibrated.windows,
                "calibrated_largest_sustained": calibrated.largest_sustained,
                "calibrated_tail_level": calibrated.tail,
                "calibrated_largest_trend": calibrated_trend.largest_sustained,
                "calibrated_trend_tail_level": calibrated_trend.tail,
                "population_scored_runs": population.runs,
                "population_largest_sustained": population.largest_sustained,
                "population_tail_level": population.tail,
                "population_largest_trend": population_trend.largest_sustained,
            },
        }
    return out


@dataclass(frozen=True)
class FittedModels:
    load: dict[str, Any]
    fused: dict[str, dict[str, Any]]
    description: str  # what they were fitted on, for the files' headers


def fit_models(
    runs: Sequence[TrainingRun],
    geometry: BogieGeometry,
    health: HealthSettings,
    processing: ProcessingSettings,
    confirm_k: int,
    confirm_n: int,
    description: str,
    calibration_runs: int,
) -> FittedModels:
    load = fit_load_model(runs, geometry, health)
    fused = fit_fused(runs, geometry, health, confirm_k, confirm_n, processing, calibration_runs)
    return FittedModels(load, fused, description)


def write_models(models: FittedModels, directory: str | Path) -> list[Path]:
    directory = Path(directory)
    stamp = f"{datetime.now(UTC):%Y-%m-%d}"
    header = [
        "# Fitted by `bogiemon evaluate --fit-models` (lab/modelfit.py states every rule) on " + stamp + ",",
        *(f"# {line}" for line in models.description.splitlines()),
        "# Data, not code: regenerate rather than edit by hand.",
    ]
    files = {
        LOAD_MODEL_FILE: ("# The load state from the spectral shape: P(full), a logistic regression (judgement/models.py).", models.load),
        FUSED_MODEL_FILE: ("# The fused score's healthy spread and levels, per load (judgement/models.py, judgement/decision.py).", models.fused),
    }
    out = []
    for name, (title, body) in files.items():
        path = directory / name
        write_text_atomically(path, "\n".join([title, *header]) + "\n\n" + tomlout.dumps(body))
        out.append(path)
    return out
