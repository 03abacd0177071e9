"""The soak's checks: RSS flat, no exception escaped, every expected event exactly once with the
config hash in force, the counters adding up; and SoakRun, the record of a run they read.
"""

from __future__ import annotations

import json
import math
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from soak_feed import Feed, Lifetime  # noqa: E402
from soak_schedule import FS_HZ, HOUR_S, T0_S, Phase, Schedule  # noqa: E402

from bogiemon.judgement.events import ClearedDetails, Event, EventKind, SensorFaultDetails  # noqa: E402
from bogiemon.judgement.vocabulary import Mode  # noqa: E402

WARMUP_H = 2.0
RSS_SLOPE_BOUND_MB_PER_H = 1.0


@dataclass
class SoakRun:
    """One soak run as the harness saw it: what the checks and the report read."""

    schedule: Schedule
    calibration: str
    lifetimes: list[Lifetime]
    feed: Feed
    observer_windows: int
    wall_s: float
    events: list[Event]
    log_records: list[dict[str, Any]]
    final_state: dict[str, Any]
    escaped: list[str]  # exceptions that ended a thread
    trend_below_warning: list[tuple[float, bool]]  # Observer's, data time from the first sample


@dataclass
class Checks:
    passed: list[str] = field(default_factory=list)
    failed: list[str] = field(default_factory=list)

    def expect(self, ok: bool, what: str) -> None:
        (self.passed if ok else self.failed).append(what)


def data_s(event: Event) -> float:
    return event.time_s - T0_S


def problems(e: Event) -> dict[str, list[str]]:
    """The problems a SENSOR_FAULT found (none for another event)."""
    return {ch: list(names) for ch, names in e.details.problems.items()} if isinstance(e.details, SensorFaultDetails) else {}


def check_events(run: SoakRun, window_s: float, hop_s: float, clear_after: int, sensor_clear_after: int, checks: Checks) -> None:
    events = run.events
    confirmed = [e for e in events if e.kind is EventKind.CONFIRMED]
    cleared_alarms = [e for e in events if isinstance(e.details, ClearedDetails) and e.details.cleared is Mode.CONFIRMED]
    faults = [p for p in run.schedule.phases if p.kind == "fault"]
    # A CONFIRMED needs confirm_k windows at alarm; a CLEARED clear_after windows below warning,
    # the first window wholly after the fault ending window_s after it, and with the fused
    # decision its trend below its own warning level too (it decays over the trend's time
    # constant after the repair).
    confirm_by_s = window_s + 6 * hop_s
    for p in faults:
        mine = [e for e in confirmed if p.start_s <= data_s(e) <= p.start_s + confirm_by_s]
        checks.expect(len(mine) == 1, f"{p.label()}: one CONFIRMED within {confirm_by_s:g} s of the onset (got {len(mine)})")
        clear_by_s = 2 * window_s + (clear_after + 3) * hop_s
        trend_ok = next((t for t, ok in run.trend_below_warning if t >= p.end_s + window_s and ok), None)
        if run.trend_below_warning and trend_ok is not None:
            clear_by_s = max(clear_by_s, trend_ok - p.end_s + (clear_after + 3) * hop_s)
        cleared = [e for e in cleared_alarms if p.end_s <= data_s(e) <= p.end_s + clear_by_s]
        checks.expect(len(cleared) == 1, f"{p.label()}: one CLEARED of it within {clear_by_s:g} s of the repair (got {len(cleared)})")
    checks.expect(len(confirmed) == len(faults), f"CONFIRMED only in fault phases: {len(confirmed)} for {len(faults)} faults")
    checks.expect(len(cleared_alarms) == len(faults), f"alarms CLEARED once each: {len(cleared_alarms)} for {len(faults)} faults")
    sensor_faults = [e for e in events if e.kind is EventKind.SENSOR_FAULT]
    sensor_cleared = [e for e in events if e.kind is EventKind.SENSOR_CLEARED]
    sensor_phases = [p for p in run.schedule.phases if p.is_sensor_phase]

    def owner(e: Event) -> Phase | None:
        """The latest sensor phase begun by the event's window end, if the event is in its reach."""
        begun = [p for p in sensor_phases if p.start_s <= data_s(e)]
        return begun[-1] if begun and data_s(e) <= begun[-1].end_s + settle_s(begun[-1]) else None

    def settle_s(p: Phase) -> float:
        # Dropouts are judged over the last hour: they clear an hour after the last one.
        return (HOUR_S if p.kind == "dropouts" else 0.0) + window_s + (sensor_clear_after + 2) * hop_s

    for p in sensor_phases:
        mine = [e for e in sensor_faults if owner(e) is p]
        sets = [json.dumps(problems(e), sort_keys=True) for e in mine]
        # The daemon raises a SENSOR_FAULT only when a problem not yet reported appears: every
        # event of the phase must name a (channel, problem) pair that no earlier one did.
        seen: set[tuple[str, str]] = set()
        stale = 0
        for e in mine:
            pairs = {(ch, what) for ch, whats in problems(e).items() for what in whats}
            stale += not (pairs - seen)
            seen |= pairs
        checks.expect(bool(mine) and stale == 0 and all(data_s(e) <= p.end_s + window_s for e in mine),
                      f"{p.label()}: SENSOR_FAULT raised within it, once per new problem ({len(mine)}: {', '.join(sets)})")  # fmt: skip
        clear = [e for e in sensor_cleared if owner(e) is p]
        checks.expect(len(clear) == 1 and data_s(clear[0]) >= p.end_s if clear else False,
                      f"{p.label()}: one SENSOR_CLEARED after it, within {settle_s(p):g} s (got {len(clear)})")  # fmt: skip
    strays = [e for e in sensor_faults + sensor_cleared if owner(e) is None]
    checks.expect(not strays, f"sensor events only in sensor phases ({len(strays)} outside: {[round(data_s(e)) for e in strays][:5]})")
    ids = [e.event_id for e in events]
    checks.expect(len(set(ids)) == len(ids), "no event stored twice")
    times = [e.time_s for e in events]
    checks.expect(times == sorted(times), "events stored in time order")
    def hash_in_force(t_s: float) -> str:
        return [h for since_s, h in run.feed.config_hashes if since_s <= t_s + 0.5 / FS_HZ][-1]

    # A window never spans a reload (the windows restart there): its events carry the hash in
    # force at its start.
    wrong = [e for e in events if e.config_hash != hash_in_force(data_s(e) - window_s)]
    checks.expect(not wrong, f"every event carries the config hash in force for its window ({len(wrong)} do not)")
    mode = run.final_state.get("decision", {}).get("mode")
    reported = run.final_state.get("health", {}).get("reported")
    checks.expect(mode == "normal" and reported == {}, f"the day ends normal with healthy sensors (mode {mode}, sensors {reported})")


def stopped_records(run: SoakRun) -> list[dict[str, Any]]:
    return [r for r in run.log_records if r.get("event") == "stopped"]


def check_counters(run: SoakRun, hop_n: int, hops_per_window: int, checks: Checks) -> dict[str, int]:
    stops = stopped_records(run)
    checks.expect(len(stops) == len(run.lifetimes), f"every service logged its counters when it stopped ({len(stops)} of {len(run.lifetimes)})")
    totals: Counter[str] = Counter()
    for i, (life, stop) in enumerate(zip(run.lifetimes, stops, strict=False)):
        c, src, ring = stop["counters"], stop["source"], stop["ring"]
        totals.update({k: v for k, v in c.items() if isinstance(v, int)})
        expected_windows = sum(max(0, n // hop_n - hops_per_window + 1) for n in life.segment_lengths)
        expected_segments = 1 + life.gap_blocks + life.reloads
        both = c["judged"] + c["gated"] + c["sensor_fault_windows"]
        problems = []
        if c["windows"] != expected_windows:
            problems.append(f"windows {c['windows']} != {expected_windows} the segments allow")
        if both != c["windows"]:
            problems.append(f"judged {c['judged']} + gated {c['gated']} + sensor-fault {c['sensor_fault_windows']} != windows {c['windows']}")
        if (c["samples"], c["blocks"]) != (life.samples, life.blocks):
            problems.append(f"samples/blocks {c['samples']}/{c['blocks']} != fed {life.samples}/{life.blocks}")
        if c["segments"] != expected_segments:
            problems.append(f"segments {c['segments']} != 1 + {life.gap_blocks} gaps + {life.reloads} reloads")
        if (src["frames"], src["gaps"]) != (life.samples, life.gap_blocks):
            problems.append(f"source frames/gaps {src['frames']}/{src['gaps']} != {life.samples}/{life.gap_blocks}")
        if not (ring["blocks_in"] == ring["blocks_out"] == life.blocks and ring["samples_dropped"] == ring["overflows"] == 0):
            problems.append(f"ring {ring} != {life.blocks} blocks in and out, none dropped")
        checks.expect(not problems, f"service {i + 1}: counters add up" + (": " + "; ".join(problems) if problems else ""))
    checks.expect(totals["windows"] == run.observer_windows, f"window reports {run.observer_windows} = windows counted {totals['windows']}")
    checks.expect(totals["events"] == len(run.events), f"events counted {totals['events']} = events stored {len(run.events)}")
    checks.expect(sum(life.samples for life in run.lifetimes) == run.feed.fed_samples, "every sample fed reached a service")
    return dict(totals)


def check_health(run: SoakRun, checks: Checks) -> tuple[float, float]:
    statuses = [life.exit_status for life in run.lifetimes]
    checks.expect(all(s == 0 for s in statuses), f"every service exited 0 ({statuses})")
    checks.expect(not run.escaped, f"no exception ended a thread ({run.escaped[:3]})")
    errors = [r for r in run.log_records if r.get("level") == "error"]
    rejected = [r for r in errors if r.get("event", "").startswith("reload rejected")]
    bad = sum(life.bad_reloads for life in run.lifetimes)
    checks.expect(len(rejected) == bad and len(errors) == len(rejected),
                  f"no error in the log but the {bad} rejected reload(s): {[r.get('event') for r in errors if r not in rejected][:3]}")  # fmt: skip
    restarts = len(run.lifetimes) - 1
    planned = sum(1 for a in run.schedule.actions if a.kind == "restart")
    checks.expect(restarts == planned and run.feed.exhausted, f"the whole timeline was fed, {restarts} of {planned} restarts")
    slope = rss_slope_mb_per_h(run.feed.rss_samples)
    checks.expect(abs(slope) < RSS_SLOPE_BOUND_MB_PER_H,
                  f"RSS flat after {WARMUP_H:g} h: slope {slope:+.3f} MB per simulated hour (bound {RSS_SLOPE_BOUND_MB_PER_H:g})")  # fmt: skip
    return slope, max(mb for _, mb, _ in run.feed.rss_samples)


def rss_slope_mb_per_h(samples: list[tuple[float, float, int]]) -> float:
    """Least-squares RSS slope after the warm-up, one intercept per epoch.

    A restart in this process starts new threads, which glibc may give new malloc arenas: RSS
    steps once (bounded: the arenas are reused) where a real restart would start a new process;
    a reload rebuilds the core. Those steps are not growth, so each epoch has its own level.
    """
    warm = [(h, mb, e) for h, mb, e in samples if h >= WARMUP_H]
    epochs = sorted({e for _, _, e in warm})
    if len(warm) < len(epochs) + 2:
        return math.nan
    design = np.zeros((len(warm), 1 + len(epochs)))
    for row, (h, _, e) in enumerate(warm):
        design[row, 0], design[row, 1 + epochs.index(e)] = h, 1.0
    coef, *_ = np.linalg.lstsq(design, np.array([mb for _, mb, _ in warm]), rcond=None)
    return float(coef[0])


def rss_steps_mb(samples: list[tuple[float, float, int]]) -> list[float]:
    """RSS change across each restart or reload: the first sample of an epoch minus the last before it."""
    return [round(b[1] - a[1], 2) for a, b in zip(samples, samples[1:], strict=False) if b[2] != a[2]]
