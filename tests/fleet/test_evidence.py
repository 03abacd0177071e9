"""Fleet-relative evidence: a wagon against its sisters of the same type and load."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa

from bogiemon.daemon.config import load_config
from bogiemon.judgement.vocabulary import Mode
from bogiemon.fleet.evidence import MIN_SPREAD, STANDS_OUT, fleet_relative, robust_distance
from bogiemon.fleet.judge import SERIES_SCHEMA
from bogiemon.fleet.judged import MeanEvidence, WagonJudged
from bogiemon.fleet.layout import Fleet, Wagon


def test_robust_distance_is_the_rms_of_robust_z_scores() -> None:
    others = np.array([[0.0, 1.0], [0.1, 1.2], [0.2, 0.8], [0.3, 1.0]])
    x = np.array([1.0, 1.0])
    median = np.median(others, axis=0)
    spread = np.maximum(1.4826 * np.median(np.abs(others - median), axis=0), MIN_SPREAD)
    expected = np.sqrt(np.mean(((x - median) / spread) ** 2))
    assert robust_distance(x, others) == expected


def _judged(wagon_id: str, vector: np.ndarray) -> WagonJudged:
    ev: dict[str, MeanEvidence] = {"full": {"first_day": list(vector), "last_day": list(vector), "first_day_windows": 100, "last_day_windows": 100}}
    return WagonJudged(
        wagon_id=wagon_id,
        events=(),
        series=pa.Table.from_pylist([], schema=SERIES_SCHEMA),
        mode=Mode.NORMAL,
        sensor_reported={},
        not_judged=False,
        unjudged_running_s=0.0,
        windows=100,
        judged=100,
        gated=0,
        sensor_fault_windows=0,
        trend=0.1,
        trend_alarm=10.0,
        days=("2026-11-02",),
        evidence=ev,
        issues=(),
    )


def _wagon(tmp_path: Path, wagon_id: str, wagon_type: str = "Sgns") -> Wagon:
    return Wagon(wagon_id, wagon_type, tmp_path / wagon_id, tmp_path / "c.toml", None, load_config(None), ())


def test_a_wagon_whose_couplings_differ_from_its_sisters_stands_out_and_they_do_not(tmp_path: Path) -> None:
    rng = np.random.default_rng(4)
    vectors = {f"W{i}": rng.normal(0.0, 0.05, 14) for i in range(6)}
    vectors["W5"] = vectors["W5"] + 0.5  # far out of the sisters' scatter
    fleet = Fleet(tmp_path, "f", tuple(_wagon(tmp_path, w) for w in vectors))
    relative = fleet_relative(fleet, [_judged(w, v) for w, v in vectors.items()])
    assert relative["W5"]["stands_out"] and relative["W5"]["recent_distance"] > STANDS_OUT
    assert "5 sisters" in relative["W5"]["why"]
    assert not any(relative[w]["stands_out"] for w in vectors if w != "W5")


def test_wagons_of_another_type_are_no_sisters(tmp_path: Path) -> None:
    rng = np.random.default_rng(5)
    vectors = {f"W{i}": rng.normal(0.0, 0.05, 14) for i in range(4)}
    wagons = [_wagon(tmp_path, w, "Sgns" if w != "W3" else "Habbiins") for w in vectors]
    relative = fleet_relative(Fleet(tmp_path, "f", tuple(wagons)), [_judged(w, v) for w, v in vectors.items()])
    assert relative["W3"]["sisters"] == 0 and relative["W3"]["recent_distance"] is None
    assert relative["W0"]["sisters"] == 2 and relative["W0"]["recent_distance"] is None  # fewer than MIN_SISTERS
