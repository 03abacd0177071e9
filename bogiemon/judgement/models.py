"""The models the daemon's judgement uses beyond thresholds, shipped as data in config/.

    config/load_model.toml       the load state from the spectral shape (a logistic regression)
    config/fused_model.toml      the fused score: the healthy couplings' spread, per load

No fault pattern is shipped: the diagnosis names the corner from the sensors' geometry
(judgement/diagnosis.py), because the signatures once fitted on model A named the wrong corner of
another wagon model's faults with confidence.

They are fitted on a simulated training fleet by `bogiemon evaluate --fit-models` (lab/modelfit.py;
the wagons, runs and numbers are in each file's header and in docs/robust/README.md) and read
here into plain dataclasses. A wagon's own healthy center comes from `bogiemon calibrate`.
"""

from __future__ import annotations

import functools
import hashlib
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection import BogieGeometry, ProcessingSettings, WindowIndicators
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection.features import COUPLING_NAMES, LOAD_NAMES, WindowFeatures

LOAD_MODEL_FILE = "load_model.toml"
FUSED_MODEL_FILE = "fused_model.toml"
UNKNOWN = "unknown"


class ModelError(ValueError):
    """A model file that cannot be used; the message names the file and the field."""


# --------------------------------------------------------------------------------------------
# The load state


@dataclass(frozen=True)
class LoadModel:
    """P(full) = 1 / (1 + exp(-(bias + sum w_i (x_i - mean_i) / scale_i))), x the named LOAD_FEATURES."""

    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float

    def __post_init__(self) -> None:
        unknown = set(self.features) - set(LOAD_NAMES)
        if unknown or not (len(self.features) == len(self.mean) == len(self.scale) == len(self.weights)):
            raise ModelError(f"load model: features {sorted(unknown)} unknown or lengths differ")

    def probability_full(self, window: WindowIndicators, geometry: BogieGeometry) -> float:
        """P(full) of one window; NaN when the window has no spectra or a mode no power."""
        if window.spectra is None:
            return math.nan
        return self.probability_of(WindowFeatures(window.spectra, geometry).load)

    def probability_of(self, load_vector: NDArray[np.float64]) -> float:
        """P(full) of a window's load vector (LOAD_NAMES; NaN where a mode had no power)."""
        x = load_vector[[LOAD_NAMES.index(f) for f in self.features]]
        z = self.bias + float(np.dot(self.weights, (x - np.asarray(self.mean)) / np.asarray(self.scale)))
        if not math.isfinite(z):
            return math.nan
        return 1.0 / (1.0 + math.exp(-max(min(z, 50.0), -50.0)))


@dataclass(frozen=True)
class LoadSignature:
    """A load state the wagon was commissioned in (decision.load_states): its windows' load vector
    (LOAD_NAMES) has this center and robust scale, and their distance (the RMS of the z-scores)
    reached limit; their excitation (excitation_of, m/s^2) spanned lowest..highest.

    The load vector is how the modes share their power between the bands: the track, the speed and
    the load set it, and so does a broken spring (it moves the modes' frequencies). So its distance
    is evidence stated with a judgement, never a reason to leave a window unjudged
    (judgement/running.py): only the excitation, which a one-corner fault hardly moves, says whether
    the running is like the commissioning's. Old configs have no highest excitation: unbounded."""

    load: LoadState
    center: NDArray[np.float64]
    scale: NDArray[np.float64]
    limit: float
    lowest_excitation_mps2: float = 0.0
    highest_excitation_mps2: float = math.inf

    def distance(self, x: NDArray[np.float64]) -> float:
        z = (x - self.center) / self.scale
        return float(np.sqrt(np.mean(z * z)))

    def excitation_outside(self, excitation_mps2: float) -> float:
        """How far outside the commissioning's excitation a window runs, as a factor >= 1 (1:
        within; 2: half the gentlest or twice the roughest commissioning window)."""
        if not excitation_mps2 > 0:
            return math.inf
        return max(1.0, self.lowest_excitation_mps2 / excitation_mps2, excitation_mps2 / self.highest_excitation_mps2)


def excitation_of(window: WindowIndicators) -> float:
    """A window's excitation: the median channel's RMS after the high-pass, m/s^2 (a faulty sensor
    moves neither the median nor the gate that uses the same figure, judgement/health.py)."""
    return float(np.median(window.rms_mps2))


def load_features(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    """The load vector of a window (LOAD_NAMES); None when it has no spectra or a mode no power."""
    if window.spectra is None:
        return None
    return finite_or_none(WindowFeatures(window.spectra, geometry).load)


@dataclass(frozen=True)
class LoadDiscriminant:
    """The wagon's own line between its two commissioned load states (decision.load_discriminant):
    a linear discriminant of the load vector, scaled so that its value's healthy scatter within a
    state is 1 (judgement/commissioning.py: fit_discriminant). Positive: full."""

    weights: NDArray[np.float64]
    offset: float
    margin: float  # |value| below this: between the states, not judged
    separation: float  # the distance of the states' centres along it, in the same units

    def value(self, x: NDArray[np.float64]) -> float:
        return float(np.dot(self.weights, x) + self.offset)

    def load_of(self, x: NDArray[np.float64]) -> LoadState | None:
        v = self.value(x)
        return LoadState.FULL if v >= self.margin else LoadState.TARE if v <= -self.margin else None


# --------------------------------------------------------------------------------------------
# The fused score


@dataclass(frozen=True)
class Levels:
    """Warning and alarm levels of the window score and of the trend, for one baseline."""

    warning: float
    alarm: float
    trend_warning: float
    trend_alarm: float

    def scaled(self, factor: float) -> Levels:
        return Levels(self.warning * factor, self.alarm * factor, self.trend_warning * factor, self.trend_alarm * factor)


@dataclass(frozen=True)
class Baseline:
    """A healthy reference of the coupling vector: center and the inverse Cholesky factor of its
    covariance (whitening: z = L (x - center), score = |z|^2), with levels on the window score and
    on the trend (|EWMA of z|^2 with time constant trend_tau_s of running)."""

    name: str  # "calibrated" (this wagon's) or "population" (the shipped fleet's)
    center: NDArray[np.float64]
    whitening: NDArray[np.float64]  # L with L^T L = covariance^-1
    levels: Levels
    trend_tau_s: float

    @property
    def warning(self) -> float:
        return self.levels.warning

    @property
    def alarm(self) -> float:
        return self.levels.alarm

    def whiten(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        return self.whitening @ (x - self.center)

    def score(self, x: NDArray[np.float64]) -> float:
        z = self.whiten(x)
        return float(z @ z)

    @functools.cached_property
    def fingerprint(self) -> str:
        """Identifies the center and spread: a trend accumulated against another baseline restarts."""
        return hashlib.sha256(np.round(np.concatenate([self.center, self.whitening.ravel()]), 9).tobytes()).hexdigest()[:16]


def whitening_of(covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """L with L^T L = covariance^-1 (the inverse of the lower Cholesky factor)."""
    return np.linalg.inv(np.linalg.cholesky(np.asarray(covariance, dtype=np.float64))).astype(np.float64, copy=False)


@dataclass(frozen=True)
class FusedModel:
    """The fused score's shipped part for one load: the spread of a calibrated wagon's healthy
    couplings around its own center (covariance, levels) and the fleet's baseline for a wagon
    without calibration (population center, covariance, levels)."""

    load: LoadState
    features: tuple[str, ...]
    window_s: float  # the processing windows it was fitted on: the spread depends on them
    hop_s: float
    covariance: NDArray[np.float64]
    levels: Levels  # of a calibrated wagon
    trend_tau_s: float
    population_center: NDArray[np.float64]
    population_covariance: NDArray[np.float64]
    population_levels: Levels
    calibration_median_score: float  # the median score of a training wagon's own calibration windows

    def fits(self, settings: ProcessingSettings) -> bool:
        """Whether windows of these processing settings are the ones the model was fitted on."""
        return math.isclose(settings.window_s, self.window_s) and math.isclose(settings.hop_s, self.hop_s)

    def population(self) -> Baseline:
        return Baseline("population", self.population_center, whitening_of(self.population_covariance), self.population_levels, self.trend_tau_s)

    def calibrated(self, center: Sequence[float], levels: Levels, covariance: NDArray[np.float64] | None = None) -> Baseline:
        """The wagon's baseline: its center, and its own spread when commissioning learned one."""
        spread = self.covariance if covariance is None else np.asarray(covariance, dtype=np.float64)
        return Baseline("calibrated", np.asarray(center, dtype=np.float64), whitening_of(spread), levels, self.trend_tau_s)


def finite_or_none(x: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """x, or None when an entry is not finite (a mode without power in a band): nothing to judge by."""
    return x if bool(np.all(np.isfinite(x))) else None


def coupling_features(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    """The coupling vector of a window; None when it has no spectra or a mode had no power."""
    if window.spectra is None:
        return None
    return finite_or_none(WindowFeatures(window.spectra, geometry).coupling)


# --------------------------------------------------------------------------------------------
# Reading the files


def _read(name: str, directory: str = "") -> dict[str, Any]:
    try:
        if directory:
            text = (Path(directory) / name).read_text(encoding="utf-8")
        else:
            text = resources.files("bogiemon.config").joinpath(name).read_text(encoding="utf-8")
    except (OSError, ValueError):
        where = directory or "bogiemon's config folder"
        raise ModelError(f"{name}: no such model file in {where}; regenerate it with `bogiemon evaluate --fit-models`") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ModelError(f"{name}: invalid TOML: {exc}") from None


def _floats(data: Mapping[str, Any], key: str, where: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in data[key])
    except (KeyError, TypeError, ValueError):
        raise ModelError(f"{where}.{key}: expected a list of numbers") from None


def _matrix(data: Mapping[str, Any], key: str, where: str, n: int) -> NDArray[np.float64]:
    try:
        m = np.array(data[key], dtype=np.float64)
    except (KeyError, TypeError, ValueError):
        raise ModelError(f"{where}.{key}: expected a {n} x {n} matrix") from None
    if m.shape != (n, n) or not np.all(np.isfinite(m)):
        raise ModelError(f"{where}.{key}: expected a finite {n} x {n} matrix, got shape {m.shape}")
    return m


def parse_load_model(data: Mapping[str, Any], where: str = LOAD_MODEL_FILE) -> LoadModel:
    try:
        return LoadModel(
            features=tuple(str(f) for f in data["features"]),
            mean=_floats(data, "mean", where),
            scale=_floats(data, "scale", where),
            weights=_floats(data, "weights", where),
            bias=float(data["bias"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelError(f"{where}: {exc}") from None


def parse_fused_model(data: Mapping[str, Any], load: LoadState, where: str = FUSED_MODEL_FILE) -> FusedModel:
    section = data.get(load)
    if not isinstance(section, Mapping):
        raise ModelError(f"{where}: no [{load}] table")
    w = f"{where}: {load}"
    listed = section.get("features", ())
    features = tuple(str(f) for f in listed) if isinstance(listed, list | tuple) else (repr(listed),)
    if features != COUPLING_NAMES:
        raise ModelError(f"{w}.features: {list(features)} differ from the detection core's {list(COUPLING_NAMES)}")
    n = len(features)
    try:
        return FusedModel(
            load=load,
            features=features,
            window_s=float(section["window_s"]),
            hop_s=float(section["hop_s"]),
            covariance=_matrix(section, "covariance", w, n),
            levels=Levels(float(section["warning"]), float(section["alarm"]), float(section["trend_warning"]), float(section["trend_alarm"])),
            trend_tau_s=float(section["trend_tau_s"]),
            population_center=np.array(_floats(section, "population_center", w)),
            population_covariance=_matrix(section, "population_covariance", w, n),
            population_levels=Levels(
                float(section["population_warning"]), float(section["population_alarm"]),
                float(section["population_trend_warning"]), float(section["population_trend_alarm"]),
            ),  # fmt: skip
            calibration_median_score=float(section["calibration_median_score"]),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelError(f"{w}: missing or bad field {exc}") from None


@dataclass(frozen=True)
class ShippedModels:
    load: LoadModel
    fused: Mapping[LoadState, FusedModel]


def model_paths(directory: str = "") -> tuple[Path, Path]:
    """Where the load and fused models are read from: `directory`, else bogiemon's config folder."""
    folder = Path(directory) if directory else Path(str(resources.files("bogiemon.config")))
    return folder / LOAD_MODEL_FILE, folder / FUSED_MODEL_FILE


def shipped_models(directory: str = "") -> ShippedModels:
    """The priors in bogiemon's config folder, or in `directory` (decision.models_dir: priors
    refitted on another fleet); read again only when a file changed (a reload then reads the new
    ones, and refuses damaged ones, instead of keeping what it read first)."""
    return _parsed_models(directory, tuple(_stamp(path) for path in model_paths(directory)))


def _stamp(path: Path) -> tuple[int, ...]:
    """What tells a file's version apart without reading it (missing: empty)."""
    try:
        st = path.stat()
    except (OSError, ValueError):
        return ()
    return (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


@functools.lru_cache(maxsize=8)
def _parsed_models(directory: str, stamps: tuple[tuple[int, ...], ...]) -> ShippedModels:
    load = parse_load_model(_read(LOAD_MODEL_FILE, directory))
    fused_data = _read(FUSED_MODEL_FILE, directory)
    return ShippedModels(load=load, fused={ld: parse_fused_model(fused_data, ld) for ld in LoadState})

