"""A simulated fleet in the back office's recordings tree (docs/fleet-formats.md section 1): what
`bogiemon fleet simulate` writes for the demo and the tests, since nobody breaks springs under
real wagons to try the back office.

    plan = FleetPlan()                                    # the demo; FleetPlan.tiny() for tests
    truth = simulate_fleet("FLEET", plan, progress)       # the tree, and what was wrong where

THE WAGONS. Wagon i is drawn with the evaluation's make_wagon (lab/robust/wagons.py: its masses,
springs, dampers and sensors spread over the fleet) from a seed of fleet_seed and i, and runs at
one load all along (by default the wagons alternate full and tare, wagon 0 full). Its gateway's
config names the paper's sensor layout (a1 leading-left, a2 leading-right, a3 trailing-left) and
decision.load = "auto"; no calibration.toml is written: the wagons are uncommissioned until the
keeper runs `bogiemon fleet calibrate` on their first day.

THE DAYS. Day 0 (start_date) holds commission_runs healthy runs of every wagon, its
commissioning; every later day runs_per_day runs. Runs start at first_run_s after midnight UTC and
every run_every_s after it, and last run_s each; a recording's times are Unix seconds. Each run's
track, drifting speed and direction of travel are drawn as the evaluation draws them
(draw_conditions, scenario_for), from a seed of the fleet, the wagon, the day and the run alone:
a fault or a damaged sensor changes nothing else of the run, so the same plan without it gives
the same tracks, speeds and sensor noise.

THE FAULTS. A FaultOnset (a case of the paper's tables at one of its severities, at a corner of
the monitored bogie, named as the wagon's config names them) is in the suspension from the first
sample of its day's first run and on every later run (no onset within a run: every recording is
either healthy or faulty, which is what the truth can state plainly). A SensorOnset
(lab/robust/fleet.py SENSOR_DAMAGE) likewise, applied to the recorded signals as the evaluation
applies it.

truth.json (not read by the back office) states per wagon its load, its faults and damaged sensors
with their day, and every run: its file, track, mean speed, direction, and the faults the
simulator actually ran (at the physical corner: mirrored on a reversed run).
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bogiemon.drivers.atomic import write_atomically, write_text_atomically
from bogiemon.daemon import tomlout
from bogiemon.detection import PAPER_LAYOUT, Corner
from bogiemon.lab.robust.fleet import (
    EXPECTED_PROBLEM,
    HEALTHY,
    SENSOR_DAMAGE,
    RunSpec,
    case_kind,
    case_load,
    damage_sensors,
    draw_conditions,
    fault_cells,
    scenario_for,
)
from bogiemon.lab.robust.wagons import Wagon, make_wagon

Progress = Callable[[float], None]

TRUTH_FORMAT = "bogiemon-fleetsim/1"
WAGON_TYPE = "Sgns-Y25"
# Wagon i is "31-80-4557-{i + 1:03d}": shaped like a 12-digit UIC wagon number written with '-'
# (no check digit), a valid folder name of the tree (letters, digits and '-').
WAGON_ID_PREFIX = "31-80-4557-"
MAX_WAGONS = 999
DAY_S = 86400.0
# Shorter runs give no window of the shipped config (120 s) and "stuck a2" freezes 60 s in.
MIN_RUN_S = 120.0
# Runs simulated together: the batch kernel is much faster per run in batches (simulator/run.py);
# 16 runs of 600 s at 500 Hz hold about 120 MB of samples.
BATCH_SIZE = 16
# zlib's fastest level for the simulated recordings: writing them was most of a fleet's simulation
# (the CSV's text, then level 6 compressing it, at 450 x real time against the kernel's 1800 x).
# Level 1 writes 220 s at 500 Hz in 0.14 CPU s instead of 0.35 s, into 12 % more bytes
# (drivers/recording.py GZIP_LEVEL); the files are the test and demo fleets, read once or twice.
GZIP_LEVEL = 1
# Simulated seconds per wall second, of the batch kernel (measured on FleetPlan.tiny()) and of
# writing a recording (CSV text and gzip at GZIP_LEVEL: 220 s in 0.14 CPU s) on the development
# machine; they only weigh the progress fraction.
_SIM_RATE, _WRITE_RATE = 1800.0, 1500.0


class FleetSimError(ValueError):
    """A fleet plan or target folder that cannot be simulated; the message names what and the remedy."""


@dataclass(frozen=True)
class FaultOnset:
    """A suspension fault of wagon `wagon` from day `day` (0-based) on.

    key: a case of the paper's tables (lab/robust/fleet.py fault_cells), e.g.
    "type_a.full.rear_outer", at one of its severities; corner: on the monitored bogie, named as
    the wagon's config names its corners (a string is taken as a Corner's value).
    """

    wagon: int
    day: int
    key: str
    severity: float
    corner: Corner

    def __post_init__(self) -> None:
        if not isinstance(self.corner, Corner):
            try:
                object.__setattr__(self, "corner", Corner(self.corner))
            except ValueError:
                names = ", ".join(c.value for c in Corner)
                raise FleetSimError(f"fault on wagon {self.wagon}: unknown corner '{self.corner}': use one of {names}") from None
        cells = fault_cells()
        if self.key not in cells:
            raise FleetSimError(f"fault on wagon {self.wagon}: unknown case '{self.key}': use one of {', '.join(cells)}")
        try:
            severity = float(self.severity)
        except (TypeError, ValueError):
            raise FleetSimError(f"fault on wagon {self.wagon}: severity must be a number, got {self.severity!r}") from None
        if severity not in cells[self.key]:
            shown = ", ".join(f"{s:g}" for s in cells[self.key])
            raise FleetSimError(f"fault on wagon {self.wagon}: {self.key} has no severity {self.severity:g} in the paper's tables: use one of {shown}")
        object.__setattr__(self, "severity", severity)

    @property
    def load(self) -> str:
        return case_load(self.key)

    @property
    def kind(self) -> str:
        """The diagnosis class: 'spring-softer', 'spring-stiffer' or 'friction' (case_kind)."""
        return case_kind(self.key, self.severity)


@dataclass(frozen=True)
class SensorOnset:
    """A damaged sensor of wagon `wagon` from day `day` (0-based) on: one of SENSOR_DAMAGE."""

    wagon: int
    day: int
    damage: str

    def __post_init__(self) -> None:
        if self.damage not in SENSOR_DAMAGE:
            raise FleetSimError(f"sensor damage on wagon {self.wagon}: unknown '{self.damage}': use one of {', '.join(SENSOR_DAMAGE)}")


# The demo (the wagons alternate full and tare from wagon 0 full): a broken rear outer coil at
# leading-left (a1's corner) of full-load wagon 2 from day 2, another at trailing-left (a3's) of
# full-load wagon 4 from day 1, and a loose a3 on tare wagon 5 from day 2 (days from 0).
DEMO_FAULTS: tuple[FaultOnset, ...] = (
    FaultOnset(wagon=2, day=2, key="type_a.full.rear_outer", severity=0.0, corner=Corner.LEADING_LEFT),
    FaultOnset(wagon=4, day=1, key="type_a.full.rear_outer", severity=0.0, corner=Corner.TRAILING_LEFT),
)
DEMO_SENSOR_DAMAGES: tuple[SensorOnset, ...] = (SensorOnset(wagon=5, day=2, damage="noisy a3"),)


@dataclass(frozen=True)
class FleetRun(RunSpec):
    """One run of the simulated fleet: the evaluation's RunSpec, placed on a day.

    Its seed is the fleet's, the wagon's, the day's and the run's alone (not the fault's): the
    RunSpec's own seed would change with the role and key, and not with the fleet seed.
    """

    fleet_seed: int = 0
    day: int = 0
    of_day: int = 0  # the run's place in its day, from 0

    @property
    def seed(self) -> int:
        return zlib.crc32(f"fleetsim|{self.fleet_seed}|{self.wagon}|{self.day}|{self.of_day}".encode())


@dataclass(frozen=True)
class FleetPlan:
    """What simulate_fleet writes. Times in seconds; days 0-based from start_date (UTC)."""

    n_wagons: int = 8
    days: int = 3
    start_date: str = "2026-11-02"
    commission_runs: int = 6  # on day 0: the wagon's commissioning, healthy
    runs_per_day: int = 3  # on every later day
    run_s: float = 600.0
    fs_hz: float = 500.0
    fleet_seed: int = 2026
    loads: tuple[str, ...] | None = None  # per wagon; None: alternating full, tare, full, ...
    faults: tuple[FaultOnset, ...] = DEMO_FAULTS
    sensor_damages: tuple[SensorOnset, ...] = DEMO_SENSOR_DAMAGES
    first_run_s: float = 6 * 3600.0  # after midnight UTC: the first run of a day starts at 06:00
    run_every_s: float = 5400.0  # a run starts every 90 minutes
    name: str = "Simulated Sgns-Y25 fleet"
    wagon_type: str = WAGON_TYPE

    def __post_init__(self) -> None:
        object.__setattr__(self, "faults", tuple(self.faults))
        object.__setattr__(self, "sensor_damages", tuple(self.sensor_damages))
        if self.loads is not None:
            object.__setattr__(self, "loads", tuple(self.loads))
        problems = self._problems()
        if problems:
            raise FleetSimError("fleet plan: " + "; ".join(problems))

    @classmethod
    def tiny(cls) -> FleetPlan:
        """Three wagons over two days, a broken coil on wagon 0 and a loose a3 on wagon 1 from day 1:
        the tests' fleet (15 runs of 400 s)."""
        return cls(
            n_wagons=3,
            days=2,
            commission_runs=3,
            runs_per_day=2,
            run_s=400.0,
            faults=(FaultOnset(wagon=0, day=1, key="type_a.full.rear_outer", severity=0.0, corner=Corner.LEADING_LEFT),),
            sensor_damages=(SensorOnset(wagon=1, day=1, damage="noisy a3"),),
            name="Tiny simulated Sgns-Y25 fleet",
        )

    def _problems(self) -> list[str]:
        problems = []
        if not (isinstance(self.n_wagons, int) and 1 <= self.n_wagons <= MAX_WAGONS):
            problems.append(f"n_wagons must be 1..{MAX_WAGONS}, got {self.n_wagons!r}")
        if not (isinstance(self.days, int) and self.days >= 1):
            problems.append(f"days must be 1 or more, got {self.days!r}")
        for field in ("commission_runs", "runs_per_day"):
            value = getattr(self, field)
            if not (isinstance(value, int) and value >= 1):
                problems.append(f"{field} must be 1 or more, got {value!r}")
        try:
            dt.date.fromisoformat(self.start_date)
        except (TypeError, ValueError):
            problems.append(f"start_date must be a date YYYY-MM-DD, got {self.start_date!r}")
        if not self.fs_hz > 0:
            problems.append(f"fs_hz must be positive, got {self.fs_hz!r}")
        if not self.run_s >= MIN_RUN_S:
            problems.append(f"run_s must be at least {MIN_RUN_S:g} s (one analysis window), got {self.run_s!r}")
        if not self.run_every_s >= self.run_s:
            problems.append(f"runs of {self.run_s:g} s starting every {self.run_every_s:g} s would overlap: make run_every_s at least run_s")
        if problems:
            return problems  # what follows needs the numbers above
        most = max(self.commission_runs, self.runs_per_day)
        end_s = self.first_run_s + (most - 1) * self.run_every_s + self.run_s
        if not (self.first_run_s >= 0 and end_s <= DAY_S):
            problems.append(
                f"{most} runs of {self.run_s:g} s every {self.run_every_s:g} s from {self.first_run_s:g} s after midnight "
                "end after midnight: a day folder holds one UTC day; fewer or shorter runs, or an earlier first_run_s"
            )
        if self.loads is not None and (len(self.loads) != self.n_wagons or not set(self.loads) <= {"full", "tare"}):
            problems.append(f"loads must name 'full' or 'tare' for each of the {self.n_wagons} wagons, got {self.loads!r}")
            return problems
        for what, onsets in (("fault", self.faults), ("sensor damage", self.sensor_damages)):
            seen: set[int] = set()
            for onset in onsets:
                if not (isinstance(onset.wagon, int) and 0 <= onset.wagon < self.n_wagons):
                    problems.append(f"{what} on wagon {onset.wagon!r}: the plan's wagons are 0..{self.n_wagons - 1}")
                    continue
                if not (isinstance(onset.day, int) and 1 <= onset.day < self.days):
                    problems.append(
                        f"{what} on wagon {onset.wagon} from day {onset.day!r}: day 0 is the healthy commissioning, "
                        f"so a day of 1..{self.days - 1}" + (" (the plan has one day: add days)" if self.days == 1 else "")
                    )
                if onset.wagon in seen:
                    problems.append(f"wagon {onset.wagon} has more than one {what}: a run simulates one of each")
                seen.add(onset.wagon)
                if isinstance(onset, FaultOnset) and onset.load != self.wagon_load(onset.wagon):
                    problems.append(
                        f"fault {onset.key} is a {onset.load}-load case, wagon {onset.wagon} runs {self.wagon_load(onset.wagon)}: "
                        f"use a {self.wagon_load(onset.wagon)}-load case or another wagon"
                    )
        return problems

    # ---- the plan's wagons, days and runs

    def wagon_load(self, wagon: int) -> str:
        if self.loads is not None:
            return self.loads[wagon]
        return "full" if wagon % 2 == 0 else "tare"

    def wagon_id(self, wagon: int) -> str:
        return f"{WAGON_ID_PREFIX}{wagon + 1:03d}"

    def wagon_seed(self, wagon: int) -> int:
        return zlib.crc32(f"{self.fleet_seed}|fleetsim|{wagon}".encode())

    def wagons(self) -> tuple[Wagon, ...]:
        return tuple(make_wagon(self.wagon_id(i), self.wagon_seed(i)) for i in range(self.n_wagons))

    def date(self, day: int) -> dt.date:
        return dt.date.fromisoformat(self.start_date) + dt.timedelta(days=day)

    def runs_on(self, day: int) -> int:
        return self.commission_runs if day == 0 else self.runs_per_day

    def start_unix_s(self, day: int, of_day: int) -> float:
        """The Unix time of a run's first sample."""
        midnight = dt.datetime.combine(self.date(day), dt.time(0), tzinfo=dt.UTC).timestamp()
        return midnight + self.first_run_s + of_day * self.run_every_s

    def fault_of(self, wagon: int) -> FaultOnset | None:
        return next((f for f in self.faults if f.wagon == wagon), None)

    def damage_of(self, wagon: int) -> SensorOnset | None:
        return next((d for d in self.sensor_damages if d.wagon == wagon), None)

    def runs(self) -> tuple[FleetRun, ...]:
        """Every run of every wagon, wagon by wagon, in time order."""
        out = []
        for w in range(self.n_wagons):
            fault, damage = self.fault_of(w), self.damage_of(w)
            number = 0
            for day in range(self.days):
                now = fault if fault is not None and day >= fault.day else None
                damaged = damage.damage if damage is not None and day >= damage.day else None
                role = "fault" if now else "sensor" if damaged else "calibration" if day == 0 else "healthy"
                for k in range(self.runs_on(day)):
                    out.append(
                        FleetRun(
                            role=role,
                            wagon=w,
                            load=self.wagon_load(w),
                            key=now.key if now else HEALTHY,
                            severity=now.severity if now else 1.0,
                            corner=now.corner if now else None,
                            number=number,
                            duration_s=self.run_s,
                            damage=damaged,
                            fleet_seed=self.fleet_seed,
                            day=day,
                            of_day=k,
                        )
                    )
                    number += 1
        return tuple(out)

    def recording_path(self, run: FleetRun) -> str:
        """The run's recording, relative to the fleet's root: <wagon-id>/<date>/<HHMMSS>_run<k>.csv.gz."""
        start = dt.datetime.fromtimestamp(self.start_unix_s(run.day, run.of_day), tz=dt.UTC)
        return f"{self.wagon_id(run.wagon)}/{self.date(run.day).isoformat()}/{start:%H%M%S}_run{run.of_day + 1}.csv.gz"

    def to_dict(self) -> dict[str, Any]:
        return {
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("faults", "sensor_damages", "loads")},
            "loads": [self.wagon_load(i) for i in range(self.n_wagons)],
        }


# --------------------------------------------------------------------------------------------
# The truth


@dataclass(frozen=True)
class RunTruth:
    """One recording as simulated."""

    file: str  # relative to the fleet's root
    day: int
    start_s: float  # Unix seconds of the first sample
    duration_s: float
    track: str
    mean_speed_kmh: float
    reversed: bool
    seed: int
    simulated_faults: tuple[str, ...]  # the simulator's faults (Fault.spec(), the physical corner)
    damage: str | None  # the sensor damage applied to the recording


@dataclass(frozen=True)
class WagonTruth:
    wagon_id: str
    index: int
    seed: int
    load: str
    wagon_type: str
    faults: tuple[FaultOnset, ...]
    sensor_damages: tuple[SensorOnset, ...]
    runs: tuple[RunTruth, ...]


@dataclass(frozen=True)
class FleetTruth:
    """What simulate_fleet wrote, and what was wrong where (truth.json)."""

    root: Path
    plan: FleetPlan
    wagons: tuple[WagonTruth, ...]

    def to_dict(self) -> dict[str, Any]:
        plan = self.plan

        def day(d: int) -> dict[str, Any]:
            return {"day": d, "date": plan.date(d).isoformat()}

        return {
            "format": TRUTH_FORMAT,
            "fleet": plan.name,
            "plan": plan.to_dict(),
            "wagons": [
                {
                    "wagon": w.wagon_id,
                    "index": w.index,
                    "seed": w.seed,
                    "type": w.wagon_type,
                    "load": w.load,
                    "faults": [
                        {**day(f.day), "corner": f.corner.value, "key": f.key, "severity": f.severity, "kind": f.kind} for f in w.faults
                    ],
                    "sensor_damages": [
                        {**day(s.day), "damage": s.damage, "problem": EXPECTED_PROBLEM[s.damage][0], "channels": list(EXPECTED_PROBLEM[s.damage][1])}
                        for s in w.sensor_damages
                    ],
                    "runs": [
                        {
                            "file": r.file,
                            **day(r.day),
                            "start_s": r.start_s,
                            "duration_s": r.duration_s,
                            "track": r.track,
                            "mean_speed_kmh": r.mean_speed_kmh,
                            "reversed": r.reversed,
                            "seed": r.seed,
                            "simulated_faults": list(r.simulated_faults),
                            "damage": r.damage,
                        }
                        for r in w.runs
                    ],
                }
                for w in self.wagons
            ],
        }


# --------------------------------------------------------------------------------------------
# Writing the tree


def simulate_fleet(root: str | Path, plan: FleetPlan, progress: Progress | None = None) -> FleetTruth:
    """Simulate the plan's fleet into the folder root (new or empty); progress(fraction) as it goes.

    truth.json is written last: a tree with it is complete.
    """
    from bogiemon.daemon.config import load_config
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when running

    root = Path(root)
    if root.exists() and (not root.is_dir() or any(root.iterdir())):
        raise FleetSimError(f"{root}: not an empty folder; simulate a fleet into a new or empty one (nothing there is overwritten)")
    root.mkdir(parents=True, exist_ok=True)
    _write_fleet_toml(root, plan)
    geometries = {}
    for w in range(plan.n_wagons):
        config_path = _write_wagon_config(root, plan, w)
        # The recordings are simulated with the sensors where the written config says they are.
        geometries[w] = load_config(config_path, log_warnings=False).bogie_geometry()

    wagons, runs = plan.wagons(), plan.runs()
    total_s = sum(r.duration_s for r in runs)
    sim_share = _WRITE_RATE / (_SIM_RATE + _WRITE_RATE)  # of a batch's wall time
    done_s = 0.0
    written: dict[FleetRun, RunTruth] = {}
    if progress is not None:
        progress(0.0)
    for first in range(0, len(runs), BATCH_SIZE):
        batch = runs[first : first + BATCH_SIZE]
        scenarios = [scenario_for(r, wagons[r.wagon], plan.fs_hz, geometries[r.wagon]) for r in batch]
        base, weight = done_s / total_s, sum(r.duration_s for r in batch) / total_s

        def report(fraction: float, base: float = base, weight: float = weight) -> None:
            if progress is not None:
                progress(min(1.0, base + weight * sim_share * fraction))

        for i, (run, scenario, result) in enumerate(zip(batch, scenarios, simulate_batch(scenarios, report), strict=True)):
            accel = result.accel_mps2 if run.damage is None else damage_sensors(result.accel_mps2, run.damage, plan.fs_hz, run.seed)
            start_s = plan.start_unix_s(run.day, run.of_day)
            path = plan.recording_path(run)
            _write_recording(root / path, start_s + result.time_s, accel)
            cond = draw_conditions(run)
            written[run] = RunTruth(
                file=path,
                day=run.day,
                start_s=start_s,
                duration_s=run.duration_s,
                track=cond.track,
                mean_speed_kmh=round(cond.speed.distance_m(run.duration_s) / run.duration_s * 3.6, 3),
                reversed=cond.reversed,
                seed=run.seed,
                simulated_faults=tuple(f.spec() for f in scenario.faults),
                damage=run.damage,
            )
            if progress is not None:
                progress(min(1.0, base + weight * (sim_share + (1.0 - sim_share) * (i + 1) / len(batch))))
        done_s += weight * total_s

    truth = FleetTruth(
        root=root,
        plan=plan,
        wagons=tuple(
            WagonTruth(
                wagon_id=plan.wagon_id(w),
                index=w,
                seed=plan.wagon_seed(w),
                load=plan.wagon_load(w),
                wagon_type=plan.wagon_type,
                faults=tuple(f for f in plan.faults if f.wagon == w),
                sensor_damages=tuple(s for s in plan.sensor_damages if s.wagon == w),
                runs=tuple(written[r] for r in runs if r.wagon == w),
            )
            for w in range(plan.n_wagons)
        ),
    )
    write_text_atomically(root / "truth.json", json.dumps(truth.to_dict(), indent=2) + "\n")
    if progress is not None:
        progress(1.0)
    return truth


def _write_fleet_toml(root: Path, plan: FleetPlan) -> None:
    data = {
        "fleet": {"name": plan.name, "default_type": plan.wagon_type},
        "wagons": {plan.wagon_id(w): {"type": plan.wagon_type} for w in range(plan.n_wagons)},
    }
    header = f"# {plan.name}: simulated by bogiemon.lab.fleetsim (fleet seed {plan.fleet_seed}); truth.json says what is wrong where.\n"
    (root / "fleet.toml").write_text(header + tomlout.dumps(data), encoding="utf-8")


def _write_wagon_config(root: Path, plan: FleetPlan, wagon: int) -> Path:
    """<wagon-id>/bogiemon.toml: its gateway's config; the shipped default for everything else."""
    data = {
        "wagon": {"id": plan.wagon_id(wagon)},
        "sensors": {f"a{i + 1}": c.value for i, c in enumerate(PAPER_LAYOUT)},
        "processing": {"fs_hz": plan.fs_hz},
        "decision": {"load": "auto"},
    }
    header = (
        f"# Simulated wagon {plan.wagon_id(wagon)} (bogiemon.lab.fleetsim): its gateway's config over the shipped default.\n"
        "# Not commissioned: `bogiemon fleet calibrate` writes calibration.toml beside this file.\n"
    )
    folder = root / plan.wagon_id(wagon)
    folder.mkdir()
    path = folder / "bogiemon.toml"
    path.write_text(header + tomlout.dumps(data), encoding="utf-8")
    return path


def _write_recording(path: Path, time_s: Any, accel_mps2: Any) -> None:
    """A gzip CSV recording, by drivers/recording.py's writer (gzip for a name ending in .gz, with no
    time stamp in its header: the same samples give the same bytes), written whole or not at all,
    at GZIP_LEVEL."""
    from bogiemon.drivers.recording import write_csv_recording

    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, lambda temporary: write_csv_recording(temporary, time_s, accel_mps2, gzip_level=GZIP_LEVEL))



