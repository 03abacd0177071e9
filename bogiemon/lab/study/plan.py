"""The study's plan: the paper's experiment matrix (loads, fault cases, speeds, tracks, runs) and
the scenario of each run; lab/study/__init__.py describes the study as a whole."""

from __future__ import annotations

import copy
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from bogiemon.judgement.events import INDICATOR_FIELDS
from bogiemon.detection import BogieGeometry, Corner
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.scenario import Scenario, SpeedProfile
from bogiemon.simulator.sensors import SensorModel
from bogiemon.simulator.suspension import Fault

INDICATORS: tuple[str, ...] = INDICATOR_FIELDS  # the daemon's indicator fields, in its order
LABELS: dict[str, str] = dict(zip(INDICATORS, ("I1", "I2", "I3", "I4", "I1n", "I2n", "I3n", "I4n"), strict=True))
PAPER_INDICATORS: tuple[str, ...] = INDICATORS[:4]  # Table 4's columns 1..4
RAW, NORMALISED = INDICATORS[:4], INDICATORS[4:]
HEALTHY = "healthy"
ENVELOPE = "envelope"  # the group of healthy runs at the speeds of the envelope outside the matrix
# The healthy runs the daemon's thresholds are derived from: the matrix's and the envelope's.
THRESHOLD_GROUPS: frozenset[str] = frozenset({"", ENVELOPE})
HEALTHY_SEVERITY = 1.0


@dataclass(frozen=True)
class Condition:
    """One operating condition: a constant speed on one track quality."""

    speed_kmh: float
    track: str

    @property
    def label(self) -> str:
        return f"{self.speed_kmh:g} km/h, {self.track}"


@dataclass(frozen=True)
class FaultCase:
    """One cell of the paper's tables: a Table 4 row ('type_a.full.rear_outer', 'type_b.tare') at a
    severity, or the healthy wagon (key 'healthy', severity 1.0) of one load."""

    key: str
    load: str
    severity: float = HEALTHY_SEVERITY

    @property
    def kind(self) -> str:
        return self.key.split(".")[0]

    @property
    def position(self) -> str | None:
        parts = self.key.split(".")
        return parts[2] if len(parts) == 3 else None

    def fault(self, corner: Corner) -> Fault | None:
        if self.key == HEALTHY:
            return None
        return Fault(kind=self.kind, corner=corner, position=self.position, severity=self.severity)


def table4_cases(fault_cases: Mapping[str, Any] | None = None) -> dict[str, tuple[float, ...]]:
    """Table 4's rows, each with the severities the paper's Tables 1-3 give for it."""
    cases = fault_cases if fault_cases is not None else default_parameter_set()["fault_cases"]
    out: dict[str, tuple[float, ...]] = {}
    for key in cases["table4"]:
        if key == "indicators":
            continue
        kind, load, *position = key.split(".")
        table = cases[kind][load][position[0]] if position else cases[kind][load]
        out[key] = tuple(sorted(float(k) for k in table if _is_number(k)))
    return out


def paper_table4(fault_cases: Mapping[str, Any] | None = None) -> dict[str, tuple[bool, ...]]:
    """The paper's Table 4: per row, identified by indicators 1..4."""
    cases = fault_cases if fault_cases is not None else default_parameter_set()["fault_cases"]
    return {k: tuple(bool(v) for v in vs) for k, vs in cases["table4"].items() if k != "indicators"}


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


@dataclass(frozen=True)
class Sensitivity:
    """Extra runs at the plan's sensitivity condition: another stick stiffness of the Lenoir damper
    (with its own healthy runs) or the fault at another corner (against the main healthy runs)."""

    name: str
    case_keys: tuple[str, ...]
    stick_stiffness_n_per_m: float | None = None  # None: the shipped value
    fault_corner: Corner | None = None  # None: the plan's fault corner
    severities: tuple[float, ...] | None = None  # None: every severity of each case

    @property
    def own_healthy(self) -> bool:
        return self.stick_stiffness_n_per_m is not None


@dataclass(frozen=True)
class StudyPlan:
    """What the study runs. Durations in seconds; runs per healthy case and per fault severity."""

    name: str
    conditions: tuple[Condition, ...]
    loads: tuple[str, ...] = ("full", "tare")
    healthy_runs: int = 24
    fault_runs: int = 6
    duration_s: float = 300.0
    window_lengths_s: tuple[float, ...] = (30.0, 60.0, 120.0)
    fault_corner: Corner = Corner.LEADING_LEFT
    noise_mps2: float = 0.01
    sensitivities: tuple[Sensitivity, ...] = ()
    sensitivity_condition: Condition | None = None
    sensitivity_healthy_runs: int = 24
    # Healthy runs at speeds outside the matrix (group "envelope"): the rest of the range the daemon
    # judges, for the thresholds (not for Table 4).
    envelope_conditions: tuple[Condition, ...] = ()
    envelope_runs: int = 24

    def __post_init__(self) -> None:
        if not self.conditions:
            raise ValueError("a study plan needs at least one speed and track")
        if self.healthy_runs < 2 or self.fault_runs < 1:
            raise ValueError(f"need at least 2 healthy runs and 1 run per fault severity, got {self.healthy_runs}, {self.fault_runs}")
        if not self.window_lengths_s:
            raise ValueError("a study plan needs at least one window length")
        if any(w <= 0 or w >= self.duration_s for w in self.window_lengths_s):
            raise ValueError(f"window lengths {self.window_lengths_s} s must lie in (0, {self.duration_s:g}) s (the run length)")
        if self.sensitivities and self.sensitivity_condition is None:
            raise ValueError("sensitivities need a sensitivity_condition")

    @classmethod
    def default(cls, window_lengths_s: Sequence[float] = (30.0, 60.0, 120.0)) -> StudyPlan:
        """The full matrix: 2 loads x (healthy + 32 fault cells) x 2 speeds x 2 ERRI tracks, with
        healthy envelope runs at 40 and 120 km/h and the sensitivity runs.

        60 and 100 km/h bracket a loaded Y25 wagon's service (100 km/h is the loaded maximum of the
        S regime); ERRI low and high level are the two standard European spectra (a good main
        line and a poorer one). Runs of 300 s hold 19 windows of 120 s every 10 s (28 of 30 s).
        """
        reference = Condition(100.0, "erri-low")
        broken_outer = ("type_a.full.rear_outer",)
        return cls(
            name="default",
            conditions=(Condition(60.0, "erri-low"), Condition(60.0, "erri-high"), reference, Condition(100.0, "erri-high")),
            window_lengths_s=tuple(float(w) for w in window_lengths_s),
            sensitivity_condition=reference,
            envelope_conditions=tuple(Condition(v, t) for v in (40.0, 120.0) for t in ("erri-low", "erri-high")),
            sensitivities=(
                *(
                    Sensitivity(
                        f"k_stick {k / 1e6:g} MN/m",
                        ("type_a.full.rear_outer", "type_b.full", "type_a.tare.rear_outer"),
                        stick_stiffness_n_per_m=k,
                    )
                    for k in (10e6, 50e6)
                ),
                *(
                    Sensitivity(f"fault at {c.value}", broken_outer, fault_corner=c, severities=(0.0,))
                    for c in (Corner.LEADING_RIGHT, Corner.TRAILING_LEFT, Corner.TRAILING_RIGHT)
                ),
            ),
        )

    @classmethod
    def quick(cls, window_s: float = 60.0) -> StudyPlan:
        """A small subset of the default matrix: its runs at 100 km/h on ERRI low level (all 24
        healthy ones per load, 2 per fault severity), one window length, no sensitivity or envelope
        runs; every Table 4 case, in well under a minute."""
        return cls(
            name="quick",
            conditions=(Condition(100.0, "erri-low"),),
            healthy_runs=24,  # as many as the default plan: the healthy 99th percentiles need many tracks
            fault_runs=2,
            window_lengths_s=(float(window_s),),
        )

    def runs(self) -> tuple[StudyRun, ...]:
        """Every run of the plan: the main matrix, the sensitivities, then the envelope."""
        rows = table4_cases()
        out: list[StudyRun] = []
        for load in self.loads:
            for cond in self.conditions:
                out += [StudyRun("", FaultCase(HEALTHY, load), cond, r, self.fault_corner) for r in range(self.healthy_runs)]
                for key, severities in rows.items():
                    if key.split(".")[1] != load:
                        continue
                    for sev in severities:
                        out += [StudyRun("", FaultCase(key, load, sev), cond, r, self.fault_corner) for r in range(self.fault_runs)]
        for sens in self.sensitivities:
            assert self.sensitivity_condition is not None
            cond, corner = self.sensitivity_condition, sens.fault_corner or self.fault_corner
            loads = [load for load in self.loads if any(k.split(".")[1] == load for k in sens.case_keys)]
            if sens.own_healthy:
                for load in loads:
                    out += [
                        StudyRun(sens.name, FaultCase(HEALTHY, load), cond, r, corner, sens.stick_stiffness_n_per_m)
                        for r in range(self.sensitivity_healthy_runs)
                    ]
            for key in sens.case_keys:
                if key.split(".")[1] not in self.loads:
                    continue
                for sev in sens.severities or rows[key]:
                    out += [
                        StudyRun(sens.name, FaultCase(key, key.split(".")[1], sev), cond, r, corner, sens.stick_stiffness_n_per_m)
                        for r in range(self.fault_runs)
                    ]
        for load in self.loads:
            for cond in self.envelope_conditions:
                out += [StudyRun(ENVELOPE, FaultCase(HEALTHY, load), cond, r, self.fault_corner) for r in range(self.envelope_runs)]
        return tuple(out)


@dataclass(frozen=True)
class StudyRun:
    """One simulated run of the study."""

    group: str  # "" for the main matrix, ENVELOPE, or a sensitivity's name
    case: FaultCase
    condition: Condition
    rep: int
    corner: Corner
    stick_stiffness_n_per_m: float | None = None

    @property
    def name(self) -> str:
        c = self.case
        return f"{c.load}|{c.key}|{c.severity:g}|{self.condition.speed_kmh:g}|{self.condition.track}|{self.rep}"

    @property
    def seed(self) -> int:
        # The group and the corner are left out on purpose: a sensitivity run sees the same track
        # as the main-matrix run of the same cell (a paired comparison).
        return zlib.crc32(self.name.encode())

    def scenario(self, duration_s: float, fs_hz: float, geometry: BogieGeometry, noise_mps2: float) -> Scenario:
        fault = self.case.fault(self.corner)
        parameters = None
        if self.stick_stiffness_n_per_m is not None:
            parameters = copy.deepcopy(default_parameter_set())
            parameters["vehicle"]["primary"]["stick_stiffness_n_per_m"] = self.stick_stiffness_n_per_m
        return Scenario(
            load=self.case.load,
            speed=SpeedProfile.constant(self.condition.speed_kmh),
            track=self.condition.track,
            duration_s=duration_s,
            seed=self.seed,
            faults=(fault,) if fault is not None else (),
            fs_hz=fs_hz,
            geometry=geometry,
            sensor=SensorModel(noise_mps2=noise_mps2),
            parameters=parameters,
        )
