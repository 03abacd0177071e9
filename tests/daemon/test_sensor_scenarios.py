"""Sensor faults and standstill on simulated runs: SENSOR_FAULT or gating, never a suspension alarm.

A frozen or dead channel creates exactly the asymmetry the indicators look for (it enters
pitch and roll together), so each case below would look like a fault if it were judged.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.events import EventKind
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.store import EventStore
from bogiemon.detection.channel_stats import channel_stats_reference
from bogiemon.drivers.base import Block
from bogiemon.simulator import Scenario, SensorModel, SpeedProfile, simulate

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
    assert faults and problem in faults[0].details["problems"][channel]
    assert monitor.counters.judged == 0 or damage is stuck  # stuck: the first windows are still whole


def test_a_channel_that_froze_two_seconds_before_a_window_ends_is_stuck_in_that_window(healthy_run, tmp_path) -> None:
    """Frozen for the last 2 s of a 120 s window: 2 % of its samples repeat, far below the share
    rule, but the run of one value is 2 s long, so that window is already not judged."""
    accel = healthy_run.copy()
    accel[int(128 * FS_HZ) :, 1] = accel[int(128 * FS_HZ), 1]
    monitor, events = feed(accel, tmp_path)
    faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    assert faults and faults[0].details["problems"] == {"a2": ["stuck"]}
    assert faults[0].details["window_end_s"] == pytest.approx(1.7e9 + 130.0)
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
    thresholds = decision.thresholds["full"]
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
