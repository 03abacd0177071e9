"""Measures whether a sensor fault hides a suspension fault: on simulated fleets of both wagon
models, how often a fault's first event is a SENSOR_FAULT told alone, with the judgement's sensor
rule as it is (noise the floor alone sees holds back no judgement of the couplings:
judgement/health.py) and as it was (every sensor problem holds the judgement back).

    .venv/bin/python -m bogiemon.lab.robust.first_event [--models a,b] [--wagons 4] [--runs 2]

Per model: wagons drawn as the robustness evaluation draws them (lab/robust/wagons.py), each
commissioned with `calibrate`'s own code on its healthy runs of each load (the noise floor learned
there too); then per fault case, severity and corner a trend sequence (a healthy lead-in, the fault
appears, the wagon runs on with it over --runs runs of other tracks and speeds), judged window by
window by the daemon's WindowJudge. Beside them, damaged-sensor runs (a loud and a faint noise, a
dead and a swapped sensor) and healthy runs: a sensor rule that let noise through to the
suspension would show there as suspension events. Printed per model and rule: the sequences whose
first event after the onset is a SENSOR_FAULT alone (one that names no corner), any SENSOR_FAULT
first, the sequences confirmed and the median running time to the CONFIRMED; the sensor runs with
suspension events and those whose damage was named; the healthy runs with any event.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import PAPER_LAYOUT, Corner
from bogiemon.judgement.events import Event, EventKind, SensorFaultDetails
from bogiemon.lab.robust.fleet import EXPECTED_PROBLEM, EvaluationData, EvaluationPlan, fault_cells, simulate_plan
from bogiemon.lab.robust.judge import Commissioned, DaemonMethod, JudgedRun, sequences

RULES = ("as it is", "as it was")  # judge_through_floor_noise True, False
SENSOR_DAMAGES = ("noisy a3", "hiss a2", "dead a1", "swapped a1-a3")
# The fault cells measured: every case at its most severe setting either way (a broken or a doubled
# spring, the damper's friction halved or raised half again): what a sensor rule could hide.
CELLS = tuple((key, sev) for key, sevs in fault_cells().items() for sev in (sevs[0], sevs[-1]))


def plan_for(model: str, wagons: int, runs: int, seed: int = 2026) -> EvaluationPlan:
    return EvaluationPlan(
        name=f"first-event-{model}", model=model, n_wagons=wagons, n_training_wagons=0, calibration_runs=6, calibration_s=400.0,
        healthy_runs=2, healthy_s=400.0, fault_runs=0, trend_runs=runs, trend_run_s=450.0, trend_cases=CELLS, fault_cases=(),
        training_fault_cases=(), sensor_runs=1, sensor_s=400.0, sensor_damages=SENSOR_DAMAGES, fleet_seed=seed,
        designed_commissioning=False,
    )  # fmt: skip


@dataclass
class Tally:
    sequences: int = 0
    sensor_alone_first: int = 0  # first event after the onset: a SENSOR_FAULT naming no corner
    sensor_first: int = 0  # a SENSOR_FAULT of any kind first
    sensor_any: int = 0  # a SENSOR_FAULT anywhere after the onset
    confirmed: int = 0
    confirm_s: list[float] = dataclasses.field(default_factory=list)
    sensor_runs: int = 0
    sensor_named: int = 0  # the damage's expected problem on its channel
    sensor_suspension: int = 0  # a SUSPECTED or CONFIRMED on a damaged-sensor run
    healthy_runs: int = 0
    healthy_events: int = 0  # a healthy run with any event


def _commission(method: DaemonMethod, data: EvaluationData, wagon: int, through: bool) -> Commissioned:
    calibration: dict[str, list[tuple]] = {}
    for r in data.select(role="calibration", wagon=wagon):
        calibration.setdefault(r.run.load, []).append(r.windows)
    done = method.commission(calibration)
    health = dataclasses.replace(done.settings.health, judge_through_floor_noise=through)
    return dataclasses.replace(done, settings=dataclasses.replace(done.settings, health=health))


def after_onset(onset_s: float, durations_s: Sequence[float], judged: Sequence[JudgedRun]) -> list[tuple[float, Event]]:
    """(running time since the onset, the event) of each event after it, of a sequence of runs
    judged one after the other (each event's time is from its own run's start)."""
    offset_s, out = 0.0, []
    for duration_s, j in zip(durations_s, judged, strict=True):
        out += [(offset_s + e.time_s - onset_s, e) for e in j.events if offset_s + e.time_s > onset_s]
        offset_s += duration_s
    return out


def tally_trend(t: Tally, events: Sequence[tuple[float, Event]]) -> None:
    """Count one fault's sequence: which event came first after the onset, and when the CONFIRMED."""
    t.sequences += 1
    first = events[0][1] if events else None
    t.sensor_first += first is not None and first.kind is EventKind.SENSOR_FAULT
    t.sensor_alone_first += isinstance(first, Event) and isinstance(first.details, SensorFaultDetails) and first.details.suspension is None
    t.sensor_any += any(e.kind is EventKind.SENSOR_FAULT for _, e in events)
    confirmed = next((s for s, e in events if e.kind is EventKind.CONFIRMED), None)
    if confirmed is not None:
        t.confirmed += 1
        t.confirm_s.append(confirmed)


def measure(data: EvaluationData, through: bool) -> Tally:
    method = DaemonMethod("daemon", "the shipped config, commissioned per wagon", BogiemonConfig(), calibrated=True)
    t = Tally()
    for w in range(len(data.fleet)):
        commissioned = _commission(method, data, w, through)
        for group in sequences(data, w):
            role = group[0].run.role
            judged = commissioned.judge([r.windows for r in group], group[0].run.load)
            if role == "trend":
                tally_trend(t, after_onset(group[0].run.onset_s, [r.run.duration_s for r in group], judged))
            elif role == "sensor":
                problem, channels = EXPECTED_PROBLEM[group[0].run.damage or ""]
                kinds = [e for j in judged for e in j.events]
                t.sensor_runs += 1
                named = {ch for e in kinds if isinstance(e.details, SensorFaultDetails) for ch, ps in e.details.problems.items() if problem in ps}
                t.sensor_named += set(channels) <= named
                t.sensor_suspension += any(e.kind in (EventKind.SUSPECTED, EventKind.CONFIRMED) for e in kinds)
            elif role == "healthy":
                t.healthy_runs += len(group)
                t.healthy_events += sum(bool(j.events) for j in judged)
    return t


def report(model: str, rule: str, t: Tally) -> str:
    median = f"{statistics.median(t.confirm_s) / 60:.1f} min" if t.confirm_s else "-"
    return (
        f"| {model} | {rule} | {t.sensor_alone_first} of {t.sequences} | {t.sensor_first} | {t.sensor_any} | {t.confirmed} of {t.sequences} "
        f"| {median} | {t.sensor_named} of {t.sensor_runs} | {t.sensor_suspension} | {t.healthy_events} of {t.healthy_runs} |"
    )


HEADER = (
    "| model | sensor rule | first event a SENSOR_FAULT alone | a SENSOR_FAULT first | any SENSOR_FAULT | confirmed "
    "| median time to CONFIRMED | damaged sensors named | damaged-sensor runs with a suspension event | healthy runs with an event |\n"
    "|---|---|---|---|---|---|---|---|---|---|"
)


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--models", default="a,b")
    p.add_argument("--wagons", type=int, default=4)
    p.add_argument("--runs", type=int, default=2, help="runs of each trend sequence (450 s each)")
    args = p.parse_args(argv)
    config = BogiemonConfig()
    settings, geometry = config.processing_settings(), config.bogie_geometry()
    assert tuple(geometry.corners) == PAPER_LAYOUT and Corner.LEADING_LEFT in geometry.corners
    lines = [HEADER]
    for model in args.models.split(","):
        started = time.process_time()
        data = simulate_plan(plan_for(model, args.wagons, args.runs), settings, geometry)
        for rule, through in zip(RULES, (True, False), strict=True):
            lines.append(report(model, rule, measure(data, through)))
            print(lines[-1], flush=True)
        print(f"model {model}: {data.simulated_s / 3600:.1f} h simulated, {time.process_time() - started:.0f} CPU s", file=sys.stderr, flush=True)
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
