"""Learning thresholds from recordings of a healthy wagon: the bench engineer's tuning step.

Only windows the daemon would judge count (moving, enough excitation, healthy sensors). For each
indicator, with d the deviation from the healthy median and sigma = 1.4826 * MAD (a standard
deviation that ignores outliers):

    warning = max(z(p_warning) * sigma, the (1 - p_warning) quantile of |d|)
    alarm   = max(z(p_alarm) * sigma, 1.1 * the largest |d| seen, warning)

where z(p) is the two-sided normal quantile of a per-window false-alarm rate p. The empirical
terms keep heavy-tailed indicators honest: no healthy calibration window reaches the alarm level,
and confirmation (k of n windows) lowers the false-alarm rate of CONFIRMED far below p_alarm.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from scipy import stats

from bogiemon.daemon import tomlout
from bogiemon.daemon.analysis import analyze_recording, open_recording
from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.decision import INDICATOR_FIELDS, Threshold
from bogiemon.daemon.health import assess_window

MIN_WINDOWS = 30
ALARM_MARGIN = 1.1


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
class CalibrationResult:
    load: str
    files: tuple[str, ...]
    n_windows: int
    n_judged: int
    warning_rate: float
    alarm_rate: float
    indicators: tuple[IndicatorCalibration, ...]


def calibrate(
    paths: Sequence[str | Path],
    config: BogiemonConfig,
    load: str,
    indicators: Sequence[str] | None = None,
    warning_rate: float = 1e-2,
    alarm_rate: float = 1e-4,
) -> CalibrationResult:
    names = list(indicators) if indicators else list(config.decision.thresholds.get(load, {}))
    unknown = set(names) - set(INDICATOR_FIELDS)
    if not names or unknown:
        raise CalibrationError(f"indicators to calibrate must be among {', '.join(INDICATOR_FIELDS)}; got {names}")
    if not 0 < alarm_rate <= warning_rate < 1:
        raise CalibrationError(f"need 0 < alarm rate ({alarm_rate}) <= warning rate ({warning_rate}) < 1")
    health_settings = config.health_settings()
    values: dict[str, list[float]] = {n: [] for n in names}
    n_windows = 0
    for path in paths:
        recording = open_recording(path, config)
        for window in analyze_recording(recording, config, clip_level_mps2=health_settings.clip_level_mps2):
            n_windows += 1
            if assess_window(window, health_settings).judgeable:
                for n in names:
                    values[n].append(float(getattr(window, n)))
    n_judged = len(values[names[0]])
    if n_judged < MIN_WINDOWS:
        raise CalibrationError(
            f"only {n_judged} of {n_windows} windows could be judged (moving, healthy sensors); "
            f"calibration needs at least {MIN_WINDOWS}: record longer runs of the healthy wagon"
        )
    z_warning = float(stats.norm.isf(warning_rate / 2))
    z_alarm = float(stats.norm.isf(alarm_rate / 2))
    out = []
    for n in names:
        x = np.array(values[n])
        median = float(np.median(x))
        deviation = np.abs(x - median)
        sigma = 1.4826 * float(np.median(deviation))
        largest = float(deviation.max())
        warning = max(z_warning * sigma, float(np.quantile(deviation, 1 - warning_rate)), np.finfo(float).tiny)
        alarm = max(z_alarm * sigma, ALARM_MARGIN * largest, warning)
        out.append(IndicatorCalibration(n, median, sigma, largest, Threshold(warning=warning, alarm=alarm, center=median)))
    return CalibrationResult(load, tuple(str(p) for p in paths), n_windows, n_judged, warning_rate, alarm_rate, tuple(out))


def fragment(result: CalibrationResult) -> str:
    """The thresholds as a config fragment for the daemon's `include` list."""
    header = [
        f"# Thresholds learned by `bogiemon calibrate` on {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC",
        f"# from {len(result.files)} recording(s) of a healthy wagon, load state '{result.load}':",
        *(f"#   {f}" for f in result.files),
        f"# {result.n_judged} of {result.n_windows} windows judged; per-window false-alarm targets:",
        f"# warning {result.warning_rate:g}, alarm {result.alarm_rate:g} (see daemon/calibrate.py for the rule).",
        "# Include it from the daemon's config: include = [\"<this file>\"]",
    ]
    body = {
        "decision": {
            "thresholds": {
                result.load: {
                    c.name: {"center": c.threshold.center, "warning": c.threshold.warning, "alarm": c.threshold.alarm}
                    for c in result.indicators
                }
            }
        }
    }
    return "\n".join(header) + "\n\n" + tomlout.dumps(body)
