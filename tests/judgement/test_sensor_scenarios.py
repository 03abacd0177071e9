"""Sensor faults and standstill on simulated runs: SENSOR_FAULT or gating, never a suspension alarm.

A frozen or dead channel creates exactly the asymmetry the indicators look for (it enters
pitch and roll together), so each case below would look like a fault if it were judged.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.judgement.events import EventKind, SensorFaultDetails
from bogiemon.judgement.gating import Gate
from bogiemon.judgement.structure import learn_structure
from bogiemon.daemon.monitor import Monitor
from bogiemon.judgement.verdict import MonitorSettings, WindowJudge, WindowVerdict
from bogiemon.daemon.store import EventStore
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import IndicatorStream, WindowIndicators
from bogiemon.detection.channel_stats import channel_stats_reference
from bogiemon.drivers.base import Block
from bogiemon.simulator import Scenario, SensorModel, SpeedProfile, simulate
from tests.judgement.event_examples import details_as

FS_HZ = 500.0
DURATION_S = 180.0
SUSPENSION_KINDS = {EventKind.SUSPECTED, EventKind.CONFIRMED}


@pytest.fixture(scope="module")
def healthy_run() -> np.ndarray:
    return simulate(Scenario(duration_s=DURATION_S, seed=4, sensor=SensorModel(noise_mps2=0.01))).accel_mps2


def feed(accel: np.ndarray, tmp_path: Path) -> tuple[Monitor, list]:
    monitor = Monitor(BogiemonConfig().monitor_settings(), EventStore(tmp_path))
    events = []
    for i in range(0, accel.shape[0], 250):
        events += monitor.feed(Block(start_s=1.7e9 + i / FS_HZ, fs_hz=FS_HZ, accel_mps2=accel[i : i + 250]))
    return monitor, events


def flat(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[:, 0] = 9.81  # a dead sensor: gravity and nothing else
    return a


def stuck(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[int(20 * FS_HZ) :, 1] = a[int(20 * FS_HZ), 1]  # the converter freezes 20 s in
    return a


def clipping(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[:: int(0.5 * FS_HZ), 2] += 400.0  # impacts twice a second, beyond the 16 g range...
    a[:, 2] = np.clip(a[:, 2], -156.9, 156.9)  # ...which the converter clips
    return a


def noisy(a: np.ndarray) -> np.ndarray:
    return a + np.array([0.0, 0.0, 1.0]) * np.random.default_rng(5).normal(0.0, 8.0, size=a.shape)


@pytest.mark.parametrize(
    ("damage", "channel", "problem"),
    [(flat, "a1", "flat"), (stuck, "a2", "stuck"), (clipping, "a3", "clipping"), (noisy, "a3", "noisy")],
    ids=["flat", "stuck", "clipping", "noisy"],
)
def test_a_damaged_channel_is_a_sensor_fault_and_never_a_suspension_alarm(healthy_run, tmp_path, damage, channel, problem) -> None:
    monitor, events = feed(damage(healthy_run), tmp_path)
    kinds = {e.kind for e in events}
    assert not kinds & SUSPENSION_KINDS
    faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    assert faults and problem in details_as(faults[0], SensorFaultDetails).problems[channel]
    assert monitor.counters.judged == 0 or damage is stuck  # stuck: the first windows are still whole


def test_a_channel_that_froze_two_seconds_before_a_window_ends_is_stuck_in_that_window(healthy_run, tmp_path) -> None:
    """Frozen for the last 2 s of a 120 s window: 2 % of its samples repeat, far below the share
    rule, but the run of one value is 2 s long, so that window is already not judged."""
    accel = healthy_run.copy()
    accel[int(128 * FS_HZ) :, 1] = accel[int(128 * FS_HZ), 1]
    monitor, events = feed(accel, tmp_path)
    faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    assert faults and details_as(faults[0], SensorFaultDetails).problems == {"a2": ("stuck",)}
    assert details_as(faults[0], SensorFaultDetails).window_end_s == pytest.approx(1.7e9 + 130.0)
    assert monitor.counters.judged == 1  # the window 0-120 s only
    assert not {e.kind for e in events} & SUSPENSION_KINDS


def test_healthy_noiseless_quantised_sensors_at_walking_pace_are_not_stuck() -> None:
    """The run rule's margin: ideal sensors quantised to a 16 g / 16-bit step hold one value far
    shorter than stuck_run_s even at 10 km/h in tare on good track, the slowest, smoothest case."""
    lsb_mps2 = 2 * 156.9 / 2**16
    run = simulate(Scenario(load="tare", speed=SpeedProfile.constant(10.0), duration_s=130.0, seed=3,
                            sensor=SensorModel(quantum_mps2=lsb_mps2))).accel_mps2  # fmt: skip
    settings = BogiemonConfig().monitor_settings()
    stats = channel_stats_reference(run[-int(120 * FS_HZ) :], FS_HZ)
    assert max(stats.longest_run_s) < settings.health.stuck_run_s / 4


def test_the_damaged_runs_would_have_looked_like_faults_if_judged(healthy_run, tmp_path) -> None:
    """The point of the health check: the frozen channel's coupling exceeds the alarm level."""
    monitor, _ = feed(flat(healthy_run), tmp_path)
    decision = BogiemonConfig().monitor_settings().decision
    thresholds = decision.thresholds[LoadState.FULL]
    window = monitor.latest.window
    assert any(abs(getattr(window, name) - t.center) >= t.alarm for name, t in thresholds.items())


def test_a_standing_wagon_is_gated_without_events(tmp_path) -> None:
    standing = simulate(Scenario(duration_s=150.0, speed=SpeedProfile.constant(0.0), sensor=SensorModel(noise_mps2=0.01), seed=6))
    monitor, events = feed(standing.accel_mps2, tmp_path)
    assert events == []
    assert monitor.counters.windows > 0 and monitor.counters.gated == monitor.counters.windows


def test_the_healthy_run_itself_is_judged_and_raises_nothing(healthy_run, tmp_path) -> None:
    monitor, events = feed(healthy_run, tmp_path)
    assert not {e.kind for e in events} & {EventKind.CONFIRMED, EventKind.SENSOR_FAULT}
    assert monitor.counters.judged == monitor.counters.windows


# --------------------------------------------------------------------------------------------
# Stops and starts, noisy sensors, the structure learned from the wagon (issue 16)

STOP_AND_START = "0:60,60:60,90:0,150:0,180:60,300:60"  # braking to a stop at 90 s, off again at 150 s
LSB_MPS2 = 2 * 16 * 9.80665 / 65536


def judged_windows(accel: np.ndarray, settings: MonitorSettings | None = None) -> list[tuple[WindowIndicators, WindowVerdict]]:
    """Every window of a recording with what the daemon's WindowJudge said of it."""
    settings = settings or BogiemonConfig().monitor_settings()
    judge = WindowJudge(settings)
    core = IndicatorStream(settings.processing, settings.geometry, 0.0, settings.health.clip_level_mps2)
    return [(w, judge.judge(w)) for w in core.process(accel)]


def reported(judged: list[tuple[WindowIndicators, WindowVerdict]]) -> dict[str, set[str]]:
    """channel -> the problems any window named on it."""
    out: dict[str, set[str]] = {}
    for _, j in judged:
        for channel, problems in j.health.problems.items():
            out.setdefault(channel, set()).update(p.value for p in problems)
    return out


def add_noise(accel: np.ndarray, channel: int, seed: int = 5) -> np.ndarray:
    """White noise of 0.4 m/s^2 RMS at 500 Hz on one channel: a loose sensor far below the RMS check."""
    out = accel.copy()
    out[:, channel] += np.random.default_rng(seed).normal(0.0, 0.4, accel.shape[0])
    return out


@pytest.mark.slow
@pytest.mark.parametrize("load", ["full", "tare"])
def test_a_stop_and_a_start_are_gated_in_the_windows_that_hold_them_and_judged_elsewhere(load: str) -> None:
    scenario = Scenario(load=load, speed=SpeedProfile.parse(STOP_AND_START), duration_s=330.0, seed=8,
                        sensor=SensorModel(noise_mps2=0.01, quantum_mps2=LSB_MPS2))  # fmt: skip
    judged = judged_windows(simulate(scenario).accel_mps2)
    holding_the_standstill = [j for w, j in judged if w.start_s < 150.0 and w.end_s > 90.0]
    steady = [j for w, j in judged if w.start_s >= 180.0]  # wholly at 60 km/h after the start
    assert len(holding_the_standstill) == 15 and len(steady) == 4
    assert all(j.health.gate is Gate.NON_STATIONARY and j.health.sensors_ok for j in holding_the_standstill)
    assert all(j.judgement is not None for j in steady)
    assert not [e for _, j in judged for e in j.events]  # no sensor fault, no suspension event


@pytest.mark.slow
@pytest.mark.parametrize(
    ("track", "load", "speed_kmh", "channel"),
    [("erri-low", "full", 80.0, 0), ("erri-low", "tare", 60.0, 2), ("fra-6", "tare", 50.0, 2), ("fra-6", "full", 50.0, 0)],
    ids=["erri-low-full-a1", "erri-low-tare-a3", "fra-6-tare-a3", "fra-6-full-a1"],
)
def test_a_sensor_with_white_noise_far_below_the_rms_check_is_reported_noisy_by_name(track, load, speed_kmh, channel, tmp_path) -> None:
    run = simulate(Scenario(load=load, track=track, speed=SpeedProfile.constant(speed_kmh), duration_s=180.0, seed=4,
                            sensor=SensorModel(noise_mps2=0.01))).accel_mps2  # fmt: skip
    _, events = feed(add_noise(run, channel), tmp_path)
    faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    assert faults and details_as(faults[-1], SensorFaultDetails).reported == {f"a{channel + 1}": ("noisy",)}
    assert not {e.kind for e in events} & SUSPENSION_KINDS


@pytest.mark.slow
@pytest.mark.parametrize(
    ("track", "load", "speed"),
    [
        ("erri-low", "full", "0:80,180:80"), ("erri-high", "tare", "0:50,180:50"), ("fra-4", "full", "0:110,180:110"),
        ("fra-5", "tare", "0:70,90:100,180:60"), ("fra-4", "full", "0:15,180:15"), ("fra-4", "full", "0:20,90:30,180:25"),
    ],
    ids=["erri-low-80", "erri-high-50", "fra-4-110", "fra-5-drifting", "fra-4-15", "fra-4-20-30"],
)
def test_a_healthy_wagon_is_never_called_noisy(track: str, load: str, speed: str) -> None:
    scenario = Scenario(load=load, track=track, speed=SpeedProfile.parse(speed), duration_s=180.0, seed=9,
                        sensor=SensorModel(noise_mps2=0.02, quantum_mps2=LSB_MPS2, gain=(1.03, 0.97, 1.0)))  # fmt: skip
    judged = judged_windows(simulate(scenario).accel_mps2)
    assert reported(judged) == {}


@pytest.mark.slow
def test_at_walking_pace_the_short_waves_between_the_rail_pair_are_not_taken_for_noise() -> None:
    """Model B (not the model the bounds came from) at 15 km/h on rough track: judged, and the rail
    pair's coherence at 0.5-1 Hz is low in some windows because the waves are only a few sensor
    spacings long, which the pair's phase shows: the noise check stands aside there."""
    scenario = Scenario(model="b", load="full", track="fra-4", speed=SpeedProfile.constant(15.0), duration_s=300.0, seed=26,
                        sensor=SensorModel(noise_mps2=0.01, quantum_mps2=0.0048))  # fmt: skip
    judged = judged_windows(simulate(scenario).accel_mps2)
    assert sum(j.judgement is not None for _, j in judged) >= len(judged) - 1
    assert reported(judged) == {}


@pytest.fixture(scope="module")
def commissioned() -> tuple[MonitorSettings, MonitorSettings, np.ndarray]:
    """The default settings, the same with the structure learned from two healthy commissioning
    runs of the wagon, and a third healthy run of it on other track."""
    settings = BogiemonConfig().monitor_settings()
    sensor = SensorModel(noise_mps2=0.01, quantum_mps2=LSB_MPS2)
    windows = []
    for track, speed, seed in (("erri-low", 70.0, 21), ("fra-5", 95.0, 22)):
        accel = simulate(Scenario(track=track, speed=SpeedProfile.constant(speed), duration_s=240.0, seed=seed, sensor=sensor)).accel_mps2
        windows += [w for w, j in judged_windows(accel, settings) if j.judgement is not None]
    fit = learn_structure(windows, settings.geometry)
    learned = replace(settings, health=fit.applied_to(settings.health))
    later = simulate(Scenario(track="erri-high", speed=SpeedProfile.constant(85.0), duration_s=180.0, seed=23, sensor=sensor)).accel_mps2
    return settings, learned, later


@pytest.mark.slow
def test_the_structure_learned_from_healthy_windows_holds_on_the_wagon_s_later_running(commissioned) -> None:
    settings, learned, later = commissioned
    assert settings.health.layout_checks == ()
    assert set(learned.health.layout_checks) >= {"diagonal", "other", "quadrature"}
    assert reported(judged_windows(later, learned)) == {}


@pytest.mark.slow
def test_a_swapped_pair_is_found_with_the_learned_structure_and_not_without_one(commissioned) -> None:
    settings, learned, later = commissioned
    swapped = later[:, [1, 0, 2]]  # the cables of a1 and a2 exchanged
    assert reported(judged_windows(swapped, learned)) == {"a1": {"swapped"}, "a2": {"swapped"}}
    uncommissioned = reported(judged_windows(swapped, settings))
    assert not {p for problems in uncommissioned.values() for p in problems} & {"swapped", "inverted"}


@pytest.mark.parametrize("offsets_mps2", [(9.81, 0.1, 0.2), (9.81, 9.81, 9.81), (0.0, 0.0, 0.0), (9.81, -0.3, 1e-6)])
def test_a_standing_wagon_with_constant_channels_of_any_offsets_raises_no_sensor_fault(offsets_mps2: tuple[float, float, float]) -> None:
    # A new user's first try: three constant channels of a standing wagon, each with its own
    # offset. The high-pass leaves only rounding of each, whose ratios once named a1 noisy for as
    # long as the wagon stood (a fault that cannot clear while every window is gated).
    accel = np.tile(np.asarray(offsets_mps2, dtype=np.float64), (int(600 * 500), 1))
    judged = judged_windows(accel)
    assert len(judged) == 49
    assert all(j.health.gate is Gate.STANDSTILL and j.health.problems == {} for _, j in judged)
    assert not [e for _, j in judged for e in j.events]
