"""Measures the sensor health checks (issue 16) on simulated runs of both wagon models: the gate on
stops and starts, the noise checks, and the frame structure learned from the wagon.

    .venv/bin/python -m bogiemon.lab.robust.health_check [--models a,b] [--wagons 6] [--runs 2]

Every run is judged window by window by the daemon's own WindowJudge with the shipped default
config (uncommissioned: no structure check in force), as a gateway would judge it. Printed:
- the exponent a of the frame's RMS against speed (RMS ~ v^a), the physics of min_hop_rms_ratio;
- healthy runs of varied wagons (lab/robust/wagons.py's spreads; model B: its one wagon with the
  fleet's sensor errors) on ERRI low and high and FRA 4, 5 and 6 at 50-110 km/h: windows gated,
  sensor faults (any is false), suspension events;
- the same runs with white noise of NOISE_MPS2 at 500 Hz added to one channel, each channel in
  turn: the runs reporting NOISY on that channel (and on another), and suspension events;
- runs that stop and start again, and healthy running at walking pace on rough track;
- the structure: learn_structure on each wagon's commissioning runs, then its other healthy runs
  (false swapped/inverted with the learned structure) and its runs with two cables swapped or a
  sensor upside down (found with the learned structure, not without).

THE NOISE FLOOR ACROSS SENSOR PARTS (--noise-floor; issue 16, part 4): the wagons of the
robustness evaluation's fleets (--fleet training: where a constant may be fitted; evaluation: where
it is judged), read by each sensor part asked for (--sensor-variant, simulator/sensors.py
SENSOR_VARIANTS), commissioned as `bogiemon calibrate` does (daemon/calibrate.py calibrate_windows
on each load's commissioning runs, drawn as the README asks), then each of its healthy runs judged
by the daemon's WindowJudge as it is, with the hiss after the sensor on each channel in turn, and
re-simulated with the hiss inside one channel's sensor (its element, before its filters; the
channel turns from run to run), and per load a run with one or two stops and one standing. Printed per model, part,
load and where the noise enters: the runs with NOISY on the noisy channel, with a problem on
another channel, the share of their windows named, suspension events, and per run the margin up to
which the noise floor alone names it (judgement/noise_floor.py floor_excess); the healthy runs (and
those with stops) with a false sensor fault and the largest floor excess of any of their windows
(what a margin must stay above). --noise-floor-margin judges
with another margin; --drawn-commissioning commissions each wagon on runs drawn like any run's
(what a keeper happens to record) instead of on every track and both ends of the speeds.

    .venv/bin/python -m bogiemon.lab.robust.health_check --noise-floor --models a,b \
        --sensor-variant standard,two-pole,mems-odr10,wideband --fleet evaluation --wagons 3 --runs 2 \
        --commissioning 4 --drawn-commissioning

docs/sensor-health.md has what it measured, on which wagons the margin was fitted and which were
held out.
"""

from __future__ import annotations

import argparse
import pickle
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.daemon.config import BogiemonConfig, validate_config
from bogiemon.judgement.events import EventKind
from bogiemon.judgement.gating import Gate
from bogiemon.judgement.health import LONG_WAVE_PHASE_RAD, assess_window, rail_pair_coherence, same_rail_pair
from bogiemon.judgement.noise_floor import floor_excess
from bogiemon.judgement.structure import learn_structure
from bogiemon.judgement.verdict import MonitorSettings, WindowJudge
from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, WindowIndicators
from bogiemon.drivers.atomic import write_bytes_atomically
from bogiemon.lab.robust.fleet import (
    HEALTHY, HISS_RMS_MPS2, EvaluationPlan, RunSpec, damage_sensors, draw_conditions, hiss_inside, scenario_for, with_sensor_variant,
)  # fmt: skip
from bogiemon.lab.robust.judge import DaemonMethod
from bogiemon.lab.robust.wagons import Wagon, make_wagon
from bogiemon.simulator import Scenario, SensorModel, SpeedProfile, simulate
from bogiemon.simulator.sensors import SENSOR_VARIANTS

FS_HZ = 500.0
NOISE_MPS2 = 0.4  # the trial's noisy sensor: white noise of this RMS per sample at 500 Hz
SUSPENSION = {EventKind.SUSPECTED, EventKind.CONFIRMED}
STOP_AND_START = "0:60,60:60,90:0,150:0,180:60,400:60"
WAGON_SEED = 16_000  # this study's wagons: other seeds than the evaluation's


@dataclass
class RunOutcome:
    windows: int = 0
    judged: int = 0
    gates: Counter[str] = field(default_factory=Counter)
    problems: dict[str, set[str]] = field(default_factory=dict)  # channel -> problems reported in the run
    suspension: Counter[str] = field(default_factory=Counter)


def judge(windows: Sequence[WindowIndicators], settings: MonitorSettings) -> RunOutcome:
    """One run through the daemon's WindowJudge, from a fresh state."""
    judge_ = WindowJudge(settings)
    out = RunOutcome()
    for w in windows:
        judged = judge_.judge(w)
        out.windows += 1
        out.judged += judged.judgement is not None
        if judged.health.gate is not None:
            out.gates[judged.health.gate.value] += 1
        for channel, problems in judged.health.problems.items():
            out.problems.setdefault(channel, set()).update(p.value for p in problems)
        for e in judged.events:
            if e.kind in SUSPENSION:
                out.suspension[e.kind.value] += 1
    return out


def core_windows(accel: np.ndarray, settings: MonitorSettings) -> list[WindowIndicators]:
    return IndicatorStream(settings.processing, settings.geometry, 0.0, settings.health.clip_level_mps2).process(accel)


def run_spec(wagon: int, load: str, number: int, role: str = "healthy", duration_s: float = 600.0) -> RunSpec:
    return RunSpec(role=role, wagon=wagon, load=load, key=HEALTHY, severity=1.0, corner=None, number=number, duration_s=duration_s)


def run_scenario(model: str, wagon_index: int, spec: RunSpec, geometry: BogieGeometry) -> Scenario:
    """The run's scenario on model A's varied wagon, or on model B's wagon with the same sensors,
    track, speeds and direction."""
    wagon = make_wagon(f"health-{wagon_index}", WAGON_SEED + wagon_index)
    scenario = scenario_for(spec, wagon, FS_HZ, geometry)
    if model == "b":
        scenario = Scenario(
            model="b", load=spec.load, speed=scenario.speed, track=scenario.track, duration_s=spec.duration_s,
            seed=scenario.seed, fs_hz=FS_HZ, geometry=scenario.geometry, sensor=wagon.sensor,
        )  # fmt: skip
    return scenario


def with_noise(accel: np.ndarray, channel: int, seed: int) -> np.ndarray:
    out = accel.copy()
    out[:, channel] += np.random.default_rng([seed, channel, 16]).normal(0.0, NOISE_MPS2, accel.shape[0])
    return out


def speed_exponents(model: str) -> list[str]:
    """Per load and track: median channel RMS at steady speeds and the fitted exponent a."""
    speeds = (20.0, 40.0, 60.0, 80.0, 110.0)
    lines = []
    for load in ("full", "tare"):
        for track in ("erri-low", "fra-6", "fra-4"):
            rms = []
            for v in speeds:
                scenario = Scenario(model=model, load=load, track=track, speed=SpeedProfile.constant(v), duration_s=40.0, seed=2,
                                    sensor=SensorModel(noise_mps2=0.01))  # fmt: skip
                a = simulate(scenario).accel_mps2[int(10 * FS_HZ) :]
                rms.append(float(np.median(a.std(axis=0))))
            exponent = float(np.polyfit(np.log(speeds), np.log(rms), 1)[0])
            cells = " ".join(f"{v:g}:{r:.2f}" for v, r in zip(speeds, rms, strict=True))
            lines.append(f"  {model} {load:4} {track:8}  RMS m/s^2 at km/h {cells}   a = {exponent:.2f}")
    return lines


@dataclass
class Margins:
    """What the healthy judged windows showed of the quantities the bounds stand on."""

    windows: int = 0
    premise: int = 0  # windows whose rail pair is within LONG_WAVE_PHASE_RAD
    rail_multiple_min: float = 1.0  # the smallest multiple coherence of a rail-pair sensor there
    hop_ratio_min: float = 1.0  # the smallest quietest-over-loudest hop RMS (median channel)

    def add(self, windows: Sequence[WindowIndicators], settings: MonitorSettings) -> None:
        i, k, _ = same_rail_pair(settings.geometry)
        for w in windows:
            if not assess_window(w, settings.health, geometry=settings.geometry).judgeable or w.spectra is None:
                continue
            self.windows += 1
            hop = float(np.median(w.channels.hop_rms_min_mps2) / np.median(w.channels.hop_rms_max_mps2))
            self.hop_ratio_min = min(self.hop_ratio_min, hop)
            c = rail_pair_coherence(w.spectra.matrix, settings.geometry)
            if c is not None and c.phase_rad <= LONG_WAVE_PHASE_RAD:
                self.premise += 1
                self.rail_multiple_min = min(self.rail_multiple_min, c.multiple[i], c.multiple[k])

    def line(self) -> str:
        return (f"judged windows {self.windows}, of them with long waves (the premise) {self.premise}: smallest multiple "
                f"coherence of a rail-pair sensor {self.rail_multiple_min:.3f}; smallest hop RMS ratio {self.hop_ratio_min:.2f}")


@dataclass
class Tally:
    runs: int = 0
    named: int = 0  # NOISY on the noisy channel
    also_other: int = 0  # NOISY (or another problem) on another channel too
    suspension: int = 0  # a SUSPECTED or CONFIRMED in the run
    suspension_unreported: int = 0  # ... in a run whose noise was never reported


# --------------------------------------------------------------------------------------------
# The noise floor across sensor parts


NOISE_RUN_S = 600.0  # every run of the noise-floor trial, commissioning too (the evaluation's)


@dataclass(frozen=True)
class NoisyRun:
    load: str
    where: str  # HISS_WHERE: "after" the sensor or "inside" it
    channel: int
    windows: tuple[WindowIndicators, ...]


@dataclass(frozen=True)
class WagonNoiseRuns:
    """One wagon's windows for the noise-floor trial, on one model and sensor part."""

    commissioning: dict[str, list[tuple[WindowIndicators, ...]]]  # per load, its runs
    healthy: list[tuple[str, tuple[WindowIndicators, ...]]]  # (load, windows)
    noisy: list[NoisyRun]
    # Healthy runs that are not steady running, per load: (load, STILL_ROLES role, windows).
    still: list[tuple[str, str, tuple[WindowIndicators, ...]]] = field(default_factory=list)


# The evaluation plan's roles of healthy runs that stand: braking to a stand once or twice and
# starting again, and a wagon that stands the whole run (a sensor fault must never come of either).
STILL_ROLES = ("stops", "standing")


def trial_fleet(model: str, fleet: str, n_wagons: int) -> tuple[Wagon, ...]:
    """The first n_wagons of the robustness evaluation's training or evaluation fleet on `model`."""
    plan = EvaluationPlan(name="noise-floor", n_wagons=n_wagons, n_training_wagons=n_wagons, model=model)
    return plan.training_fleet() if fleet == "training" else plan.fleet()


def trial_specs(fleet: str, wagon: int, load: str, n_commissioning: int, n_runs: int, drawn: bool) -> tuple[list[RunSpec], list[RunSpec]]:
    """The wagon's commissioning and healthy test runs of one load, specs of the evaluation plan's
    roles (an evaluation wagon's calibration and healthy runs; a training wagon's first runs, as
    commissioning, and those after them). The commissioning runs follow the README's instruction
    (every track, both ends of the speeds), or with `drawn` are what the wagon happened to run, their
    conditions drawn like any run's (draw_conditions)."""
    if fleet == "training":
        runs = [RunSpec("train-healthy", wagon, load, HEALTHY, 1.0, None, r, NOISE_RUN_S, commissioning=r < n_commissioning and not drawn)
                for r in range(n_commissioning + n_runs)]  # fmt: skip
        return runs[:n_commissioning], runs[n_commissioning:]
    commissioning = [RunSpec("calibration", wagon, load, HEALTHY, 1.0, None, r, NOISE_RUN_S, commissioning=not drawn) for r in range(n_commissioning)]
    return commissioning, [RunSpec("healthy", wagon, load, HEALTHY, 1.0, None, r, NOISE_RUN_S) for r in range(n_runs)]


def noise_trial_wagon(
    model: str, variant: str, fleet: str, wagon_index: int, n_wagons: int, n_commissioning: int, n_runs: int, settings: MonitorSettings,
    drawn: bool,
) -> WagonNoiseRuns:
    """Simulate one wagon's runs of the trial (one batch, every core) and compute their windows."""
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when running

    wagon = trial_fleet(model, fleet, n_wagons)[wagon_index]
    geometry = settings.geometry
    jobs: list[tuple[str, str, RunSpec, int]] = []  # (kind, load, spec, channel of the hiss inside)
    for li, load in enumerate(("full", "tare")):
        commissioning, healthy = trial_specs(fleet, wagon_index, load, n_commissioning, n_runs, drawn)
        jobs += [("commissioning", load, spec, -1) for spec in commissioning]
        for n, spec in enumerate(healthy):
            jobs += [("healthy", load, spec, -1), ("inside", load, spec, (wagon_index + li + n) % 3)]
        jobs += [(role, load, RunSpec(role, wagon_index, load, HEALTHY, 1.0, None, 0, NOISE_RUN_S), -1) for role in STILL_ROLES]
    scenarios = []
    for kind, _, spec, channel in jobs:
        scenario = with_sensor_variant(scenario_for(spec, wagon, FS_HZ, geometry), variant)
        scenarios.append(hiss_inside(scenario, channel) if kind == "inside" else scenario)
    out = WagonNoiseRuns({"full": [], "tare": []}, [], [])
    for (kind, load, spec, channel), result in zip(jobs, simulate_batch(scenarios), strict=True):
        windows = tuple(core_windows(result.accel_mps2, settings))
        if kind == "commissioning":
            out.commissioning[load].append(windows)
        elif kind == "inside":
            out.noisy.append(NoisyRun(load, "inside", channel, windows))
        elif kind in STILL_ROLES:
            out.still.append((load, kind, windows))
        else:
            out.healthy.append((load, windows))
            for c in range(3):
                hissed = damage_sensors(result.accel_mps2, f"hiss a{c + 1}", FS_HZ, spec.seed)
                out.noisy.append(NoisyRun(load, "after", c, tuple(core_windows(hissed, settings))))
    return out


def trial_runs(
    model: str, variant: str, fleet: str, n_wagons: int, n_commissioning: int, n_runs: int, settings: MonitorSettings, data: Path | None,
    drawn: bool = False,
) -> list[WagonNoiseRuns]:
    """Every wagon's runs, from the data file where it holds them (written back with the new ones)."""
    cache: dict[tuple[Any, ...], WagonNoiseRuns] = {}
    if data is not None and data.exists():
        with data.open("rb") as f:
            cache = pickle.load(f)  # noqa: S301 - the user's own cache, named on the command line
    out, added = [], False
    for w in range(n_wagons):
        key = (model, variant, fleet, w, n_commissioning, n_runs, drawn, settings.processing)
        if key not in cache:
            cache[key], added = noise_trial_wagon(model, variant, fleet, w, n_wagons, n_commissioning, n_runs, settings, drawn), True
        out.append(cache[key])
    if data is not None and added:
        write_bytes_atomically(data, pickle.dumps(cache, protocol=pickle.HIGHEST_PROTOCOL))
    return out


def commissioned_settings(runs: WagonNoiseRuns, config: BogiemonConfig) -> MonitorSettings:
    """The wagon's settings after its commissioning, as `bogiemon calibrate --full ... --tare ...`
    makes them (lab/robust/judge.py DaemonMethod.commission: calibrate_windows per load)."""
    method = DaemonMethod("default", "the daemon's default config", config, calibrated=True)
    return method.commission(runs.commissioning).settings


@dataclass
class NoiseCell:
    runs: int = 0
    named: int = 0  # NOISY on the noisy channel in some window (a SENSOR_FAULT naming it)
    elsewhere: int = 0  # a problem on another channel (in a healthy run: on any channel)
    suspension: int = 0  # a SUSPECTED or CONFIRMED in the run
    windows: int = 0  # the runs' windows that were not gated
    windows_named: int = 0  # ... with NOISY on the noisy channel
    # Per run, the largest noise-floor excess (judgement/noise_floor.py floor_excess) of the noisy
    # channel (of any channel in a healthy run) over its moving windows: the margin up to which the
    # floor alone would name it.
    excess: list[float] = field(default_factory=list)


def judge_trial_run(windows: Sequence[WindowIndicators], settings: MonitorSettings, channel: int | None, cell: NoiseCell) -> dict[str, set[str]]:
    """One run of the trial through the daemon's WindowJudge, counted into its cell; its problems."""
    judge_ = WindowJudge(settings)
    name = f"a{channel + 1}" if channel is not None else None
    problems: dict[str, set[str]] = {}
    suspension, excess = False, 0.0
    for window in windows:
        verdict = judge_.judge(window)
        for ch, found in verdict.health.problems.items():
            problems.setdefault(ch, set()).update(p.value for p in found)
        suspension |= any(e.kind in SUSPENSION for e in verdict.events)
        if verdict.health.gate is None:
            cell.windows += 1
            cell.windows_named += name is not None and any(p.value == "noisy" for p in verdict.health.problems.get(name, ()))
        floor = floor_excess(window, settings.health) if verdict.health.gate is not Gate.STANDSTILL else None
        if floor is not None:
            excess = max(excess, float(floor[channel] if channel is not None else floor.max()))
    cell.runs += 1
    cell.named += name is not None and "noisy" in problems.get(name, set())
    cell.elsewhere += any(ch != name for ch in problems)
    cell.suspension += suspension
    cell.excess.append(excess)
    return problems


def noise_floor_trial(model: str, variant: str, wagons: Sequence[WagonNoiseRuns], config: BogiemonConfig) -> list[str]:
    """The trial's table for one model and part (module docstring)."""
    cells: dict[tuple[str, str], NoiseCell] = {}
    false: list[str] = []
    for w, runs in enumerate(wagons):
        settings = commissioned_settings(runs, config)
        for load, windows in runs.healthy:
            problems = judge_trial_run(windows, settings, None, cells.setdefault((load, "healthy"), NoiseCell()))
            if problems:
                false.append(f"wagon {w} {load}: {problems}")
        for load, role, windows in runs.still:
            problems = judge_trial_run(windows, settings, None, cells.setdefault((load, role), NoiseCell()))
            if problems:
                false.append(f"wagon {w} {load} {role}: {problems}")
        for run in runs.noisy:
            judge_trial_run(run.windows, settings, run.channel, cells.setdefault((run.load, run.where), NoiseCell()))
    lines = [f"model {model.upper()}, sensor {variant}: {len(wagons)} wagons"]
    for (load, where), c in sorted(cells.items()):
        excess = np.array(c.excess)
        if where == "healthy" or where in STILL_ROLES:
            lines.append(f"  {load:4} {where:11}: runs {c.runs:3}, a sensor fault (false) {c.elsewhere}, suspension {c.suspension}; "
                         f"largest floor excess {excess.max():.2f}")  # fmt: skip
            continue
        lines.append(
            f"  {load:4} hiss {where:6}: runs {c.runs:3}, NOISY on the noisy channel {c.named:3} ({100 * c.named / max(c.runs, 1):3.0f} %), "
            f"a problem elsewhere {c.elsewhere}, windows named {c.windows_named} of {c.windows}, suspension {c.suspension}; "
            f"floor excess per run: smallest {excess.min():.3g}, 10th percentile {np.quantile(excess, 0.1):.3g}"
        )
    lines += [f"    false: {f}" for f in false]
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="a,b", help="wagon models, comma-separated (default a,b)")
    parser.add_argument("--wagons", type=int, default=6, help="wagons per model (default 6)")
    parser.add_argument("--runs", type=int, default=2, help="healthy 10-min runs per wagon and load (default 2)")
    parser.add_argument("--commissioning", type=int, default=4, help="commissioning runs per wagon and load (default 4)")
    parser.add_argument("--noise-floor", action="store_true", help="only the noise floor across sensor parts (module docstring)")
    parser.add_argument("--sensor-variant", default="standard", help=f"sensor parts, comma-separated: {', '.join(SENSOR_VARIANTS)} (default standard)")
    parser.add_argument("--fleet", choices=("training", "evaluation"), default="evaluation", help="whose wagons (default evaluation)")
    parser.add_argument("--data", type=Path, help="a file keeping the noise-floor trial's windows, to judge them again without simulating")
    parser.add_argument("--noise-floor-margin", type=float, help="[health] noise_floor_margin to judge with (default: the shipped config's)")
    parser.add_argument("--drawn-commissioning", action="store_true", help="commission each wagon on runs drawn like any run's, as a keeper records them")
    args = parser.parse_args(argv)
    config = BogiemonConfig()
    if args.noise_floor_margin is not None:
        data = config.model_dump(mode="json")
        data["health"]["noise_floor_margin"] = args.noise_floor_margin
        config = validate_config(data, "--noise-floor-margin")
    settings = config.monitor_settings()
    geometry = settings.geometry
    models = [m.strip() for m in args.models.split(",") if m.strip()]
    if args.noise_floor:
        variants = [v.strip() for v in args.sensor_variant.split(",") if v.strip()]
        unknown = sorted(set(variants) - set(SENSOR_VARIANTS))
        if unknown:
            parser.error(f"unknown sensor variants {unknown}: use some of {', '.join(SENSOR_VARIANTS)}")
        print(f"the noise floor on the {args.fleet} fleet's first {args.wagons} wagons, {args.commissioning} commissioning "
              f"and {args.runs} test runs of {NOISE_RUN_S:g} s per load; hiss {HISS_RMS_MPS2:g} m/s^2; "
              f"noise_floor_margin {config.health.noise_floor_margin:g}" + ("; commissioning drawn" if args.drawn_commissioning else ""))  # fmt: skip
        for model in models:
            for variant in variants:
                wagons = trial_runs(model, variant, args.fleet, args.wagons, args.commissioning, args.runs, settings, args.data, args.drawn_commissioning)
                for line in noise_floor_trial(model, variant, wagons, config):
                    print(line)
        return 0

    print("RMS of the frame against speed (median channel, steady speed, 30 s):")
    for model in models:
        for line in speed_exponents(model):
            print(line)

    for model in models:
        print(f"\nMODEL {model.upper()}")
        healthy = Tally()
        gate_counts: Counter[str] = Counter()
        windows_total = 0
        false_faults: list[str] = []
        per_track: dict[str, Tally] = {}
        noisy = {c: Tally() for c in range(3)}
        structure_lines: list[str] = []
        margins = Margins()
        for wagon in range(args.wagons):
            for load in ("full", "tare"):
                # Commissioning: the wagon's own healthy runs, what learn_structure learns from.
                commissioning = []
                for n in range(args.commissioning):
                    spec = run_spec(wagon, load, n, role="calibration")
                    accel = simulate(run_scenario(model, wagon, spec, geometry)).accel_mps2
                    commissioning += [w for w in core_windows(accel, settings) if assess_window(w, settings.health, geometry=geometry).judgeable]
                fit = learn_structure(commissioning, geometry)
                learned = replace(settings, health=fit.applied_to(settings.health))
                structure_lines.append(
                    f"  wagon {wagon} {load:4}: {fit.windows} windows, in force {list(fit.checks)}, smallest "
                    + ", ".join(f"{c} {v:.3f}" for c, v in fit.smallest.items())
                )
                for n in range(args.runs):
                    spec = run_spec(wagon, load, 100 + n)
                    scenario = run_scenario(model, wagon, spec, geometry)
                    accel = simulate(scenario).accel_mps2
                    windows = core_windows(accel, settings)
                    margins.add(windows, settings)
                    out = judge(windows, settings)
                    windows_total += out.windows
                    gate_counts.update(out.gates)
                    healthy.runs += 1
                    healthy.suspension += bool(out.suspension)
                    if out.problems:
                        false_faults.append(f"{scenario.track} {load} {out.problems}")
                    with_learned = judge(windows, learned)
                    if with_learned.problems:
                        structure_lines.append(f"    healthy run {n} with the learned structure: {with_learned.problems} (false)")
                    cond = draw_conditions(spec)
                    for channel in range(3):
                        noisy_out = judge(core_windows(with_noise(accel, channel, spec.seed), settings), settings)
                        reported = "noisy" in noisy_out.problems.get(f"a{channel + 1}", set())
                        other = any(ch != f"a{channel + 1}" for ch in noisy_out.problems)
                        for tally in (noisy[channel], per_track.setdefault(cond.track, Tally())):
                            tally.runs += 1
                            tally.named += reported
                            tally.also_other += other
                            tally.suspension += bool(noisy_out.suspension)
                            tally.suspension_unreported += bool(noisy_out.suspension) and not noisy_out.problems
                    if n == 0:  # the wagon's cables swapped and a sensor upside down, with and without its structure
                        for damage in ("swapped a1-a2", "swapped a2-a3", "inverted a3"):
                            damaged = core_windows(damage_sensors(accel, damage, FS_HZ, spec.seed), settings)
                            structure_lines.append(
                                f"    {damage}: uncommissioned {sorted(judge(damaged, settings).problems.items())}, "
                                f"learned {sorted(judge(damaged, learned).problems.items())}"
                            )
        print(f"healthy 10-min runs: {healthy.runs}, windows {windows_total}, gated {dict(gate_counts)}")
        print(f"  runs with a sensor fault (false): {len(false_faults)} {false_faults}")
        print(f"  runs with a suspension event: {healthy.suspension}")
        print(f"  {margins.line()}")
        print(f"white noise of {NOISE_MPS2} m/s^2 on one channel, each in turn:")
        for channel, t in noisy.items():
            print(f"  a{channel + 1}: runs {t.runs}, NOISY on a{channel + 1} {t.named} ({100 * t.named / max(t.runs, 1):.0f} %), "
                  f"a problem on another channel {t.also_other}, suspension events {t.suspension} "
                  f"(of them with the noise unreported {t.suspension_unreported})")  # fmt: skip
        for track, t in sorted(per_track.items()):
            print(f"  {track:8}: runs {t.runs}, noisy channel named {t.named} ({100 * t.named / max(t.runs, 1):.0f} %), "
                  f"suspension events {t.suspension}")  # fmt: skip
        print("stops and starts (" + STOP_AND_START + "), healthy:")
        for load in ("full", "tare"):
            for track in ("erri-low", "fra-6", "fra-4"):
                speed = SpeedProfile.parse(STOP_AND_START)
                scenario = Scenario(model=model, load=load, track=track, speed=speed, duration_s=400.0, seed=5, fs_hz=FS_HZ,
                                    sensor=SensorModel(noise_mps2=0.01, quantum_mps2=2 * 16 * 9.80665 / 65536))  # fmt: skip
                windows = core_windows(simulate(scenario).accel_mps2, settings)
                out = judge(windows, settings)
                print(f"  {load:4} {track:8}: windows {out.windows}, judged {out.judged}, gated {dict(out.gates)}, "
                      f"sensor problems {out.problems}, suspension {dict(out.suspension)}")  # fmt: skip
        print("slow running, healthy (300 s at a steady speed):")
        slow = Margins()
        for load in ("full", "tare"):
            for track in ("fra-4", "erri-low"):
                for v in (10.0, 15.0, 20.0, 30.0):
                    scenario = Scenario(model=model, load=load, track=track, speed=SpeedProfile.constant(v), duration_s=300.0,
                                        seed=int(v), fs_hz=FS_HZ, sensor=SensorModel(noise_mps2=0.01, quantum_mps2=0.0048))  # fmt: skip
                    windows = core_windows(simulate(scenario).accel_mps2, settings)
                    slow.add(windows, settings)
                    out = judge(windows, settings)
                    print(f"  {load:4} {track:8} {v:g} km/h: windows {out.windows}, judged {out.judged}, gated {dict(out.gates)}, "
                          f"sensor problems {out.problems or '-'}")  # fmt: skip
        print(f"  {slow.line()}")
        if model == "a":  # the fault cases are model A's tables
            print("suspension faults (a broken coil 150 s into the run), healthy sensors:")
            for key in ("type_a.full.rear_outer", "type_a.full.front_outer", "type_a.tare.front_outer"):
                for corner in Corner:
                    spec = RunSpec(role="fault", wagon=0, load=key.split(".")[1], key=key, severity=0.0, corner=corner, number=0,
                                   duration_s=420.0, onset_s=150.0)  # fmt: skip
                    scenario = scenario_for(spec, make_wagon("health-0", WAGON_SEED), FS_HZ, geometry)
                    out = judge(core_windows(simulate(scenario).accel_mps2, settings), settings)
                    print(f"  {key} 0 at {corner.value}: windows {out.windows}, sensor problems {out.problems or '-'}, "
                          f"suspension {dict(out.suspension) or '-'}")  # fmt: skip
        print("the structure learned per wagon and load:")
        for line in structure_lines:
            print(line)
    return 0


if __name__ == "__main__":
    # Through the module's own name, so that the windows kept by --data pickle as its classes, not __main__'s.
    from bogiemon.lab.robust import health_check

    raise SystemExit(health_check.main())
