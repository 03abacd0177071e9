"""The monitor end to end in one thread: blocks in, committed events out."""

from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import parse_config
from bogiemon.judgement.events import EventKind, SensorFaultDetails
from bogiemon.daemon.monitor import Monitor
from bogiemon.daemon.sinks import EventSink, MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.judgement.vocabulary import LoadState
from tests.daemon.synthetic import as_blocks, bogie_accel, short_windows_config
from tests.judgement.event_examples import details_as

CONFIG = parse_config(short_windows_config(clear_after_windows=2), "test")


def make_monitor(tmp_path: Path, sinks=()) -> Monitor:
    return Monitor(CONFIG.monitor_settings(), EventStore(tmp_path), list(sinks))


def feed_all(monitor: Monitor, blocks) -> list:
    events = []
    for b in blocks:
        events += monitor.feed(b)
    return events


def kinds(events) -> list[EventKind]:
    return [e.kind for e in events]


def test_independent_modes_raise_nothing(tmp_path: Path) -> None:
    monitor = make_monitor(tmp_path)
    assert feed_all(monitor, as_blocks(bogie_accel(60, seed=1))) == []
    assert monitor.counters.windows == 28 and monitor.counters.judged == 28


def test_coupled_pitch_and_roll_are_suspected_then_confirmed(tmp_path: Path) -> None:
    events = feed_all(make_monitor(tmp_path), as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0)))
    assert kinds(events) == [EventKind.SUSPECTED, EventKind.CONFIRMED]
    assert events[1].indicators["i4_norm"] > 0.3


def test_a_fault_that_goes_away_is_cleared(tmp_path: Path) -> None:
    accel = np.concatenate([bogie_accel(20, 3, pitch_roll_coupling=1.0), bogie_accel(40, 4)])
    assert kinds(feed_all(make_monitor(tmp_path), as_blocks(accel))) == [EventKind.SUSPECTED, EventKind.CONFIRMED, EventKind.CLEARED]


def test_a_flat_channel_is_a_sensor_fault_never_a_suspension_alarm(tmp_path: Path) -> None:
    accel = bogie_accel(40, seed=5)
    accel[:, 0] = 9.81  # a1 frozen: pitch and roll now share -a3 and -a2 terms and correlate
    events = feed_all(make_monitor(tmp_path), as_blocks(accel))
    assert kinds(events) == [EventKind.SENSOR_FAULT]
    assert details_as(events[0], SensorFaultDetails).problems == {"a1": ("flat", "stuck")}


def test_standstill_is_gated_without_events(tmp_path: Path) -> None:
    monitor = make_monitor(tmp_path)
    assert feed_all(monitor, as_blocks(bogie_accel(30, seed=6, pitch_roll_coupling=1.0, scale=0.01))) == []
    assert monitor.counters.gated == monitor.counters.windows > 0 and monitor.counters.judged == 0


def test_a_gap_restarts_the_windows(tmp_path: Path) -> None:
    monitor = make_monitor(tmp_path)
    feed_all(monitor, as_blocks(bogie_accel(20, seed=7), gap_at={1000}))  # 10 s + 10 s
    assert monitor.counters.segments == 2 and monitor.counters.windows == 2 * 3


def test_events_are_committed_before_any_sink_sees_them(tmp_path: Path) -> None:
    class CheckingSink(EventSink):
        def __init__(self) -> None:
            self.seen_in_store: list[bool] = []

        def publish(self, event) -> None:
            self.seen_in_store.append(event in EventStore(tmp_path, readonly=True).events())

    sink = CheckingSink()
    feed_all(make_monitor(tmp_path, [sink]), as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0)))
    assert sink.seen_in_store == [True, True]


def test_alarm_state_survives_a_restart(tmp_path: Path) -> None:
    first = make_monitor(tmp_path)
    feed_all(first, as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0)))
    assert first.mode == "confirmed"
    assert isinstance(first.store, EventStore)
    first.store.close()
    sink = MemorySink()
    second = make_monitor(tmp_path, [sink])
    assert second.mode == "confirmed"
    feed_all(second, as_blocks(bogie_accel(30, seed=8, pitch_roll_coupling=1.0)))
    assert kinds(sink.events) == []  # still the same alarm: no second CONFIRMED


@pytest.mark.parametrize("load", [LoadState.FULL, LoadState.TARE])
def test_the_load_state_picks_its_thresholds(tmp_path: Path, load: LoadState) -> None:
    monitor = Monitor(CONFIG.monitor_settings(load=load), EventStore(tmp_path))
    feed_all(monitor, as_blocks(bogie_accel(10, seed=9)))
    assert set(monitor.latest.judgement.values) == set(CONFIG.decision.thresholds[load])
    assert CONFIG.decision.thresholds[LoadState.FULL] != CONFIG.decision.thresholds[LoadState.TARE]
