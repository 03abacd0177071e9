"""Commissioning: learning a wagon's healthy baseline from recordings of it, per load state.

Only windows the daemon would judge count (moving, enough excitation, healthy sensors in their
configured places). With `load` "auto" each window goes to the load state the daemon estimates
for it, and every load with enough windows is calibrated. Per load, two things are learned:

THE FUSED BASELINE (decision.method "fused"): the center is the mean coupling vector of the
wagon's healthy windows; the spread is the shipped one (config/fused_model.toml), and so are the
levels of the window score and of the trend, raised in proportion when this wagon's own windows
scatter more around their center than the training fleet's did (the median score over the
calibration windows against the shipped median; never lowered):

    levels = shipped levels x max(1, median score here / shipped median score)

THE THRESHOLDS (decision.method "thresholds"): for each indicator the config thresholds, with d
the deviation from the healthy median and sigma = 1.4826 * MAD (a standard deviation that ignores
outliers):

    warning = max(z(p_warning) * sigma, the (1 - p_warning) quantile of |d|)
    alarm   = max(z(p_alarm) * sigma, 1.1 * the largest |d| seen, warning)

where z(p) is the two-sided normal quantile of a per-window false-alarm rate p (the rule itself is
daemon/rules.py's fit_threshold, which the lab's study uses too). The empirical
terms keep heavy-tailed indicators honest: no healthy calibration window reaches the alarm level,
and confirmation (k of n windows) lowers the false-alarm rate of CONFIRMED far below p_alarm.

Both go into one config fragment for the daemon's `include` list.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from bogiemon.daemon import tomlout
from bogiemon.daemon.analysis import analyze_recording, open_recording
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.decision import INDICATOR_FIELDS
from bogiemon.daemon.health import assess_window
from bogiemon.daemon.models import Levels, coupling_features, shipped_models
from bogiemon.daemon.rules import Threshold, fit_threshold
from bogiemon.detection import WindowIndicators
from bogiemon.detection.features import COUPLING_NAMES

MIN_WINDOWS = 30
LOADS = ("full", "tare")


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
    """The wagon's fused baseline for one load."""

    center: tuple[float, ...]
    levels: Levels
    median_score: float  # of the calibration windows against their own center
    level_factor: float  # the shipped levels were multiplied by this (>= 1)


@dataclass(frozen=True)
class LoadCalibration:
    load: str
    n_judged: int
    indicators: tuple[IndicatorCalibration, ...]
    fused: FusedCalibration | None  # None when the processing windows are not the fused model's


@dataclass(frozen=True)
class CalibrationResult:
    load: str  # as asked: "full", "tare" or "auto"
    files: tuple[str, ...]
    n_windows: int
    warning_rate: float
    alarm_rate: float
    loads: tuple[LoadCalibration, ...]
    skipped: dict[str, int]  # loads seen with too few windows (auto): load -> windows

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
    for path in paths:
        recording = open_recording(path, config)
        windows += analyze_recording(recording, config, clip_level_mps2=health.clip_level_mps2)
    return calibrate_windows(windows, config, load, indicators, warning_rate, alarm_rate, files=tuple(str(p) for p in paths))


def calibrate_windows(
    windows: Iterable[WindowIndicators],
    config: BogiemonConfig,
    load: str,
    indicators: Sequence[str] | None = None,
    warning_rate: float = 1e-2,
    alarm_rate: float = 1e-4,
    files: tuple[str, ...] = (),
) -> CalibrationResult:
    """Calibrate from windows of the healthy wagon (the detection core's, in time order or not)."""
    if load not in (*LOADS, "auto"):
        raise CalibrationError(f"load state '{load}': use full, tare or auto")
    if not 0 < alarm_rate <= warning_rate < 1:
        raise CalibrationError(f"need 0 < alarm rate ({alarm_rate}) <= warning rate ({warning_rate}) < 1")
    health = config.health_settings()
    geometry = config.bogie_geometry()
    load_model = config.load_model() if load == "auto" else None
    by_load: dict[str, list[WindowIndicators]] = {ld: [] for ld in LOADS}
    n_windows = 0
    for window in windows:
        n_windows += 1
        if not assess_window(window, health, geometry=geometry).judgeable:
            continue
        if load_model is not None:
            by_load["full" if load_model.probability_full(window, geometry) >= 0.5 else "tare"].append(window)
        else:
            by_load[load].append(window)
    wanted = LOADS if load == "auto" else (load,)
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
        names = list(indicators) if indicators else list(config.decision.thresholds.get(ld, {}))  # type: ignore[call-overload]
        unknown = set(names) - set(INDICATOR_FIELDS)
        if not names or unknown:
            raise CalibrationError(f"indicators to calibrate must be among {', '.join(INDICATOR_FIELDS)}; got {names}")
        thresholds = tuple(_indicator(n, [float(getattr(w, n)) for w in judged], warning_rate, alarm_rate) for n in names)
        results.append(LoadCalibration(ld, len(judged), thresholds, _fused(judged, config, ld)))
    if not results:
        counts = ", ".join(f"{ld} {len(by_load[ld])}" for ld in LOADS)
        raise CalibrationError(
            f"no load state had {MIN_WINDOWS} judged windows of {n_windows} ({counts}): record longer runs of the healthy wagon"
        )
    return CalibrationResult(load, files, n_windows, warning_rate, alarm_rate, tuple(results), skipped)


def _indicator(name: str, values: list[float], warning_rate: float, alarm_rate: float) -> IndicatorCalibration:
    fit = fit_threshold(values, warning_rate, alarm_rate)
    return IndicatorCalibration(name, fit.center, fit.robust_sigma, fit.max_deviation, Threshold(warning=fit.warning, alarm=fit.alarm, center=fit.center))


def _fused(windows: Sequence[WindowIndicators], config: BogiemonConfig, load: str) -> FusedCalibration | None:
    model = shipped_models().fused[load]
    if not model.fits(config.processing_settings()):
        return None
    geometry = config.bogie_geometry()
    rows = [x for x in (coupling_features(w, geometry) for w in windows) if x is not None]
    if len(rows) < MIN_WINDOWS:
        return None
    x = np.array(rows)
    center = x.mean(axis=0)
    baseline = model.calibrated(center, model.levels)
    median_score = float(np.median([baseline.score(row) for row in x]))
    factor = max(1.0, median_score / model.calibration_median_score)
    return FusedCalibration(tuple(float(v) for v in center), model.levels.scaled(factor), median_score, factor)


def fragment(result: CalibrationResult) -> str:
    """The calibration as a config fragment for the daemon's `include` list."""
    header = [
        f"# Learned by `bogiemon calibrate` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"# from {len(result.files)} recording(s) of a healthy wagon, load state '{result.load}':",
        *(f"#   {f}" for f in result.files),
        f"# {result.n_judged} of {result.n_windows} windows judged ("
        + ", ".join(f"{c.load} {c.n_judged}" for c in result.loads)
        + f"); per-window false-alarm targets of the thresholds: warning {result.warning_rate:g}, alarm {result.alarm_rate:g}.",
        "# decision.fused.<load>: this wagon's healthy center of the coupling vector for the fused score and its levels;",
        "# decision.thresholds.<load>: the thresholds of the indicators (daemon/calibrate.py states both rules).",
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
        }  # fmt: skip
        for c in result.loads
        if c.fused is not None
    }
    body = {"decision": {"thresholds": thresholds, **({"fused": fused} if fused else {})}}
    return "\n".join(header) + "\n\n" + tomlout.dumps(body)
