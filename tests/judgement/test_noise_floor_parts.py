"""The noise floor on simulated wagons read by other sensor parts than ours (simulator/sensors.py
SENSOR_VARIANTS): commissioned on two healthy runs, a channel with 0.4 m/s^2 of white noise is named
on a later run on other track, the healthy later run and the standing wagon raise no sensor fault."""

from __future__ import annotations

from dataclasses import replace

from typing import Any

import numpy as np
import pytest

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.judgement.gating import Gate
from bogiemon.judgement.health import SensorProblem
from bogiemon.judgement.noise_floor import learn_noise_floor
from bogiemon.judgement.verdict import MonitorSettings, WindowJudge, WindowVerdict
from bogiemon.detection import IndicatorStream
from bogiemon.simulator import Scenario, SensorModel, SpeedProfile, simulate

FS_HZ = 500.0
RUN_S = 180.0  # seven of the daemon's 120 s windows each: enough for the floor, short enough for the suite
HISS_MPS2 = 0.4  # white noise per sample at 500 Hz, after the part (a poor cable screen)
# Parts with another anti-alias filter and bandwidth than the model's converter: an analog part's
# two-pole stage at fs/4, a MEMS part's digital filter at ODR/10 (50 Hz).
PARTS = ("two-pole", "mems-odr10")


def verdicts(accel_mps2: np.ndarray, settings: MonitorSettings) -> list[WindowVerdict]:
    judge = WindowJudge(settings)
    core = IndicatorStream(settings.processing, settings.geometry, 0.0, settings.health.clip_level_mps2)
    return [judge.judge(w) for w in core.process(accel_mps2)]


def reported(judged: list[WindowVerdict]) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {}
    for verdict in judged:
        for channel, problems in verdict.health.problems.items():
            out.setdefault(channel, set()).update(p.value for p in problems)
    return out


def run(part: str, track: str, speed_kmh: float, seed: int) -> np.ndarray:
    sensor = SensorModel(noise_mps2=0.01, quantum_mps2=0.0048, variant=part)
    return simulate(Scenario(track=track, speed=SpeedProfile.constant(speed_kmh), duration_s=RUN_S, seed=seed, sensor=sensor)).accel_mps2


@pytest.fixture(scope="module", params=PARTS)
def commissioned(request: pytest.FixtureRequest) -> tuple[str, MonitorSettings, np.ndarray]:
    """The part, the default settings with the floors learned, as calibrate learns them, from the
    judgeable windows of two healthy runs at full load on two tracks and speeds, and a later healthy
    run of the wagon on other track."""
    part = request.param
    settings = BogiemonConfig().monitor_settings()
    windows = []
    for track, speed_kmh, seed in (("erri-low", 70.0, 31), ("fra-5", 95.0, 32)):
        core = IndicatorStream(settings.processing, settings.geometry, 0.0, settings.health.clip_level_mps2)
        judge = WindowJudge(settings)
        windows += [w for w in core.process(run(part, track, speed_kmh, seed)) if judge.judge(w).health.judgeable]
    fit = learn_noise_floor(windows)
    assert fit is not None
    floors: dict[str, Any] = {k: tuple(v) for k, v in fit.health_fields().items()}
    learned = replace(settings, health=replace(settings.health, **floors))
    return part, learned, run(part, "erri-high", 85.0, 33)


@pytest.mark.slow
def test_a_channel_with_white_noise_is_named_noisy_on_a_part_with_another_filter(commissioned) -> None:
    _, settings, later = commissioned
    noisy = later.copy()
    noisy[:, 1] += np.random.default_rng(5).normal(0.0, HISS_MPS2, later.shape[0])
    judged = verdicts(noisy, settings)
    assert reported(judged) == {"a2": {"noisy"}}
    assert all(v.health.problems == {"a2": (SensorProblem.NOISY,)} for v in judged if v.health.gate is None)


@pytest.mark.slow
def test_the_healthy_wagon_on_other_track_raises_no_sensor_fault_on_a_part_with_another_filter(commissioned) -> None:
    _, settings, later = commissioned
    assert reported(verdicts(later, settings)) == {}


@pytest.mark.slow
def test_a_standing_wagon_read_by_another_part_raises_no_sensor_fault_after_commissioning(commissioned) -> None:
    part, settings, _ = commissioned
    standing = simulate(Scenario(duration_s=RUN_S, speed=SpeedProfile.constant(0.0), seed=34,
                                 sensor=SensorModel(noise_mps2=0.01, quantum_mps2=0.0048, variant=part))).accel_mps2  # fmt: skip
    judged = verdicts(standing, settings)
    assert judged and all(v.health.gate is Gate.STANDSTILL and v.health.problems == {} and not v.events for v in judged)
