"""The robustness evaluation's fleet and runs (issue 8): a varied fleet of simulated wagons, the
plan of their commissioning, healthy, fault and sensor runs, and every run's windows.

    plan = EvaluationPlan.default()                    # or EvaluationPlan.quick()
    data = simulate_plan(plan, settings, geometry)     # every run's windows, by the detection core
    judged = judge_runs(data, method)                  # lab/robust/judge.py: the daemon's own code
    score = score_method(data, ...)                    # lab/robust/score.py
    write_report(data, [score], "docs/robust", ...)    # lab/robust/report.py

THE FLEET: lab/robust/wagons.py (each wagon's draws on either wagon model).

THE RUNS. Every run drives on one track quality drawn from ERRI low and high level and FRA
classes 4, 5 and 6, at a speed that drifts within 50..110 km/h (a random walk through a point every
30 s, linear between them), in either direction of travel. The simulator's sensors sit on the
wagon's leading bogie; a run in the other direction is emulated by mirroring the three sensors and
the corners (x -> -x, y -> -y: the config still names the corners for the reference direction), so
the monitored bogie leads the wagon in both directions (on a real wagon it would trail, coupled to
the other bogie through the carbody). Per wagon and load:
- commissioning: CALIBRATION runs of the healthy wagon, what the keeper records to calibrate, as
  the README asks (every track quality, both directions, from the low and the high end of the
  speed range: draw_conditions); the training wagons' first runs likewise;
- healthy test runs: the same wagon later, other tracks and speeds, for the false alarms;
- fault runs: a healthy lead-in that fills the windows, then the fault appears under the running
  wagon (the simulator's fault onset) and the run goes on; a run counts as detected when the
  fault is CONFIRMED within DETECTION_HORIZON_S of running with it;
- stops (off in the default plan): healthy runs that brake to a stop once or twice, stand 60 to
  120 s and start again (draw_conditions); standing (off too): the wagon stands the whole run.
Every fault case of the paper's Tables 1 to 3 at every severity, on every corner of the monitored
bogie (the one without a sensor too), and the inner coils in tare (which do not touch the frame:
invisible by construction, run to show it). Fault runs are spread over the fleet's wagons.
A TRAINING fleet of other wagons (other seeds) gives the data the shipped models are fitted on
(the load classifier, the fused spread and levels, the population baseline of an uncalibrated wagon); nothing
of the evaluation fleet is used to fit them.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.simulator.model_b import parameters as model_b_parameters
from bogiemon.simulator.scenario import Scenario, SpeedProfile
from bogiemon.lab.study.plan import HEALTHY, table4_cases
from bogiemon.lab.robust.wagons import Wagon, make_wagon
from bogiemon.simulator.suspension import CORNER_ORDER, Fault

Progress = Callable[[float], None]

TRACKS: tuple[str, ...] = ("erri-low", "erri-high", "fra-4", "fra-5", "fra-6")
SPEED_MIN_KMH, SPEED_MAX_KMH = 50.0, 110.0
SPEED_POINT_EVERY_S = 30.0
SPEED_STEP_SD_KMH = 8.0
DETECTION_HORIZON_S = 120.0  # "2 minutes of running" with the fault
MIRROR: dict[Corner, Corner] = {
    Corner.LEADING_LEFT: Corner.TRAILING_RIGHT,
    Corner.TRAILING_RIGHT: Corner.LEADING_LEFT,
    Corner.LEADING_RIGHT: Corner.TRAILING_LEFT,
    Corner.TRAILING_LEFT: Corner.LEADING_RIGHT,
}
# Every cell of the paper's tables, plus the tare inner coils (not in Table 4: invisible in tare).
TARE_INNER: dict[str, tuple[float, ...]] = {"type_a.tare.front_inner": (0.0, 0.5, 1.5, 2.0), "type_a.tare.rear_inner": (0.0, 0.5, 1.5, 2.0)}



HISS_RMS_MPS2 = 0.4  # "hiss a2": per sample at the recording's rate
# Where the noisy sensor's white noise enters: added to the recording after the sensor ("hiss aN",
# damage_sensors), or inside it, before its filters (a failing element: hiss_inside).
HISS_WHERE = ("after", "inside")

# What can be wrong with the sensors (applied to the simulated output; see damage_sensors).
SENSOR_DAMAGE: dict[str, str] = {
    "dead a1": "a1 reads gravity and nothing else (a broken cable at a powered sensor)",
    "stuck a2": "a2's converter freezes 60 s into the run",
    "noisy a3": "a3 picks up white noise of 8 m/s^2 (a loose mounting)",
    "clipping a3": "impacts twice a second drive a3 beyond the +/-16 g range",
    "inverted a1": "a1 mounted upside down",
    "inverted a2": "a2 mounted upside down",
    "inverted a3": "a3 mounted upside down",
    "swapped a1-a2": "the cables of a1 and a2 exchanged",
    "swapped a1-a3": "the cables of a1 and a3 exchanged",
    "swapped a2-a3": "the cables of a2 and a3 exchanged",
    "hiss a2": f"a2 picks up white noise of {HISS_RMS_MPS2:g} m/s^2 RMS, a failing sensor or a poor cable screen: "
    "less than a running frame's own signal, so no level check sees it",
}
# The problem judgement/health.py should name, and on which channels.
EXPECTED_PROBLEM: dict[str, tuple[str, tuple[str, ...]]] = {
    "dead a1": ("flat", ("a1",)),
    "stuck a2": ("stuck", ("a2",)),
    "noisy a3": ("noisy", ("a3",)),
    "clipping a3": ("clipping", ("a3",)),
    "inverted a1": ("inverted", ("a1",)),
    "inverted a2": ("inverted", ("a2",)),
    "inverted a3": ("inverted", ("a3",)),
    "swapped a1-a2": ("swapped", ("a1", "a2")),
    "swapped a1-a3": ("swapped", ("a1", "a3")),
    "swapped a2-a3": ("swapped", ("a2", "a3")),
    "hiss a2": ("noisy", ("a2",)),
}


def damage_sensors(accel_mps2: np.ndarray, damage: str, fs_hz: float, seed: int) -> np.ndarray:
    """The (n, 3) recording with one of SENSOR_DAMAGE applied (a copy)."""
    a = np.array(accel_mps2, dtype=np.float64)
    rng = np.random.default_rng([seed, 2])
    kind, what = damage.split(" ")
    if kind == "dead":
        a[:, 0] = 9.81
    elif kind == "stuck":
        at = int(60 * fs_hz)
        a[at:, 1] = a[at, 1]
    elif kind == "noisy":
        a[:, 2] += rng.normal(0.0, 8.0, a.shape[0])
    elif kind == "hiss":
        c = int(what[1]) - 1
        a[:, c] += rng.normal(0.0, HISS_RMS_MPS2, a.shape[0])
    elif kind == "clipping":
        a[:: int(0.5 * fs_hz), 2] += 400.0
        a[:, 2] = np.clip(a[:, 2], -156.9, 156.9)
    elif kind == "inverted":
        c = int(what[1]) - 1
        a[:, c] = -a[:, c]
    elif kind == "swapped":
        i, j = (int(x[1]) - 1 for x in what.split("-"))
        a[:, [i, j]] = a[:, [j, i]]
    else:  # pragma: no cover - SENSOR_DAMAGE lists every kind
        raise ValueError(f"unknown sensor damage '{damage}'")
    return a


def hiss_inside(scenario: Scenario, channel: int, rms_mps2: float = HISS_RMS_MPS2) -> Scenario:
    """The scenario with white noise inside one channel's sensor, before its filters (a failing
    element, shaped like the signal), of the density the recording's "hiss" has: white noise of
    rms_mps2 per sample at the scenario's rate. Model A's element noise (simulator/sensors.py) or
    model B's (its [sensor] section, through B's own anti-alias filter); either then passes the
    scenario's sensor variant."""
    if scenario.model == "b":
        parameters = copy.deepcopy(scenario.parameters)
        assert parameters is not None
        density = [0.0, 0.0, 0.0]
        density[channel] = rms_mps2 / math.sqrt(scenario.fs_hz / 2.0)
        parameters["vehicle"]["sensor"]["element_noise_density_mps2_per_sqrt_hz"] = density
        return dataclasses.replace(scenario, parameters=parameters)
    noise = [0.0, 0.0, 0.0]
    noise[channel] = rms_mps2
    return dataclasses.replace(scenario, sensor=dataclasses.replace(scenario.sensor, element_noise_mps2=(noise[0], noise[1], noise[2])))


def with_sensor_variant(scenario: Scenario, variant: str) -> Scenario:
    """The scenario read by another sensor part (simulator/sensors.py SENSOR_VARIANTS): model A's
    SensorModel.variant, model B's [sensor] section (its own chain takes the part's filter)."""
    if scenario.model == "b":
        assert scenario.parameters is not None
        return dataclasses.replace(scenario, parameters=model_b_parameters.with_sensor_variant(scenario.parameters, variant))
    return dataclasses.replace(scenario, sensor=dataclasses.replace(scenario.sensor, variant=variant))


def fault_cells() -> dict[str, tuple[float, ...]]:
    """Every case key with its severities: Table 4's rows and the tare inner coils."""
    return {**table4_cases(), **TARE_INNER}


def case_load(key: str) -> str:
    return key.split(".")[1]


def case_kind(key: str, severity: float) -> str:
    """The diagnosis class of a case: 'spring-softer', 'spring-stiffer' or 'friction'."""
    if key.startswith("type_b"):
        return "friction"
    return "spring-softer" if severity < 1.0 else "spring-stiffer"


# --------------------------------------------------------------------------------------------
# The plan


@dataclass(frozen=True)
class RunSpec:
    """One run: who, what, where. `corner` is the fault's corner in the config's naming."""

    # "calibration", "healthy", "fault", "trend", "sensor", "stops", "standing" (evaluation fleet)
    # or "train-healthy", "train-fault"
    role: str
    wagon: int  # index into the plan's fleet (evaluation or training, by role)
    load: str
    key: str  # HEALTHY or a case key, e.g. "type_a.full.rear_outer"
    severity: float
    corner: Corner | None
    number: int  # the run's number among the runs of its role, wagon and load (or its cell); in a trend sequence, its place
    duration_s: float
    onset_s: float = 0.0  # the fault appears this far into the run (0: healthy run)
    damage: str | None = None  # role "sensor": what is wrong with a sensor (SENSOR_DAMAGE)
    # A commissioning run (an evaluation wagon's, or the first runs of a training wagon's, which
    # the model fitting commissions it on).
    commissioning: bool = False
    # A commissioning run's conditions follow the README's old instruction (every track quality,
    # both directions, both ends of the speed range: draw_conditions); not designed, they are what
    # the wagon happened to run (a random draw like any run's), as a keeper commissions.
    designed: bool = True

    @property
    def name(self) -> str:
        where = self.corner.value if self.corner else "-"
        damage = f"|{self.damage}" if self.damage else ""
        planned = ("|commissioning" if self.designed else "|commissioning-drawn") if self.commissioning else ""
        return f"{self.role}|{self.wagon}|{self.load}|{self.key}|{self.severity:g}|{where}|{self.number}{damage}{planned}"

    @property
    def seed(self) -> int:
        return zlib.crc32(self.name.encode())

    @property
    def training(self) -> bool:
        return self.role.startswith("train")

    @property
    def kind(self) -> str | None:
        return None if self.key == HEALTHY else case_kind(self.key, self.severity)


@dataclass(frozen=True)
class Conditions:
    """A run's drawn conditions."""

    track: str
    speed: SpeedProfile
    reversed: bool


def draw_conditions(run: RunSpec) -> Conditions:
    """The run's track, speed profile and direction, from its own seed (reproducible alone).

    A commissioning run follows the README's instruction to a keeper (every track quality, both
    directions of travel, the whole speed range): its number k takes track k modulo the tracks, the
    reverse direction when k is odd, and a speed starting in the lowest or (k // 2 odd) the highest
    quarter of the range, from where it drifts as any run's does."""
    rng = np.random.default_rng([run.seed, 1])
    track = TRACKS[int(rng.integers(len(TRACKS)))]
    n_points = int(math.ceil(run.duration_s / SPEED_POINT_EVERY_S)) + 1
    speeds = [float(rng.uniform(SPEED_MIN_KMH, SPEED_MAX_KMH))]
    if run.commissioning and run.designed:
        track = TRACKS[run.number % len(TRACKS)]
        quarter = (SPEED_MAX_KMH - SPEED_MIN_KMH) / 4.0
        speeds = [SPEED_MAX_KMH - quarter * float(rng.uniform()) if (run.number // 2) % 2 else SPEED_MIN_KMH + quarter * float(rng.uniform())]
    for _ in range(n_points - 1):
        v = speeds[-1] + rng.normal(0.0, SPEED_STEP_SD_KMH)
        # Reflected at the limits (clipping would pile the speeds up at 50 and 110 km/h).
        v = 2 * SPEED_MIN_KMH - v if v < SPEED_MIN_KMH else v
        v = 2 * SPEED_MAX_KMH - v if v > SPEED_MAX_KMH else v
        speeds.append(float(np.clip(v, SPEED_MIN_KMH, SPEED_MAX_KMH)))
    points = tuple((k * SPEED_POINT_EVERY_S, round(v, 3)) for k, v in enumerate(speeds))
    reversed_ = bool(run.number % 2) if run.commissioning and run.designed else bool(rng.integers(2))
    if run.role == "standing":
        points = ((0.0, 0.0),)
    elif run.role == "stops":
        points = with_stops(points, run.duration_s, np.random.default_rng([run.seed, 3]))
    return Conditions(track, SpeedProfile(points), reversed_)


# A stop of a freight train: service braking, a stand, and a start at what the locomotive pulls.
BRAKING_MPS2 = 0.5
STARTING_MPS2 = 0.3
STAND_S = (60.0, 120.0)
FIRST_STOP_S = (60.0, 120.0)  # the first braking begins this far into the run
BETWEEN_STOPS_S = (30.0, 90.0)  # running at speed between one start and the next braking


def with_stops(points: Sequence[tuple[float, float]], duration_s: float, rng: np.random.Generator) -> tuple[tuple[float, float], ...]:
    """The drifting speed profile with one or two stops in it: from the profile's speed at the
    braking, down to 0 km/h at BRAKING_MPS2, standing STAND_S, up at STARTING_MPS2 until it meets
    the profile again, which it then follows. A second stop only where it ends within the run."""
    times = np.array([t for t, _ in points])
    speeds = np.array([v for _, v in points])

    def drift(t: float) -> float:
        return float(np.interp(t, times, speeds))

    wanted = 1 + int(rng.integers(2))
    stops: list[tuple[float, float, float, float]] = []  # (braking starts, stands, starts, back at speed)
    begin = float(rng.uniform(*FIRST_STOP_S))
    for _ in range(wanted):
        stand_s = float(rng.uniform(*STAND_S))
        halt = begin + drift(begin) / 3.6 / BRAKING_MPS2
        start = halt + stand_s
        # Back on the profile where the start's ramp meets it (the profile changes slowly: a few
        # fixed-point steps are exact to well under a second).
        resume = start + drift(start) / 3.6 / STARTING_MPS2
        for _ in range(8):
            resume = start + drift(resume) / 3.6 / STARTING_MPS2
        if resume > duration_s and stops:
            break
        stops.append((begin, halt, start, resume))
        begin = resume + float(rng.uniform(*BETWEEN_STOPS_S))
    out: list[tuple[float, float]] = []
    after = -1.0  # the profile's points are kept from here on (half a second clear of a ramp's ends)
    for begin, halt, start, resume in stops:
        out += [(t, v) for t, v in points if after < t < begin - 0.5]
        out += [(begin, drift(begin)), (halt, 0.0), (start, 0.0), (resume, drift(resume))]
        after = resume + 0.5
    out += [(t, v) for t, v in points if t > after]
    return tuple((round(t, 3), round(v, 3)) for t, v in out)


@dataclass(frozen=True)
class EvaluationPlan:
    """What the evaluation runs. Durations in seconds."""

    name: str
    n_wagons: int = 10
    n_training_wagons: int = 8
    calibration_runs: int = 12  # per wagon and load: two hours of commissioning
    calibration_s: float = 600.0
    healthy_runs: int = 30  # per wagon and load
    healthy_s: float = 600.0
    fault_runs: int = 6  # per case, severity and corner
    lead_in_s: float = 150.0
    fault_s: float = 240.0
    trend_runs: int = 4  # per trend sequence: one per case, severity and corner
    trend_run_s: float = 450.0
    training_healthy_runs: int = 30  # per training wagon and load: its commissioning, then the runs that set the levels
    training_healthy_s: float = 600.0
    training_fault_runs: int = 2  # per case, severity and corner
    training_fault_s: float = 300.0
    sensor_runs: int = 4  # per damage and load
    sensor_s: float = 600.0
    fleet_seed: int = 2026
    loads: tuple[str, ...] = ("full", "tare")
    corners: tuple[Corner, ...] = tuple(Corner)
    model: str = "a"  # the wagon model every run is simulated on (Scenario.model)
    # The (case, severity) cells of the single fault runs, of the trend sequences and of the
    # training fleet's fault runs; None: every cell (fault_cells()).
    fault_cases: tuple[tuple[str, float], ...] | None = None
    trend_cases: tuple[tuple[str, float], ...] | None = None
    training_fault_cases: tuple[tuple[str, float], ...] | None = None
    trend_corners: tuple[Corner, ...] | None = None  # of the trend sequences; None: `corners`
    training_corners: tuple[Corner, ...] | None = None  # of the training fleet's fault runs; None: `corners`
    sensor_damages: tuple[str, ...] | None = None  # None: every SENSOR_DAMAGE
    stop_runs: int = 0  # per wagon and load: healthy runs with one or two stops (draw_conditions)
    stop_s: float = 600.0
    standing_runs: int = 0  # per wagon and load: the wagon stands the whole run
    standing_s: float = 300.0
    # Commissioning on a designed grid (every track quality, both ends of the speeds: the README's
    # old instruction), or on a random draw of what the wagon runs, as a keeper commissions.
    designed_commissioning: bool = True

    @classmethod
    def default(cls) -> EvaluationPlan:
        return cls(name="default")

    @classmethod
    def quick(cls) -> EvaluationPlan:
        """A small plan for trying the command: few wagons, short runs, one run per cell, two corners."""
        return cls(
            name="quick", n_wagons=2, n_training_wagons=2, calibration_runs=2, calibration_s=400.0,
            healthy_runs=2, healthy_s=400.0, fault_runs=1, trend_runs=2, trend_run_s=240.0, training_healthy_runs=6,
            training_healthy_s=400.0, training_fault_runs=1, sensor_runs=1, sensor_s=400.0,
            corners=(Corner.LEADING_LEFT, Corner.TRAILING_RIGHT),
        )  # fmt: skip

    def fleet(self) -> tuple[Wagon, ...]:
        return tuple(
            make_wagon(f"wagon {i + 1}", zlib.crc32(f"{self.fleet_seed}|evaluation|{i}".encode()), self.model) for i in range(self.n_wagons)
        )

    def training_fleet(self) -> tuple[Wagon, ...]:
        return tuple(
            make_wagon(f"training wagon {i + 1}", zlib.crc32(f"{self.fleet_seed}|training|{i}".encode()), self.model)
            for i in range(self.n_training_wagons)
        )

    def runs(self) -> tuple[RunSpec, ...]:
        out: list[RunSpec] = []
        for w in range(self.n_wagons):
            for load in self.loads:
                out += [
                    RunSpec("calibration", w, load, HEALTHY, 1.0, None, r, self.calibration_s, commissioning=True, designed=self.designed_commissioning)
                    for r in range(self.calibration_runs)
                ]
                out += [RunSpec("healthy", w, load, HEALTHY, 1.0, None, r, self.healthy_s) for r in range(self.healthy_runs)]
        out += self._fault_runs("fault", self.n_wagons, self.fault_runs, self.lead_in_s, self.lead_in_s + self.fault_s, self.fault_cases)
        out += self._trend_runs()
        turn = 0
        # In SENSOR_DAMAGE's order, so that a damage added at its end leaves the others' wagons.
        for damage in (d for d in SENSOR_DAMAGE if self.sensor_damages is None or d in self.sensor_damages):
            for load in self.loads:
                for r in range(self.sensor_runs):
                    out.append(RunSpec("sensor", turn % self.n_wagons, load, HEALTHY, 1.0, None, r, self.sensor_s, damage=damage))
                    turn += 1
        for w in range(self.n_wagons):
            for load in self.loads:
                out += [RunSpec("stops", w, load, HEALTHY, 1.0, None, r, self.stop_s) for r in range(self.stop_runs)]
                out += [RunSpec("standing", w, load, HEALTHY, 1.0, None, r, self.standing_s) for r in range(self.standing_runs)]
        for w in range(self.n_training_wagons):
            for load in self.loads:
                out += [
                    RunSpec(
                        "train-healthy", w, load, HEALTHY, 1.0, None, r, self.training_healthy_s,
                        commissioning=r < self.calibration_runs, designed=self.designed_commissioning,
                    )  # fmt: skip
                    for r in range(self.training_healthy_runs)
                ]
        out += self._fault_runs(
            "train-fault", self.n_training_wagons, self.training_fault_runs, 0.0, self.training_fault_s, self.training_fault_cases, self.training_corners
        )
        return tuple(out)

    def _trend_runs(self) -> list[RunSpec]:
        """One sequence per case, severity and corner: a healthy lead-in, the fault appears, and the
        same wagon runs on with it over trend_runs runs of other tracks and speeds."""
        out = []
        for i, run in enumerate(self._fault_runs("trend", self.n_wagons, 1, self.lead_in_s, self.trend_run_s, self.trend_cases, self.trend_corners)):
            # Every sequence on another wagon than the single fault run of its cell and turn.
            wagon = (i + self.n_wagons // 2) % self.n_wagons
            for k in range(self.trend_runs):
                out.append(dataclasses.replace(run, wagon=wagon, number=k, onset_s=self.lead_in_s if k == 0 else 0.0))
        return out

    def _fault_runs(
        self,
        role: str,
        n_wagons: int,
        per_cell: int,
        onset_s: float,
        duration_s: float,
        cases: Sequence[tuple[str, float]] | None = None,
        corners: Sequence[Corner] | None = None,
    ) -> list[RunSpec]:
        out = []
        turn = 0  # cells go round the fleet so that every wagon carries every kind of fault
        for key, severities in fault_cells().items():
            load = case_load(key)
            if load not in self.loads:
                continue
            for severity in severities:
                if cases is not None and (key, severity) not in cases:
                    continue
                for corner in self.corners if corners is None else corners:
                    for r in range(per_cell):
                        out.append(RunSpec(role, turn % n_wagons, load, key, severity, corner, r, duration_s, onset_s))
                        turn += 1
        return out


def scenario_for(run: RunSpec, wagon: Wagon, fs_hz: float, geometry: BogieGeometry) -> Scenario:
    """The simulator's scenario of one run of one wagon."""
    cond = draw_conditions(run)

    def physical(corner: Corner) -> Corner:
        return MIRROR[corner] if cond.reversed else corner

    faults, standing = [], []
    for bogie in ("leading", "trailing"):
        for corner in CORNER_ORDER:
            if bogie == "leading" and corner == run.corner:
                parts = run.key.split(".")
                position = parts[2] if len(parts) == 3 else None
                faults.append(Fault(kind=parts[0], corner=physical(corner), position=position, severity=run.severity))
            else:
                standing.append(wagon.tolerance_fault(physical(corner), bogie, corner, run.load))
    sensors = BogieGeometry(geometry.wheelbase_m, geometry.sensor_spacing_m, tuple(physical(c) for c in geometry.corners))  # type: ignore[arg-type]
    return Scenario(
        load=run.load,
        speed=cond.speed,
        track=cond.track,
        duration_s=run.duration_s,
        seed=run.seed,
        faults=tuple(faults),
        standing_faults=tuple(standing),
        fault_onset_s=run.onset_s if run.key != HEALTHY else 0.0,
        fs_hz=fs_hz,
        geometry=sensors,
        sensor=wagon.scenario_sensor,
        parameters=wagon.parameters,
        model=wagon.model,
    )


# --------------------------------------------------------------------------------------------
# Simulating and analysing


@dataclass(frozen=True)
class RunWindows:
    """One run's windows (detection core at the report's settings), with what the run was."""

    run: RunSpec
    conditions: Conditions
    windows: tuple[WindowIndicators, ...]
    speed_kmh: tuple[float, ...]  # mean speed over each window


@dataclass(frozen=True)
class EvaluationData:
    plan: EvaluationPlan
    settings: ProcessingSettings
    geometry: BogieGeometry
    fleet: tuple[Wagon, ...]
    training_fleet: tuple[Wagon, ...]
    runs: tuple[RunWindows, ...]
    simulated_s: float  # running time of every run of the plan
    elapsed_s: float  # to simulate and analyse the runs that were not reused
    reused_runs: int = 0  # runs taken from an earlier simulation (simulate_plan's `have`)

    def select(self, **where: Any) -> list[RunWindows]:
        """Runs whose RunSpec matches every given attribute (a value, or a set of values)."""
        out = []
        for r in self.runs:
            if all(getattr(r.run, k) in (v if isinstance(v, set | frozenset) else {v}) for k, v in where.items()):
                out.append(r)
        return out


def _window_speeds(speed: SpeedProfile, windows: Sequence[WindowIndicators], step_s: float = 1.0) -> tuple[float, ...]:
    times, speeds = speed.arrays_mps()
    out = []
    for w in windows:
        grid = np.arange(w.start_s, w.end_s + step_s / 2, step_s)
        out.append(float(np.mean(np.interp(grid, times, speeds))) * 3.6)
    return tuple(out)


# Simulated seconds per wall second of the batch kernel and the core on the development machine;
# only weighs the progress fraction.
_SIM_RATE, _ANALYSIS_RATE = 2500.0, 3500.0


def simulate_plan(
    plan: EvaluationPlan,
    settings: ProcessingSettings,
    geometry: BogieGeometry,
    progress: Progress | None = None,
    batch_size: int = 16,
    roles: Iterable[str] | None = None,
    clip_level_mps2: float = 155.0,
    have: Mapping[RunSpec, RunWindows] | None = None,
) -> EvaluationData:
    """Simulate every run of the plan (or of the given roles) and compute its windows.

    have: runs already simulated at these settings (e.g. by an earlier, smaller version of the
    plan): reused as they are, since a run is a function of its spec alone.
    """
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when running

    fleet, training = plan.fleet(), plan.training_fleet()
    wanted = set(roles) if roles is not None else None
    runs = [r for r in plan.runs() if wanted is None or r.role in wanted]
    have = have or {}
    results: dict[int, RunWindows] = {i: have[r] for i, r in enumerate(runs) if r in have}
    todo = [i for i in range(len(runs)) if i not in results]
    total_s = sum(runs[i].duration_s for i in todo) or 1.0
    done_s = 0.0
    out: list[RunWindows] = []
    started = time.perf_counter()
    # Runs of similar length share a batch (the kernel runs until the longest one ends).
    order = sorted(todo, key=lambda i: (runs[i].duration_s, i))
    for first in range(0, len(order), batch_size):
        batch = [runs[i] for i in order[first : first + batch_size]]
        scenarios = [scenario_for(r, (training if r.training else fleet)[r.wagon], settings.fs_hz, geometry) for r in batch]
        weight = sum(r.duration_s for r in batch) / total_s
        sim_share = _ANALYSIS_RATE / (_SIM_RATE + _ANALYSIS_RATE)

        def report(fraction: float, base: float = done_s / total_s, weight: float = weight, sim_share: float = sim_share) -> None:
            if progress is not None:
                progress(min(1.0, base + weight * sim_share * fraction))

        simulated = simulate_batch(scenarios, report)
        for i, run, scenario, result in zip(order[first : first + batch_size], batch, scenarios, simulated, strict=True):
            accel = result.accel_mps2 if run.damage is None else damage_sensors(result.accel_mps2, run.damage, settings.fs_hz, run.seed)
            windows = tuple(IndicatorStream(settings, geometry, clip_level_mps2=clip_level_mps2).process(accel))
            cond = draw_conditions(run)
            results[i] = RunWindows(run, cond, windows, _window_speeds(scenario.speed, windows))
        done_s += weight * total_s
        if progress is not None:
            progress(min(1.0, done_s / total_s))
    out = [results[i] for i in range(len(runs))]
    return EvaluationData(
        plan=plan,
        settings=settings,
        geometry=geometry,
        fleet=fleet,
        training_fleet=training,
        runs=tuple(out),
        simulated_s=sum(r.duration_s for r in runs),
        elapsed_s=time.perf_counter() - started,
        reused_runs=len(runs) - len(todo),
    )
