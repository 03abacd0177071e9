"""Commissioning: learning a wagon's healthy baseline from recordings of it, per load state.

Only windows the daemon would judge count (moving, enough excitation, healthy sensors in their
configured places). Each load state is best commissioned from its own recordings (`--full ...
--tare ...`, calibrate_loads); `--load auto` splits the windows with the shipped load model, a
prior fitted on our simulator (judgement/commissioning.py says why no cluster split replaces it).
Per load, three things are learned:

THE LOAD STATE (decision.load_states): the centre, robust scale and familiarity limit of the
windows' load vector, so that with decision.load = "auto" a window goes to the nearest
commissioned state, or is not judged when it is like none of them (judgement/commissioning.py).

THE FUSED BASELINE (decision.method "fused"): the centre is the mean coupling vector of the
wagon's healthy windows; the spread is the wagon's own covariance shrunk towards the shipped one;
the levels are the shipped ones raised by how much worse the wagon's commissioning runs score out
of sample, and the trend's by the largest out-of-sample trend (judgement/commissioning.py:
fit_spread). Never lowered below the shipped levels.

THE THRESHOLDS (decision.method "thresholds"): for each indicator the config thresholds, with d
the deviation from the healthy median and sigma = 1.4826 * MAD (a standard deviation that ignores
outliers):

    warning = max(z(p_warning) * sigma, the (1 - p_warning) quantile of |d|)
    alarm   = max(z(p_alarm) * sigma, 1.1 * the largest |d| seen, warning)

where z(p) is the two-sided normal quantile of a per-window false-alarm rate p (the rule itself is
judgement/rules.py's fit_threshold, which the lab's study uses too). The empirical
terms keep heavy-tailed indicators honest: no healthy calibration window reaches the alarm level,
and confirmation (k of n windows) lowers the false-alarm rate of CONFIRMED far below p_alarm.

All of it goes into one config fragment for the daemon's `include` list.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.daemon import tomlout
from bogiemon.daemon.analysis import analyze_recording, open_recording
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.judgement.events import INDICATOR_FIELDS
from bogiemon.judgement.health import assess_window
from bogiemon.judgement.structure import StructureFit, learn_structure, merge_structures
from bogiemon.judgement.noise_floor import NoiseFloorFit, learn_noise_floor, merge_noise_floors
from bogiemon.judgement.commissioning import fit_discriminant, fit_spread, load_signature, runs_of, split_loads
from bogiemon.judgement.models import Levels, LoadDiscriminant, LoadSignature, coupling_features, load_features, shipped_models
from bogiemon.judgement.rules import Threshold, fit_threshold
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import WindowIndicators
from bogiemon.detection.features import COUPLING_NAMES

MIN_WINDOWS = 30
LOADS = tuple(LoadState)


class CalibrationError(ValueError):
    """Calibration cannot produce trustworthy thresholds; the message says what to record."""


@dataclass(frozen=True)
class IndicatorCalibration:
    name: str
    median: float
    robust_sigma: float
    max_deviation: float
    threshold: Threshold


@dataclass(frozen=True)
class FusedCalibration:
    """The wagon's fused baseline for one load (judgement/commissioning.py: fit_spread)."""

    center: tuple[float, ...]
    levels: Levels
    median_score: float  # of the calibration windows against their own center
    level_factor: float  # the shipped window levels were multiplied by this (>= 1)
    covariance: tuple[tuple[float, ...], ...]  # the wagon's own spread, shrunk towards the shipped one
    shrinkage: float  # the shipped spread's weight in it
    runs: int  # commissioning runs (stretches of consecutive windows)
    out_of_sample_median: float | None  # each run scored against the others (None: too few runs)


@dataclass(frozen=True)
class LoadCalibration:
    load: LoadState
    n_judged: int
    indicators: tuple[IndicatorCalibration, ...]
    fused: FusedCalibration | None  # None when the processing windows are not the fused model's
    signature: LoadSignature | None = None  # the load state's own load vector, for load "auto"
    # The load vectors of its windows, for the discriminant between two states (not written out).
    load_rows: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)


@dataclass(frozen=True)
class CalibrationResult:
    load: str  # as asked: "full", "tare" or "auto"
    files: tuple[str, ...]
    n_windows: int
    warning_rate: float
    alarm_rate: float
    loads: tuple[LoadCalibration, ...]
    skipped: dict[LoadState, int]  # loads seen with too few windows (auto): load -> windows
    load_note: str = ""  # how the load states were told apart (auto)
    load_named_by_prior: bool = False  # one state, named by the shipped load model: the keeper should state it
    # The frame structure of its three sensors the wagon showed (which inverted/swapped checks hold):
    # in force after commissioning, so a changed structure is a sensor fault (judgement/health.py).
    structure: StructureFit | None = None
    # With both load states: the wagon's own line between them (judgement/commissioning.py).
    discriminant: LoadDiscriminant | None = None
    # Its sensors' noise floors (judgement/noise_floor.py): in force after commissioning, so a sensor whose
    # floor rises far above what the healthy wagon showed is noisy.
    noise_floor: NoiseFloorFit | None = None

    @property
    def n_judged(self) -> int:
        return sum(c.n_judged for c in self.loads)

    @property
    def indicators(self) -> tuple[IndicatorCalibration, ...]:
        """The thresholds of a single-load calibration."""
        if len(self.loads) != 1:
            raise ValueError(f"{len(self.loads)} load states were calibrated: use .loads")
        return self.loads[0].indicators


def calibrate(
    paths: Sequence[str | Path],
    config: BogiemonConfig,
    load: str,
    indicators: Sequence[str] | None = None,
    warning_rate: float = 1e-2,
    alarm_rate: float = 1e-4,
) -> CalibrationResult:
    """Calibrate from recordings (CSV) of the healthy wagon; see the module docstring."""
    health = config.health_settings()
    windows: list[WindowIndicators] = []
    runs: list[int] = []
    for number, path in enumerate(paths):
        recording = open_recording(path, config, "calibrate")
        these = list(analyze_recording(recording, config, clip_level_mps2=health.clip_level_mps2))
        windows += these
        runs += [number] * len(these)
    return calibrate_windows(windows, config, load, indicators, warning_rate, alarm_rate, files=tuple(str(p) for p in paths), runs=runs)


def calibrate_loads(
    paths_by_load: Mapping[str, Sequence[str | Path]],
    config: BogiemonConfig,
    indicators: Sequence[str] | None = None,
    warning_rate: float = 1e-2,
    alarm_rate: float = 1e-4,
) -> CalibrationResult:
    """Commission each load state from its own recordings ({"full": [...], "tare": [...]}): the
    way that needs no model of the wagon to tell its loads apart (judgement/commissioning.py)."""
    if not paths_by_load or set(paths_by_load) - set(LOADS):
        raise CalibrationError(f"recordings per load state: use {' and '.join(LOADS)}; got {sorted(paths_by_load)}")
    return combine_loads([calibrate(paths, config, load, indicators, warning_rate, alarm_rate) for load, paths in sorted(paths_by_load.items())], config)


def combine_loads(parts: Sequence[CalibrationResult], config: BogiemonConfig) -> CalibrationResult:
    """One commissioning from each load state's own (one load each): the structure checks in force
    are those that held in every load, and with both loads the line between them."""
    loads = [c.load for r in parts for c in r.loads]
    if len(set(loads)) != len(loads):
        raise CalibrationError(f"each load state once: got {loads}")
    first = parts[0]
    return CalibrationResult(
        "per load", tuple(f for r in parts for f in r.files), sum(r.n_windows for r in parts), first.warning_rate, first.alarm_rate,
        tuple(c for r in parts for c in r.loads), {}, "each load state from its own recordings",
        structure=merge_structures([r.structure for r in parts if r.structure is not None]),
        discriminant=_discriminant([c for r in parts for c in r.loads], config),
        noise_floor=merge_noise_floors([r.noise_floor for r in parts]),
    )  # fmt: skip


def calibrate_windows(
    windows: Iterable[WindowIndicators],
    config: BogiemonConfig,
    load: str,
    indicators: Sequence[str] | None = None,
    warning_rate: float = 1e-2,
    alarm_rate: float = 1e-4,
    files: tuple[str, ...] = (),
    runs: Sequence[int] | None = None,
) -> CalibrationResult:
    """Calibrate from windows of the healthy wagon (the detection core's, in time order or not).

    runs: each window's run (e.g. its recording's number), for the out-of-sample check of the
    spread; None: runs are stretches of consecutive windows.
    """
    windows = list(windows)
    run_of = {id(w): r for w, r in zip(windows, runs, strict=True)} if runs is not None else None
    if load not in (*LOADS, "auto"):
        raise CalibrationError(f"load state '{load}': use full, tare or auto")
    if not 0 < alarm_rate <= warning_rate < 1:
        raise CalibrationError(f"need 0 < alarm rate ({alarm_rate}) <= warning rate ({warning_rate}) < 1")
    health = config.health_settings()
    geometry = config.bogie_geometry()
    by_load: dict[LoadState, list[WindowIndicators]] = {ld: [] for ld in LOADS}
    n_windows = 0
    judgeable = []
    for window in windows:
        n_windows += 1
        if assess_window(window, health, geometry=geometry).judgeable:
            judgeable.append(window)
    split = None
    if load == "auto":
        # The wagon's own load states, told apart by its own windows (judgement/commissioning.py).
        split = split_loads(judgeable, geometry, config.load_model())
        for ld, ws in split.windows.items():
            by_load[LoadState(ld)] = ws
    else:
        by_load[LoadState(load)] = judgeable
    wanted = LOADS if load == "auto" else (LoadState(load),)
    results, skipped = [], {}
    for ld in wanted:
        judged = by_load[ld]
        if len(judged) < MIN_WINDOWS:
            if load == "auto" and judged:
                skipped[ld] = len(judged)
            if load != "auto":
                raise CalibrationError(
                    f"only {len(judged)} of {n_windows} windows could be judged (moving, healthy sensors); "
                    f"calibration needs at least {MIN_WINDOWS}: record longer runs of the healthy wagon"
                )
            continue
        names = list(indicators) if indicators else list(config.decision.thresholds.get(ld, {}))
        unknown = set(names) - set(INDICATOR_FIELDS)
        if not names or unknown:
            raise CalibrationError(f"indicators to calibrate must be among {', '.join(INDICATOR_FIELDS)}; got {names}")
        thresholds = tuple(_indicator(n, [float(getattr(w, n)) for w in judged], warning_rate, alarm_rate) for n in names)
        rows = np.array([v for w in judged if (v := load_features(w, geometry)) is not None])
        results.append(LoadCalibration(ld, len(judged), thresholds, _fused(judged, config, ld, run_of), load_signature(ld, judged, geometry), rows))
    if not results:
        counts = ", ".join(f"{ld} {len(by_load[ld])}" for ld in LOADS)
        raise CalibrationError(
            f"no load state had {MIN_WINDOWS} judged windows of {n_windows} ({counts}): record longer runs of the healthy wagon"
        )
    return CalibrationResult(
        load, files, n_windows, warning_rate, alarm_rate, tuple(results), skipped,
        split.note if split is not None else "", split.by_prior if split is not None else False,
        learn_structure(judgeable, geometry), _discriminant(results, config), learn_noise_floor(judgeable),
    )  # fmt: skip


def _discriminant(loads: Sequence[LoadCalibration], config: BogiemonConfig) -> LoadDiscriminant | None:
    rows = {c.load: c.load_rows for c in loads if c.load_rows is not None and len(c.load_rows)}
    if set(rows) != set(LoadState):
        return None
    return fit_discriminant(rows[LoadState.FULL], rows[LoadState.TARE], config.processing.window_s / config.processing.hop_s)


def _indicator(name: str, values: list[float], warning_rate: float, alarm_rate: float) -> IndicatorCalibration:
    fit = fit_threshold(values, warning_rate, alarm_rate)
    return IndicatorCalibration(name, fit.center, fit.robust_sigma, fit.max_deviation, Threshold(warning=fit.warning, alarm=fit.alarm, center=fit.center))


def _fused(windows: Sequence[WindowIndicators], config: BogiemonConfig, load: LoadState, run_of: Mapping[int, int] | None) -> FusedCalibration | None:
    model = shipped_models(config.decision.models_dir).fused[load]
    if not model.fits(config.processing_settings()):
        return None
    geometry = config.bogie_geometry()
    kept = [(w, x) for w in windows if (x := coupling_features(w, geometry)) is not None]
    if len(kept) < MIN_WINDOWS:
        return None
    rows = np.array([x for _, x in kept])
    if run_of is not None:
        groups: dict[int, list[int]] = {}
        for i, (w, _) in enumerate(kept):
            groups.setdefault(run_of[id(w)], []).append(i)
        runs = [groups[r] for r in sorted(groups)]
    else:
        runs = runs_of([w for w, _ in kept], config.processing.hop_s)
    fit = fit_spread(rows, runs, model, config.processing.hop_s, config.decision.confirm_k, config.decision.confirm_n)
    return FusedCalibration(
        tuple(float(v) for v in fit.center), fit.levels, fit.median_score, fit.level_factor,
        tuple(tuple(float(v) for v in row) for row in fit.covariance), fit.shrinkage, fit.runs, fit.out_of_sample_median,
    )  # fmt: skip


def fragment(result: CalibrationResult) -> str:
    """The calibration as a config fragment for the daemon's `include` list."""
    header = [
        f"# Learned by `bogiemon calibrate` on {datetime.now(UTC):%Y-%m-%d %H:%M} UTC",
        f"# from {len(result.files)} recording(s) of a healthy wagon, load state '{result.load}':",
        *(f"#   {f}" for f in result.files),
        f"# {result.n_judged} of {result.n_windows} windows judged ("
        + ", ".join(f"{c.load} {c.n_judged}" for c in result.loads)
        + f"); per-window false-alarm targets of the thresholds: warning {result.warning_rate:g}, alarm {result.alarm_rate:g}.",
        "# decision.fused.<load>: this wagon's healthy center of the coupling vector for the fused score and its levels;",
        "# decision.thresholds.<load>: the thresholds of the indicators (daemon/calibrate.py states both rules).",
        "# decision.fused.<load>.covariance: this wagon's own spread of the couplings (judgement/commissioning.py);",
        "# decision.load_states.<load>: the load states it was commissioned in, for decision.load = \"auto\";",
        "# decision.load_discriminant: with both, this wagon's own line between them (near it: not judged).",
        "# health.layout_checks: the checks of the sensors' places and signs that held on every healthy window",
        "# (none held: none in force, so no SWAPPED or INVERTED is ever reported for this wagon);",
        "# health.noise_floor_*: each sensor's smallest noise floor and largest ratio to the others' on the healthy windows.",
        *([f"# Load states: {result.load_note}."] if result.load_note else []),
        "# Include it from the daemon's config: include = [\"<this file>\"]",
    ]
    thresholds = {
        c.load: {i.name: {"center": i.threshold.center, "warning": i.threshold.warning, "alarm": i.threshold.alarm} for i in c.indicators}
        for c in result.loads
    }
    fused = {
        c.load: {
            "features": list(COUPLING_NAMES), "center": list(c.fused.center), "warning": c.fused.levels.warning, "alarm": c.fused.levels.alarm,
            "trend_warning": c.fused.levels.trend_warning, "trend_alarm": c.fused.levels.trend_alarm, "windows": c.n_judged,
            **({"covariance": [list(row) for row in c.fused.covariance]} if c.fused.shrinkage < 1.0 else {}),
        }  # fmt: skip
        for c in result.loads
        if c.fused is not None
    }
    load_states = {
        c.load: {"center": [float(v) for v in c.signature.center], "scale": [float(v) for v in c.signature.scale],
                 "limit": c.signature.limit, "windows": c.n_judged,
                 "lowest_excitation_mps2": math.floor(c.signature.lowest_excitation_mps2 * 1e4) / 1e4,
                 "highest_excitation_mps2": math.ceil(c.signature.highest_excitation_mps2 * 1e4) / 1e4}  # fmt: skip
        for c in result.loads
        if c.signature is not None
    }
    body: dict[str, Any] = {"decision": {"thresholds": thresholds, **({"fused": fused} if fused else {}), **({"load_states": load_states} if load_states else {})}}
    if result.discriminant is not None:
        d = result.discriminant
        body["decision"]["load_discriminant"] = {
            "weights": [float(v) for v in d.weights], "offset": d.offset, "margin": d.margin, "separation": d.separation,
        }  # fmt: skip
    if result.structure is not None:
        body["health"] = result.structure.health_fields()
    if result.noise_floor is not None:
        body.setdefault("health", {}).update(result.noise_floor.health_fields())
    return "\n".join(header) + "\n\n" + tomlout.dumps(body)
