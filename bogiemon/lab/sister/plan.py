"""The sister study's fleets and runs: wagons of either model recorded on both bogies (issue 33).

    plan = SisterPlan.default("a")                     # or .quick(model) for a test
    data = simulate_sister(plan, settings, geometry, cache_dir="build/sister")
    data.select(role="train-healthy", load="full")     # PairRuns: each bogie's windows, aligned

THE FLEETS. Each model has a TRAINING fleet (what the study chooses on and the priors are fitted
on) and an EVALUATION fleet, held out: other seeds of lab/robust/wagons.py's draws (masses, coils,
dampers, side bearers, every corner's tolerance on both bogies, six sensors). Neither is the fleet
the shipped config/fused_model.toml was fitted on.

THE RUNS. Every run drives one track quality and a drifting speed as lab/robust/fleet.py draws
them (draw_conditions: 50-110 km/h, five track qualities, either direction), and records both
bogies. A run in the other direction runs the wagon the other way round: its bogie 2 then leads,
every corner of each frame is the config's mirrored (x -> -x, y -> -y), and the recording's
channels are given back in the wagon's own order, bogie 1's first, each bogie reading through its
own sensors. So a bogie's number is the wagon's, never the direction's, as on a gateway.
- train-healthy: training wagons, each load; their first `commissioning_runs` are what a
  commissioning of that wagon would hold (a random draw of what it ran, as a keeper commissions).
  Loaded, a training run carries its load unevenly between the wagon's ends, bogie 1's share of
  the carbody drawn per run uniformly within 0.5 +/- TRAINING_SHARE_SPREAD: a wagon's loading
  changes from trip to trip, and what the sister learns (a commissioning's spread, the prior's)
  must allow it; empty, the carbody is its own, even. Many wagons with few runs each: the spread
  between wagons (the prior's, the guard's) is what the fleet's size limits.
- train-fault: every fault case of the paper's Tables 1 to 3, on either bogie, at two corners a
  cell (turning through the four), the fault present from the start: what a broken spring looks
  like to each feature, and to a commissioning that already holds it.
- calibration, healthy: evaluation wagons, commissioning and later healthy running.
- fault: evaluation wagons, a healthy lead-in then the fault (the broken springs at every corner of
  either bogie; the other cases at one diagonal, leading-left and trailing-right).
- uneven-*: the same for evaluation wagons whose carbody is loaded 60/40 between its ends
  (`leading_share`), commissioning, healthy running and broken springs.
- sensor: evaluation wagons running healthy with one sensor of one bogie damaged
  (lab/robust/fleet.py damage_sensors, on that bogie's three channels): the other bogie must
  never be blamed.

Simulating is the cost: runs of one length share a kernel call (simulate_batch's scenario axis),
and each run's windows are kept in a file of its own under the cache folder, so a rerun (or a
larger plan that shares runs) simulates only what is missing.
"""

from __future__ import annotations

import hashlib
import pickle
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.lab.robust.fleet import MIRROR, Conditions, RunSpec, damage_sensors, draw_conditions, fault_cells
from bogiemon.lab.robust.report import FULL_SPRINGS, TARE_OUTER
from bogiemon.lab.robust.wagons import Wagon, make_wagon
from bogiemon.lab.study.plan import HEALTHY, table4_cases
from bogiemon.simulator.scenario import Scenario
from bogiemon.simulator.suspension import CORNER_ORDER, Fault

Progress = Callable[[float], None]

BROKEN = tuple((key, 0.0) for key in (*FULL_SPRINGS, *TARE_OUTER))
DIAGONAL = (Corner.LEADING_LEFT, Corner.TRAILING_RIGHT)
UNEVEN_SHARE = 0.6  # of the carbody's weight on bogie 1: a wagon loaded 60/40 between its ends
TRAINING_SHARE_SPREAD = 0.1
# A sensor of one bogie (lab/robust/fleet.py SENSOR_DAMAGE), run healthy on each load.
SENSOR_DAMAGES = ("dead a1", "noisy a3", "hiss a2", "swapped a1-a2")
CACHE_VERSION = 1  # of a run's cached windows; a new one simulates again


@dataclass(frozen=True)
class SisterRun:
    """One run of a wagon recorded on both bogies. `corner`: the fault's corner in the config's
    naming, on bogie `bogie` (1 or 2; 0 healthy)."""

    role: str
    wagon: int
    load: str
    key: str = HEALTHY
    severity: float = 1.0
    corner: Corner | None = None
    bogie: int = 0
    number: int = 0
    duration_s: float = 600.0
    onset_s: float = 0.0
    leading_share: float = 0.5  # of the carbody's weight on bogie 1
    damage: str | None = None  # role "sensor": what is wrong with a sensor of bogie `bogie` (SENSOR_DAMAGES)

    @property
    def name(self) -> str:
        where = f"{self.bogie}:{self.corner.value}" if self.corner else "-"
        share = f"|share {self.leading_share:g}" if self.leading_share != 0.5 else ""
        damage = f"|{self.bogie}:{self.damage}" if self.damage else ""
        return f"sister|{self.role}|{self.wagon}|{self.load}|{self.key}|{self.severity:g}|{where}|{self.number}|{self.duration_s:g}|{self.onset_s:g}{share}{damage}"

    @property
    def training(self) -> bool:
        return self.role.startswith("train")

    @property
    def commissioning(self) -> bool:
        return self.role in ("calibration", "uneven-calibration")

    def spec(self) -> RunSpec:
        """The robustness evaluation's run of the same seed, whose conditions it drives."""
        return RunSpec(
            role=f"sister-{self.role}", wagon=self.wagon, load=self.load, key=self.key, severity=self.severity, corner=self.corner,
            number=100 * self.bogie + self.number, duration_s=self.duration_s, onset_s=self.onset_s,
            commissioning=self.commissioning, designed=False,
        )  # fmt: skip

    def conditions(self) -> Conditions:
        return draw_conditions(self.spec())


@dataclass(frozen=True)
class SisterPlan:
    """What the study simulates for one wagon model. Durations in seconds."""

    name: str
    model: str
    n_training_wagons: int = 20
    training_healthy_runs: int = 3  # per training wagon and load, 10 min each
    commissioning_runs: int = 2  # of those, what a commissioning of the training wagon holds
    training_fault_corners: int = 2  # per fault cell and bogie (turning through the corners)
    training_fault_s: float = 600.0
    training_fault_cases: tuple[tuple[str, float], ...] | None = None  # None: every cell of Table 4
    n_wagons: int = 6
    calibration_runs: int = 8  # per evaluation wagon and load
    healthy_runs: int = 8
    run_s: float = 600.0
    lead_in_s: float = 150.0
    fault_s: float = 600.0  # running with the fault after the lead-in: "within 10 minutes"
    broken_cases: tuple[tuple[str, float], ...] = BROKEN  # at every corner of either bogie
    fault_cases: tuple[tuple[str, float], ...] | None = None  # the evaluation's other cells, at DIAGONAL; None: every cell
    uneven_wagons: int = 2  # evaluation wagons also run loaded UNEVEN_SHARE / rest
    sensor_damages: tuple[str, ...] = SENSOR_DAMAGES
    fleet_seed: int = 2026
    loads: tuple[str, ...] = ("full", "tare")

    @classmethod
    def default(cls, model: str) -> SisterPlan:
        return cls(name="default", model=model)

    @classmethod
    def quick(cls, model: str) -> SisterPlan:
        """A test's: few wagons, short runs, the broken rear outer coils only."""
        return cls(
            name="quick", model=model, n_training_wagons=3, training_healthy_runs=2, commissioning_runs=1,
            training_fault_corners=1, training_fault_s=300.0, n_wagons=1, calibration_runs=2, healthy_runs=1, run_s=300.0,
            fault_s=300.0, broken_cases=(("type_a.full.rear_outer", 0.0),), fault_cases=(), training_fault_cases=(("type_a.full.rear_outer", 0.0),), uneven_wagons=1, loads=("full",),
            sensor_damages=("dead a1",),
        )  # fmt: skip

    def training_share(self, wagon: int, load: str, run: str) -> float:
        """Bogie 1's share of the carbody in a training run (module docstring): drawn per run."""
        if load != "full":
            return 0.5
        rng = np.random.default_rng(zlib.crc32(f"{self.fleet_seed}|sister-training-share|{wagon}|{run}".encode()))
        return round(float(rng.uniform(0.5 - TRAINING_SHARE_SPREAD, 0.5 + TRAINING_SHARE_SPREAD)), 4)

    def training_fleet(self) -> tuple[Wagon, ...]:
        return tuple(
            make_wagon(f"sister training wagon {i + 1}", zlib.crc32(f"{self.fleet_seed}|sister-training|{i}".encode()), self.model)
            for i in range(self.n_training_wagons)
        )

    def fleet(self) -> tuple[Wagon, ...]:
        return tuple(
            make_wagon(f"sister wagon {i + 1}", zlib.crc32(f"{self.fleet_seed}|sister-evaluation|{i}".encode()), self.model) for i in range(self.n_wagons)
        )

    def _cells(self, cases: Sequence[tuple[str, float]] | None) -> list[tuple[str, float]]:
        return [(k, s) for k, sev in fault_cells().items() for s in sev if k in table4_cases() and (cases is None or (k, s) in cases)]

    def runs(self) -> tuple[SisterRun, ...]:
        out: list[SisterRun] = []
        for w in range(self.n_training_wagons):
            for load in self.loads:
                out += [
                    SisterRun("train-healthy", w, load, number=r, duration_s=self.run_s, leading_share=self.training_share(w, load, f"healthy {r}"))
                    for r in range(self.training_healthy_runs)
                ]
        turn = 0
        for key, severity in self._cells(self.training_fault_cases):
            load = key.split(".")[1]
            if load not in self.loads:
                continue
            for bogie in (1, 2):
                for _ in range(self.training_fault_corners):
                    corner, w = CORNER_ORDER[turn % 4], turn % self.n_training_wagons
                    share = self.training_share(w, load, f"{key} {severity} {bogie} {corner.value}")
                    out.append(SisterRun("train-fault", w, load, key, severity, corner, bogie, 0, self.training_fault_s, leading_share=share))
                    turn += 1
        for w in range(self.n_wagons):
            for load in self.loads:
                out += [SisterRun("calibration", w, load, number=r, duration_s=self.run_s) for r in range(self.calibration_runs)]
                out += [SisterRun("healthy", w, load, number=r, duration_s=self.run_s) for r in range(self.healthy_runs)]
        out += self._fault_runs("fault", range(self.n_wagons), self.broken_cases, tuple(Corner), 0.5)
        others = [c for c in self._cells(self.fault_cases) if c not in self.broken_cases]
        out += self._fault_runs("fault", range(self.n_wagons), others, DIAGONAL, 0.5)
        uneven = range(min(self.uneven_wagons, self.n_wagons))
        for w in uneven:
            for load in self.loads:
                out += [SisterRun("uneven-calibration", w, load, number=r, duration_s=self.run_s, leading_share=UNEVEN_SHARE) for r in range(self.calibration_runs)]
                out += [SisterRun("uneven-healthy", w, load, number=r, duration_s=self.run_s, leading_share=UNEVEN_SHARE) for r in range(self.healthy_runs)]
        out += self._fault_runs("uneven-fault", uneven, self.broken_cases, DIAGONAL, UNEVEN_SHARE)
        turn = 0
        for damage in self.sensor_damages:
            for load in self.loads:
                for bogie in (1, 2):
                    out.append(SisterRun("sensor", turn % self.n_wagons, load, bogie=bogie, duration_s=self.run_s, damage=damage))
                    turn += 1
        return tuple(out)

    def _fault_runs(self, role: str, wagons: Sequence[int], cells: Sequence[tuple[str, float]], corners: Sequence[Corner], share: float) -> list[SisterRun]:
        out = []
        turn = 0
        for key, severity in cells:
            load = key.split(".")[1]
            if load not in self.loads or not wagons:
                continue
            for bogie in (1, 2):
                for corner in corners:
                    out.append(
                        SisterRun(
                            role, wagons[turn % len(wagons)], load, key, severity, corner, bogie, 0,
                            self.lead_in_s + self.fault_s, self.lead_in_s, share,
                        )  # fmt: skip
                    )
                    turn += 1
        return out


def scenario_for(run: SisterRun, wagon: Wagon, fs_hz: float, geometry: BogieGeometry) -> tuple[Scenario, bool]:
    """The two-bogie scenario of a run, and whether its recording's halves come back swapped (the
    wagon's bogie 2 leading: module docstring)."""
    cond = run.conditions()
    reversed_ = cond.reversed

    def physical(corner: Corner) -> Corner:
        return MIRROR[corner] if reversed_ else corner

    kz_n_per_m, fs_n = wagon.healthy_corner(run.load)
    # The carbody's share on each physical bogie; a corner's damper grips in proportion to its
    # static load (the Lenoir link), so its tolerance's Fs follows the share.
    frame_kg, carbody_kg = _masses(wagon, run.load)
    faults, standing = [], []
    for own in (1, 2):
        share = run.leading_share if own == 1 else 1.0 - run.leading_share
        grip = (carbody_kg * share / 4.0 + frame_kg / 4.0) / (carbody_kg / 8.0 + frame_kg / 4.0)
        kernel_bogie = "leading" if (own == 1) != reversed_ else "trailing"
        for corner in CORNER_ORDER:
            if own == run.bogie and corner == run.corner:
                parts = run.key.split(".")
                position = parts[2] if len(parts) == 3 else None
                faults.append(Fault(kind=parts[0], corner=physical(corner), bogie=kernel_bogie, position=position, severity=run.severity))
            else:
                k = 4 * (own - 1) + CORNER_ORDER.index(corner)
                standing.append(
                    Fault(
                        kind="custom", corner=physical(corner), bogie=kernel_bogie,
                        kz_n_per_m=kz_n_per_m * wagon.corner_kz_scale[k], fs_n=fs_n * wagon.corner_fs_scale[k] * grip,
                    )  # fmt: skip
                )
    sensor, sensor_2, parameters = wagon.bogie_sensors(2 if reversed_ else 1)
    if run.leading_share != 0.5:
        from bogiemon.simulator.params import centre_offset_m  # the carbody's offset for the share

        parameters = _with_offset(parameters, run.leading_share, reversed_, centre_offset_m)
    sensors = BogieGeometry(geometry.wheelbase_m, geometry.sensor_spacing_m, tuple(physical(c) for c in geometry.corners))  # type: ignore[arg-type]
    scenario = Scenario(
        load=run.load, speed=cond.speed, track=cond.track, duration_s=run.duration_s, seed=zlib.crc32(run.name.encode()),
        faults=tuple(faults), standing_faults=tuple(standing), fault_onset_s=run.onset_s if run.key != HEALTHY else 0.0,
        fs_hz=fs_hz, geometry=sensors, sensor=sensor, sensor_bogie_2=sensor_2, parameters=parameters, model=wagon.model, bogies=2,
    )  # fmt: skip
    return scenario, reversed_


def _masses(wagon: Wagon, load: str) -> tuple[float, float]:
    """(a frame's sprung mass, the carbody's) in kg, of the wagon's own parameter set."""
    v = wagon.parameters["vehicle"]
    carbody = v["carbody"][f"mass_{load}_kg"] if wagon.model == "b" else wagon.parameters["fault_cases"]["wagon"][f"carbody_mass_{load}_kg"]
    return float(v["bogie_frame"]["mass_kg"]), float(carbody)


def _with_offset(parameters: dict[str, Any], share: float, reversed_: bool, offset: Callable[[float, float], float]) -> dict[str, Any]:
    params = {**parameters, "vehicle": {**parameters["vehicle"], "carbody": dict(parameters["vehicle"]["carbody"])}}
    body = params["vehicle"]["carbody"]
    # Towards the kernel's leading bogie: the wagon's bogie 1, or bogie 2 when it runs the other way.
    body["centre_of_mass_offset_m"] = offset(1.0 - share if reversed_ else share, float(body["bogie_centre_distance_m"]))
    return params


# --------------------------------------------------------------------------------------------
# Simulating, and the windows kept


@dataclass(frozen=True)
class PairRun:
    """One run's windows on each bogie (the wagon's bogie 1, then 2), aligned in time."""

    run: SisterRun
    conditions: Conditions
    windows: tuple[tuple[WindowIndicators, ...], tuple[WindowIndicators, ...]]


@dataclass(frozen=True)
class SisterData:
    plan: SisterPlan
    settings: ProcessingSettings
    geometry: BogieGeometry
    runs: tuple[PairRun, ...]
    simulated_s: float  # running time of every run of the plan
    new_s: float  # of which simulated now (not found in the cache)

    def select(self, **where: Any) -> list[PairRun]:
        """Runs whose SisterRun matches every given attribute (a value, or a set of values)."""
        return [r for r in self.runs if all(getattr(r.run, k) in (v if isinstance(v, set | frozenset) else {v}) for k, v in where.items())]


def _cache_file(folder: Path, plan: SisterPlan, run: SisterRun, settings: ProcessingSettings, geometry: BogieGeometry) -> Path:
    key = repr((CACHE_VERSION, plan.model, plan.fleet_seed, run.name, settings, geometry.wheelbase_m, geometry.sensor_spacing_m, geometry.corners))
    return folder / plan.model / f"{hashlib.sha256(key.encode()).hexdigest()[:24]}.pkl"


def _read(path: Path) -> tuple[tuple[WindowIndicators, ...], tuple[WindowIndicators, ...]] | None:
    try:
        with path.open("rb") as f:
            found = pickle.load(f)  # noqa: S301 - the study's own cache under build/
    except (OSError, pickle.UnpicklingError, EOFError, AttributeError, ImportError):
        return None
    return found if isinstance(found, tuple) and len(found) == 2 else None


def simulate_sister(
    plan: SisterPlan,
    settings: ProcessingSettings,
    geometry: BogieGeometry,
    cache_dir: str | Path | None = None,
    roles: Iterable[str] | None = None,
    progress: Progress | None = None,
    batch_size: int = 16,
) -> SisterData:
    """Every run of the plan (or of the given roles): from the cache where it holds the run at
    these settings, else simulated (one kernel call per batch) and written there."""
    from bogiemon.drivers.atomic import write_bytes_atomically  # one atomic write of a file someone reads after us
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when simulating

    wanted = set(roles) if roles is not None else None
    runs = [r for r in plan.runs() if wanted is None or r.role in wanted]
    fleets = {True: plan.training_fleet(), False: plan.fleet()}
    folder = Path(cache_dir) if cache_dir is not None else None
    found: dict[int, tuple[tuple[WindowIndicators, ...], tuple[WindowIndicators, ...]]] = {}
    if folder is not None:
        for i, r in enumerate(runs):
            windows = _read(_cache_file(folder, plan, r, settings, geometry))
            if windows is not None:
                found[i] = windows
    todo = sorted((i for i in range(len(runs)) if i not in found), key=lambda i: (runs[i].duration_s, i))
    total_s = sum(runs[i].duration_s for i in todo) or 1.0
    done_s = 0.0
    for first in range(0, len(todo), batch_size):
        batch = todo[first : first + batch_size]
        built = [scenario_for(runs[i], fleets[runs[i].training][runs[i].wagon], settings.fs_hz, geometry) for i in batch]
        for i, (_, swapped), result in zip(batch, built, simulate_batch([s for s, _ in built]), strict=True):
            accel = result.accel_mps2
            halves = [accel[:, 3:], accel[:, :3]] if swapped else [accel[:, :3], accel[:, 3:]]
            damage = runs[i].damage
            if damage is not None:
                k = runs[i].bogie - 1
                halves[k] = damage_sensors(halves[k], damage, settings.fs_hz, zlib.crc32(runs[i].name.encode()))
            one, two = (tuple(IndicatorStream(settings, geometry, clip_level_mps2=155.0).process(h)) for h in halves)
            found[i] = (one, two)
            if folder is not None:
                path = _cache_file(folder, plan, runs[i], settings, geometry)
                path.parent.mkdir(parents=True, exist_ok=True)
                write_bytes_atomically(path, pickle.dumps(found[i], protocol=pickle.HIGHEST_PROTOCOL))
            done_s += runs[i].duration_s
        if progress is not None:
            progress(done_s / total_s)
    pairs = tuple(PairRun(r, r.conditions(), found[i]) for i, r in enumerate(runs))
    return SisterData(plan, settings, geometry, pairs, sum(r.duration_s for r in runs), sum(runs[i].duration_s for i in todo))


def aligned(pair: PairRun) -> list[tuple[WindowIndicators, WindowIndicators]]:
    """The run's window pairs: bogie 1's and bogie 2's windows that cover the same time."""
    by_start = {round(w.start_s, 6): w for w in pair.windows[1]}
    return [(w, by_start[round(w.start_s, 6)]) for w in pair.windows[0] if round(w.start_s, 6) in by_start]
