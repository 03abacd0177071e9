"""The detection study (issue 4): the paper's experiment matrix on the simulator, its Table 4, and
evidence for the daemon's defaults (window length, normalisation, thresholds).

    plan = StudyPlan.default()                           # or StudyPlan.quick()
    result = run_study(plan, settings, geometry)         # simulate, then the detection core per window
    table = identify(result)                             # Table 4 under the rule below
    write_report(result, "docs/study", command="bogiemon study -o docs/study")

THE MATRIX. For each load (full, tare): the healthy wagon and every fault case of the paper's
tables (Type A by spring position and severity, Type B by severity; the shipped verbatim copy of
../shared/paper/y25_fault_cases.toml), the fault on one corner of the monitored bogie
(leading-left, the corner of sensor a1, by default), at each speed and track quality of the plan,
several runs each (independent track realisations). Each run's seed is the CRC-32 of its name
(load, case, severity, speed, track, run number), so the quick plan's runs are the same runs as the
default plan's at its condition and every run is reproducible alone. Each signal is simulated
once and analysed for every window length (analysis is cheap, simulation is not).

THE IDENTIFICATION RULE, fixed before any result was looked at (not to be tuned to the paper):
for one load, speed, track and window length, the healthy reference is every window of the
healthy runs, with, per indicator, its median m and the 99th percentile h of the deviation
|x - m|. A window is flagged when |x - m| > h. A severity's detection share is the share of its
windows that are flagged, pooled over the plan's speeds and tracks (each window judged against the
reference of its own speed and track). A fault case (a row of Table 4) is IDENTIFIED by an
indicator when the detection share is at least RULE_MIN_SHARE = 0.5 for EVERY severity of the
case: the median faulty window lies beyond the healthy 1 % tail. The rule's per-window
false-alarm rate is 1 % in-sample by construction; out of sample (two-fold over the healthy runs:
the reference from the even-numbered runs judges the odd-numbered ones, and back) it must stay at
or below RULE_MAX_FALSE_ALARM = 3 %.

THE DEFAULTS RULES. Thresholds: daemon/calibrate.py's rule (warning and alarm at per-window
false-alarm targets 1e-2 and 1e-4, robust sigma and empirical terms; reimplemented here because
the simulator does not import the daemon, and checked against it by a test), applied per load to
all healthy windows pooled over speeds and tracks (the daemon knows the load, not the speed or
the track): the matrix's, and the envelope's (healthy runs at 40 and 120 km/h, the rest of the
speeds the daemon judges). The envelope was added after the first full run, in which thresholds
from the matrix's speeds alone confirmed alarms on healthy runs at 40 km/h; the report shows
that comparison on every run. Indicators per load: forward selection on the per-window alarm-level
detection share over all fault windows of the load: start with the best indicator, add the next
best while it raises the share of windows in which any selected indicator reaches its alarm
level by at least SELECTION_MIN_GAIN (2 points), at most SELECTION_MAX_INDICATORS (3). Window
length: the one with the highest combined share, averaged over the loads; a shorter window
within WINDOW_TIE (2 points) of the best wins (quicker confirmation, less speed change inside a
window); a window length is eligible only if no healthy run of the study (matrix or envelope)
confirms an alarm (confirm_k of confirm_n windows at alarm level) and every full-load
broken-outer-spring run of the matrix does.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import os
import time
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.scenario import Scenario, SpeedProfile
from bogiemon.simulator.sensors import SensorModel
from bogiemon.simulator.suspension import Fault

Progress = Callable[[float], None]  # called with the fraction done, 0..1

INDICATORS: tuple[str, ...] = ("i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm")
LABELS: dict[str, str] = dict(zip(INDICATORS, ("I1", "I2", "I3", "I4", "I1n", "I2n", "I3n", "I4n"), strict=True))
PAPER_INDICATORS: tuple[str, ...] = INDICATORS[:4]  # Table 4's columns 1..4
RAW, NORMALISED = INDICATORS[:4], INDICATORS[4:]
HEALTHY = "healthy"
ENVELOPE = "envelope"  # the group of healthy runs at the speeds of the envelope outside the matrix
# The healthy runs the daemon's thresholds are derived from: the matrix's and the envelope's.
THRESHOLD_GROUPS: frozenset[str] = frozenset({"", ENVELOPE})
HEALTHY_SEVERITY = 1.0

# The identification rule (module docstring).
RULE_QUANTILE = 0.99
RULE_MIN_SHARE = 0.5
RULE_MAX_FALSE_ALARM = 0.03

# The defaults rules (module docstring); the threshold rule's constants are daemon/calibrate.py's.
WARNING_RATE = 1e-2
ALARM_RATE = 1e-4
ALARM_MARGIN = 1.1
SELECTION_MIN_GAIN = 0.02
SELECTION_MAX_INDICATORS = 3
WINDOW_TIE = 0.02

# Measured on the 2-core development machine: simulated seconds per wall second of the batch
# kernel and of one IndicatorStream; only used to weigh the progress fraction.
_SIM_RATE = 2500.0
_ANALYSIS_RATE = 4500.0


# --------------------------------------------------------------------------------------------
# The plan


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

    def runs(self) -> tuple[RunSpec, ...]:
        """Every run of the plan: the main matrix, the sensitivities, then the envelope."""
        rows = table4_cases()
        out: list[RunSpec] = []
        for load in self.loads:
            for cond in self.conditions:
                out += [RunSpec("", FaultCase(HEALTHY, load), cond, r, self.fault_corner) for r in range(self.healthy_runs)]
                for key, severities in rows.items():
                    if key.split(".")[1] != load:
                        continue
                    for sev in severities:
                        out += [RunSpec("", FaultCase(key, load, sev), cond, r, self.fault_corner) for r in range(self.fault_runs)]
        for sens in self.sensitivities:
            assert self.sensitivity_condition is not None
            cond, corner = self.sensitivity_condition, sens.fault_corner or self.fault_corner
            loads = [load for load in self.loads if any(k.split(".")[1] == load for k in sens.case_keys)]
            if sens.own_healthy:
                for load in loads:
                    out += [
                        RunSpec(sens.name, FaultCase(HEALTHY, load), cond, r, corner, sens.stick_stiffness_n_per_m)
                        for r in range(self.sensitivity_healthy_runs)
                    ]
            for key in sens.case_keys:
                if key.split(".")[1] not in self.loads:
                    continue
                for sev in sens.severities or rows[key]:
                    out += [
                        RunSpec(sens.name, FaultCase(key, key.split(".")[1], sev), cond, r, corner, sens.stick_stiffness_n_per_m)
                        for r in range(self.fault_runs)
                    ]
        for load in self.loads:
            for cond in self.envelope_conditions:
                out += [RunSpec(ENVELOPE, FaultCase(HEALTHY, load), cond, r, self.fault_corner) for r in range(self.envelope_runs)]
        return tuple(out)


@dataclass(frozen=True)
class RunSpec:
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


# --------------------------------------------------------------------------------------------
# Running it


@dataclass(frozen=True)
class WindowTable:
    """Every window of the study at one window length: its run, its place in the run, its indicators."""

    run: NDArray[np.int64]  # index into StudyResult.runs
    position: NDArray[np.int64]  # 0, 1, ... in hop order within the run
    values: NDArray[np.float64]  # (n, 8), columns in INDICATORS order
    excitation_mps2: NDArray[np.float64]  # median of the three channels' RMS: the daemon's excitation gate


@dataclass(frozen=True)
class StudyResult:
    """Every run of a plan and every window's indicators; the analyses below take it as it is."""

    plan: StudyPlan
    settings: ProcessingSettings  # the default settings (the config's); window lengths vary
    geometry: BogieGeometry
    runs: tuple[RunSpec, ...]
    windows: Mapping[float, WindowTable]  # window_s -> windows
    simulated_s: float
    elapsed_s: float
    cpu_count: int

    @property
    def default_window_s(self) -> float:
        return self.settings.window_s

    @property
    def min_excitation_rms_mps2(self) -> float:
        """The main matrix's smallest median channel RMS of any window (the daemon gates below 0.3)."""
        table = self.windows[self.default_window_s]
        return float(table.excitation_mps2[self.run_mask(group="")[table.run]].min())

    def run_mask(self, **where: Any) -> NDArray[np.bool_]:
        """Runs matching every given attribute: group, load, key, severity, condition, rep (a set or a value)."""
        mask = np.ones(len(self.runs), dtype=bool)
        for name, wanted in where.items():
            accepted = wanted if isinstance(wanted, set | frozenset) else {wanted}
            mask &= np.array([_run_attribute(r, name) in accepted for r in self.runs])
        return mask

    def values(self, window_s: float, **where: Any) -> NDArray[np.float64]:
        """(n, 8): the indicators of every window of the matching runs at one window length."""
        table = self.windows[window_s]
        return table.values[self.run_mask(**where)[table.run]]


def _run_attribute(run: RunSpec, name: str) -> Any:
    if name in ("load", "key", "severity"):
        return getattr(run.case, name)
    if name == "parity":
        return run.rep % 2
    return getattr(run, name)


def window_settings(plan: StudyPlan, settings: ProcessingSettings) -> dict[float, ProcessingSettings]:
    """The processing settings of every window length the plan analyses (the plan's and the
    settings' own). Raises ValueError for one that does not fit the hop, the lags or the runs."""
    out = {}
    for w in sorted({*plan.window_lengths_s, settings.window_s}):
        s = dataclasses.replace(settings, window_s=w)
        if s.window_n % s.hop_n or s.max_lag_n >= s.window_n:
            raise ValueError(f"window {w:g} s must be a whole number of hops ({s.hop_s:g} s) and longer than the lags ({s.max_lag_s:g} s)")
        if w >= plan.duration_s:
            raise ValueError(f"window {w:g} s must be shorter than the runs ({plan.duration_s:g} s)")
        out[w] = s
    return out


def run_study(
    plan: StudyPlan,
    settings: ProcessingSettings,
    geometry: BogieGeometry,
    progress: Progress | None = None,
    batch_size: int = 24,
) -> StudyResult:
    """Simulate every run of the plan and compute every window's indicators with the detection core.

    `settings` are the processing settings of the report (the config's); the main matrix's and the
    envelope's runs are also analysed at each of the plan's window lengths (hop and everything
    else unchanged), the sensitivity runs at settings.window_s only. Raises ValueError for a
    window length that does not fit the hop, the lags or the runs.
    """
    from bogiemon.simulator.run import simulate_batch  # the numba kernel: only when running

    per_window = window_settings(plan, settings)
    windows_s = sorted(per_window)
    runs = plan.runs()
    names = [r.name + "|" + r.group + "|" + r.corner.value for r in runs]
    assert len(set(names)) == len(names), "two runs of the plan are the same run"

    def analysed(run: RunSpec) -> list[float]:
        return windows_s if run.group in THRESHOLD_GROUPS else [settings.window_s]

    cost = [plan.duration_s * (1 / _SIM_RATE + len(analysed(r)) / _ANALYSIS_RATE) for r in runs]
    total_cost, done_cost = sum(cost), 0.0
    rows: dict[float, tuple[list[int], list[int], list[NDArray[np.float64]], list[float]]] = {w: ([], [], [], []) for w in windows_s}
    started = time.perf_counter()
    for first in range(0, len(runs), batch_size):
        batch = range(first, min(first + batch_size, len(runs)))
        sim_share = sum(plan.duration_s / _SIM_RATE for _ in batch) / total_cost

        def report(fraction: float, base: float = done_cost / total_cost, share: float = sim_share) -> None:
            if progress is not None:
                progress(min(1.0, base + share * fraction))

        scenarios = [runs[i].scenario(plan.duration_s, settings.fs_hz, geometry, plan.noise_mps2) for i in batch]
        results = simulate_batch(scenarios, report)
        done_cost += sim_share * total_cost
        for i, result in zip(batch, results, strict=True):
            for w in analysed(runs[i]):
                found = IndicatorStream(per_window[w], geometry).process(result.accel_mps2)
                run_ids, positions, values, excitation = rows[w]
                run_ids += [i] * len(found)
                positions += range(len(found))
                values.append(np.array([[getattr(x, n) for n in INDICATORS] for x in found]))
                excitation += [float(np.median(x.rms_mps2)) for x in found]
            done_cost += cost[i] - plan.duration_s / _SIM_RATE
            if progress is not None:
                progress(min(1.0, done_cost / total_cost))
    tables = {
        w: WindowTable(np.array(r, dtype=np.int64), np.array(p, dtype=np.int64), np.concatenate(v), np.array(e))
        for w, (r, p, v, e) in rows.items()
    }
    return StudyResult(
        plan=plan,
        settings=settings,
        geometry=geometry,
        runs=runs,
        windows=tables,
        simulated_s=plan.duration_s * len(runs),
        elapsed_s=time.perf_counter() - started,
        cpu_count=os.cpu_count() or 1,
    )


# --------------------------------------------------------------------------------------------
# The identification rule


@dataclass(frozen=True)
class Reference:
    """The healthy windows of one load, speed, track and window length, per indicator."""

    center: NDArray[np.float64]  # median
    limit: NDArray[np.float64]  # RULE_QUANTILE of |x - center|
    n_windows: int

    @classmethod
    def of(cls, healthy: NDArray[np.float64]) -> Reference:
        if len(healthy) == 0:
            raise ValueError("no healthy windows to form a reference")
        center = np.median(healthy, axis=0)
        return cls(center, np.quantile(np.abs(healthy - center), RULE_QUANTILE, axis=0), len(healthy))

    def flags(self, values: NDArray[np.float64]) -> NDArray[np.bool_]:
        return np.abs(values - self.center) > self.limit


def roc_auc(faulty: NDArray[np.float64], healthy: NDArray[np.float64]) -> float:
    """P(a faulty deviation exceeds a healthy one), ties counted half (Mann-Whitney U / (n m))."""
    ranks = stats.rankdata(np.concatenate([faulty, healthy]))
    n_f, n_h = len(faulty), len(healthy)
    return float((ranks[:n_f].sum() - n_f * (n_f + 1) / 2) / (n_f * n_h))


@dataclass(frozen=True)
class SeverityEvidence:
    """One severity of one case: what the rule saw, per indicator (arrays in INDICATORS order)."""

    severity: float
    n_windows: int
    n_runs: int
    detection_share: NDArray[np.float64]  # pooled over the conditions
    share_per_condition: dict[str, NDArray[np.float64]]
    auc: NDArray[np.float64]  # of |x - m|, faulty against healthy, mean over the conditions
    median_shift: NDArray[np.float64]  # median faulty minus healthy median, mean over the conditions


@dataclass(frozen=True)
class CaseEvidence:
    """One row of Table 4: every severity's evidence, and the rule's verdict per indicator."""

    key: str
    severities: tuple[SeverityEvidence, ...]

    @property
    def min_share(self) -> NDArray[np.float64]:
        return np.min([s.detection_share for s in self.severities], axis=0)

    @property
    def identified(self) -> NDArray[np.bool_]:
        return self.min_share >= RULE_MIN_SHARE


def _conditions(result: StudyResult, group: str) -> tuple[Condition, ...]:
    if group == "":
        return result.plan.conditions
    assert result.plan.sensitivity_condition is not None
    return (result.plan.sensitivity_condition,)


def _healthy_group(result: StudyResult, group: str) -> str:
    sens = {s.name: s for s in result.plan.sensitivities}
    return group if group == "" or sens[group].own_healthy else ""


def identify(result: StudyResult, window_s: float | None = None, group: str = "") -> dict[str, CaseEvidence]:
    """Table 4 under the rule (module docstring): the evidence for every case the group ran."""
    w = result.default_window_s if window_s is None else window_s
    conditions = _conditions(result, group)
    healthy_group = _healthy_group(result, group)
    present = {(r.case.key, r.case.severity) for r in result.runs if r.group == group and r.case.key != HEALTHY}
    refs = {
        (load, c): Reference.of(result.values(w, group=healthy_group, key=HEALTHY, load=load, condition=c))
        for load in {k.split(".")[1] for k, _ in present}
        for c in conditions
    }
    out: dict[str, CaseEvidence] = {}
    for key in table4_cases():
        severities = sorted(s for k, s in present if k == key)
        if not severities:
            continue
        load = key.split(".")[1]
        evidence = []
        for sev in severities:
            flagged, n = np.zeros(len(INDICATORS)), 0
            per_condition: dict[str, NDArray[np.float64]] = {}
            aucs: list[list[float]] = []
            shifts: list[NDArray[np.float64]] = []
            for c in conditions:
                ref = refs[(load, c)]
                healthy = result.values(w, group=healthy_group, key=HEALTHY, load=load, condition=c)
                faulty = result.values(w, group=group, key=key, severity=sev, condition=c)
                f = ref.flags(faulty)
                flagged += f.sum(axis=0)
                n += len(faulty)
                per_condition[c.label] = f.mean(axis=0)
                d_f, d_h = np.abs(faulty - ref.center), np.abs(healthy - ref.center)
                aucs.append([roc_auc(d_f[:, j], d_h[:, j]) for j in range(len(INDICATORS))])
                shifts.append(np.median(faulty, axis=0) - ref.center)
            n_runs = int(result.run_mask(group=group, key=key, severity=sev).sum())
            evidence.append(
                SeverityEvidence(sev, n, n_runs, flagged / n, per_condition, np.mean(aucs, axis=0), np.mean(shifts, axis=0))
            )
        out[key] = CaseEvidence(key, tuple(evidence))
    return out


def rule_false_alarm(result: StudyResult, window_s: float | None = None, group: str = "") -> dict[str, NDArray[np.float64]]:
    """Per load, the rule's out-of-sample per-window false-alarm rate per indicator (two-fold over
    the healthy runs by the parity of their number), pooled over the conditions."""
    w = result.default_window_s if window_s is None else window_s
    group = _healthy_group(result, group)
    out = {}
    for load in sorted({r.case.load for r in result.runs if r.group == group and r.case.key == HEALTHY}):
        flagged, n = np.zeros(len(INDICATORS)), 0
        for c in _conditions(result, group):
            for parity in (0, 1):
                ref = Reference.of(result.values(w, group=group, key=HEALTHY, load=load, condition=c, parity=parity))
                judged = result.values(w, group=group, key=HEALTHY, load=load, condition=c, parity=1 - parity)
                flagged += ref.flags(judged).sum(axis=0)
                n += len(judged)
        out[load] = flagged / n
    return out


def rule_detection_rate(result: StudyResult, window_s: float | None = None) -> dict[str, NDArray[np.float64]]:
    """Per load, the share of ALL fault windows of the main matrix that the rule flags, per indicator."""
    w = result.default_window_s if window_s is None else window_s
    out = {}
    for load in result.plan.loads:
        flagged, n = np.zeros(len(INDICATORS)), 0
        for c in result.plan.conditions:
            ref = Reference.of(result.values(w, group="", key=HEALTHY, load=load, condition=c))
            faulty_keys = {k for k in table4_cases() if k.split(".")[1] == load}
            f = ref.flags(result.values(w, group="", key=faulty_keys, condition=c))
            flagged += f.sum(axis=0)
            n += len(f)
        out[load] = flagged / n
    return out


# --------------------------------------------------------------------------------------------
# Thresholds and the confirmation: the evidence for the defaults


@dataclass(frozen=True)
class ThresholdEstimate:
    """daemon/calibrate.py's thresholds for one indicator, from healthy windows."""

    center: float
    warning: float
    alarm: float
    robust_sigma: float
    max_deviation: float
    n_windows: int


def calibrate_thresholds(values: NDArray[np.float64], warning_rate: float = WARNING_RATE, alarm_rate: float = ALARM_RATE) -> ThresholdEstimate:
    """The same rule as daemon/calibrate.py (a test checks they agree), for one indicator:

        warning = max(z(p_warning) * sigma, the (1 - p_warning) quantile of |d|)
        alarm   = max(z(p_alarm) * sigma, 1.1 * the largest |d| seen, warning)

    with d = x - median and sigma = 1.4826 * MAD.
    """
    x = np.asarray(values, dtype=np.float64)
    median = float(np.median(x))
    deviation = np.abs(x - median)
    sigma = 1.4826 * float(np.median(deviation))
    largest = float(deviation.max())
    z_warning = float(stats.norm.isf(warning_rate / 2))
    z_alarm = float(stats.norm.isf(alarm_rate / 2))
    warning = max(z_warning * sigma, float(np.quantile(deviation, 1 - warning_rate)), np.finfo(float).tiny)
    alarm = max(z_alarm * sigma, ALARM_MARGIN * largest, warning)
    return ThresholdEstimate(median, warning, alarm, sigma, largest, len(x))


def first_confirmation(alarm: NDArray[np.bool_], confirm_k: int, confirm_n: int) -> int | None:
    """The index of the first window at which confirm_k of the last confirm_n windows (fewer at the
    start, as the daemon's history fills) are alarms; None if never."""
    counts = np.cumsum(np.asarray(alarm, dtype=np.int64))
    lagged = np.concatenate([np.zeros(confirm_n, dtype=np.int64), counts])[: len(counts)]
    hits = np.flatnonzero(counts - lagged >= confirm_k)
    return int(hits[0]) if hits.size else None


class Levels(Protocol):
    """Threshold levels on |value - center| (daemon.decision.Threshold, ThresholdEstimate, ...)."""

    center: float
    warning: float
    alarm: float


@dataclass(frozen=True)
class ThresholdCheck:
    """What one set of thresholds does at one load and window length: to the healthy runs of some
    groups, and to the main matrix's fault runs; alarm and warning windows, and the daemon's k-of-n
    confirmation, run by run."""

    load: str
    window_s: float
    indicators: tuple[str, ...]
    fault_alarm_share: float  # fault windows (every case, severity, speed, track) with any indicator at alarm
    healthy_windows: int  # judged (at or above the excitation gate)
    healthy_windows_total: int
    healthy_alarm_windows: int
    healthy_warning_windows: int
    healthy_runs: int
    healthy_confirmed_runs: int
    healthy_confirmed_by_condition: dict[str, int]  # only the conditions with a confirmed run
    broken_outer_runs: int  # full load only: front or rear outer coil broken (severity 0)
    broken_outer_confirmed_runs: int
    broken_outer_median_confirm_s: float  # end of the confirming window from the run's start
    confirmed_share_per_case: dict[str, float]  # 'key@severity' -> share of its runs confirmed


def _windows_by_run(
    result: StudyResult, window_s: float, mask_runs: NDArray[np.bool_], min_excitation_rms_mps2: float = 0.0
) -> dict[int, NDArray[np.float64]]:
    """Each matching run's windows in time order; windows the daemon would gate for weak excitation
    are left out (they are not judged and do not enter the k-of-n history)."""
    table = result.windows[window_s]
    keep = mask_runs[table.run] & (table.excitation_mps2 >= min_excitation_rms_mps2)
    runs, positions, values = table.run[keep], table.position[keep], table.values[keep]
    out: dict[int, NDArray[np.float64]] = {}
    for r in np.unique(runs):
        sel = runs == r
        out[int(r)] = values[sel][np.argsort(positions[sel])]
    return out


def _alarm(values: NDArray[np.float64], thresholds: Mapping[str, Levels], level: str = "alarm") -> NDArray[np.bool_]:
    """Windows with any of the thresholded indicators at `level` or above (the daemon's >=)."""
    hits = [np.abs(values[:, INDICATORS.index(n)] - t.center) >= getattr(t, level) for n, t in thresholds.items()]
    return np.any(hits, axis=0) if hits else np.zeros(len(values), dtype=bool)


def _confirmations(
    result: StudyResult,
    window_s: float,
    mask: NDArray[np.bool_],
    thresholds: Mapping[str, Levels],
    confirm_k: int,
    confirm_n: int,
    min_excitation_rms_mps2: float = 0.0,
) -> dict[int, int | None]:
    """Per run: the index (among its judged windows) of the window that confirms, None if none does."""
    return {
        run: first_confirmation(_alarm(v, thresholds), confirm_k, confirm_n)
        for run, v in _windows_by_run(result, window_s, mask, min_excitation_rms_mps2).items()
    }


def _judged(result: StudyResult, window_s: float, min_excitation_rms_mps2: float, **where: Any) -> NDArray[np.float64]:
    table = result.windows[window_s]
    keep = result.run_mask(**where)[table.run] & (table.excitation_mps2 >= min_excitation_rms_mps2)
    return table.values[keep]


def check_thresholds(
    result: StudyResult,
    load: str,
    window_s: float,
    thresholds: Mapping[str, Levels],
    confirm_k: int = 3,
    confirm_n: int = 5,
    healthy_groups: frozenset[str] = THRESHOLD_GROUPS,
    min_excitation_rms_mps2: float = 0.3,
) -> ThresholdCheck:
    """Judge the healthy runs of `healthy_groups` and the main matrix's fault runs of `load` with
    `thresholds` as the daemon would: windows below its excitation gate are not judged, the others
    advance a k-of-n history per run."""
    gate, groups = min_excitation_rms_mps2, set(healthy_groups)
    faulty_keys = {r.case.key for r in result.runs if r.group == "" and r.case.load == load and r.case.key != HEALTHY}
    healthy = _judged(result, window_s, gate, group=groups, key=HEALTHY, load=load)
    faulty = _judged(result, window_s, gate, group="", key=faulty_keys)
    healthy_mask = result.run_mask(group=groups, key=HEALTHY, load=load)
    healthy_confirm = _confirmations(result, window_s, healthy_mask, thresholds, confirm_k, confirm_n, gate)
    by_condition: dict[str, int] = {}
    for run, found in healthy_confirm.items():
        if found is not None:
            label = result.runs[run].condition.label
            by_condition[label] = by_condition.get(label, 0) + 1
    per_case: dict[str, float] = {}
    for key in sorted(faulty_keys):
        for sev in sorted({r.case.severity for r in result.runs if r.group == "" and r.case.key == key}):
            mask = result.run_mask(group="", key=key, severity=sev)
            found = list(_confirmations(result, window_s, mask, thresholds, confirm_k, confirm_n, gate).values())
            per_case[f"{key}@{sev:g}"] = sum(c is not None for c in found) / len(found)
    broken_keys = {"type_a.full.front_outer", "type_a.full.rear_outer"} & faulty_keys
    broken_mask = result.run_mask(group="", key=broken_keys, severity=0.0)
    broken = list(_confirmations(result, window_s, broken_mask, thresholds, confirm_k, confirm_n, gate).values()) if broken_keys else []
    # The matrix's windows are all above the gate (StudyResult.min_excitation_rms_mps2), so the
    # confirming window's index among the judged ones gives its end time.
    confirm_s = [window_s + c * result.settings.hop_s for c in broken if c is not None]
    table = result.windows[window_s]
    return ThresholdCheck(
        load=load,
        window_s=window_s,
        indicators=tuple(thresholds),
        fault_alarm_share=float(_alarm(faulty, thresholds).mean()) if len(faulty) else math.nan,
        healthy_windows=len(healthy),
        healthy_windows_total=int(healthy_mask[table.run].sum()),
        healthy_alarm_windows=int(_alarm(healthy, thresholds).sum()),
        healthy_warning_windows=int(_alarm(healthy, thresholds, "warning").sum()),
        healthy_runs=len(healthy_confirm),
        healthy_confirmed_runs=sum(c is not None for c in healthy_confirm.values()),
        healthy_confirmed_by_condition=by_condition,
        broken_outer_runs=len(broken),
        broken_outer_confirmed_runs=sum(c is not None for c in broken),
        broken_outer_median_confirm_s=float(np.median(confirm_s)) if confirm_s else math.nan,
        confirmed_share_per_case=per_case,
    )


def gated_share(result: StudyResult, group: str, window_s: float, min_excitation_rms_mps2: float, **where: Any) -> float:
    """The share of a group's windows the daemon would not judge (weak excitation)."""
    table = result.windows[window_s]
    sel = result.run_mask(group=group, **where)[table.run]
    return float(np.mean(table.excitation_mps2[sel] < min_excitation_rms_mps2)) if sel.any() else math.nan


@dataclass(frozen=True)
class DecisionEvidence:
    """Indicators selected among candidates at one load and window length, their calibrated
    thresholds, and what they do."""

    load: str
    window_s: float
    indicators: tuple[str, ...]
    thresholds: dict[str, ThresholdEstimate]
    per_indicator_share: dict[str, float]  # each candidate alone, at its own thresholds
    check: ThresholdCheck
    held_out_alarm_windows: int  # thresholds from half the healthy runs, judged on the other half
    held_out_confirmed_runs: int
    held_out_confirmed_by_condition: dict[str, int]


def decision_evidence(
    result: StudyResult,
    load: str,
    window_s: float,
    candidates: Sequence[str] = INDICATORS,
    confirm_k: int = 3,
    confirm_n: int = 5,
    min_excitation_rms_mps2: float = 0.3,
    healthy_groups: frozenset[str] = THRESHOLD_GROUPS,
) -> DecisionEvidence:
    """Thresholds from the load's healthy windows (all speeds and tracks of `healthy_groups`),
    forward selection of the indicators among `candidates` (module docstring), and the k-of-n
    confirmation they give (on the healthy runs of THRESHOLD_GROUPS, whatever they came from)."""
    gate, groups = min_excitation_rms_mps2, set(healthy_groups)
    faulty_keys = {k for k in table4_cases() if k.split(".")[1] == load}
    healthy = _judged(result, window_s, gate, group=groups, key=HEALTHY, load=load)
    faulty = _judged(result, window_s, gate, group="", key=faulty_keys)
    thresholds = {n: calibrate_thresholds(healthy[:, INDICATORS.index(n)]) for n in INDICATORS}

    def share(names: Sequence[str]) -> float:
        return float(_alarm(faulty, {n: thresholds[n] for n in names}).mean())

    per_indicator = {n: share([n]) for n in candidates}
    chosen: list[str] = [max(candidates, key=lambda n: per_indicator[n])]
    while len(chosen) < SELECTION_MAX_INDICATORS:
        rest = [n for n in candidates if n not in chosen]
        if not rest:
            break
        best = max(rest, key=lambda n: share([*chosen, n]))
        if share([*chosen, best]) - share(chosen) < SELECTION_MIN_GAIN:
            break
        chosen.append(best)
    selected = {n: thresholds[n] for n in chosen}
    held_out_alarms = 0
    held_out_by_condition: dict[str, int] = {}
    for parity in (0, 1):
        fit = _judged(result, window_s, gate, group=groups, key=HEALTHY, load=load, parity=parity)
        refit = {n: calibrate_thresholds(fit[:, INDICATORS.index(n)]) for n in chosen}
        judged = result.run_mask(group=groups, key=HEALTHY, load=load, parity=1 - parity)
        held_out_alarms += int(_alarm(_judged(result, window_s, gate, group=groups, key=HEALTHY, load=load, parity=1 - parity), refit).sum())
        for run, found in _confirmations(result, window_s, judged, refit, confirm_k, confirm_n, gate).items():
            if found is not None:
                label = result.runs[run].condition.label
                held_out_by_condition[label] = held_out_by_condition.get(label, 0) + 1
    return DecisionEvidence(
        load=load,
        window_s=window_s,
        indicators=tuple(chosen),
        thresholds=selected,
        per_indicator_share=per_indicator,
        check=check_thresholds(result, load, window_s, selected, confirm_k, confirm_n, min_excitation_rms_mps2=gate),
        held_out_alarm_windows=held_out_alarms,
        held_out_confirmed_runs=sum(held_out_by_condition.values()),
        held_out_confirmed_by_condition=held_out_by_condition,
    )


@dataclass(frozen=True)
class DefaultsEvidence:
    """Every window length x candidate set (raw, normalised, all) x load, and the choice."""

    table: dict[tuple[float, str, str], DecisionEvidence]  # (window_s, candidate set, load) -> evidence
    eligible: dict[float, bool]
    chosen_window_s: float
    chosen: dict[str, DecisionEvidence]  # load -> the defaults
    confirm_k: int
    confirm_n: int


CANDIDATE_SETS: dict[str, tuple[str, ...]] = {"raw": RAW, "normalised": NORMALISED, "all": INDICATORS}


def defaults_evidence(result: StudyResult, confirm_k: int = 3, confirm_n: int = 5, min_excitation_rms_mps2: float = 0.3) -> DefaultsEvidence:
    """The defaults rules of the module docstring over the plan's window lengths."""
    table = {
        (w, name, load): decision_evidence(result, load, w, cands, confirm_k, confirm_n, min_excitation_rms_mps2)
        for w in result.plan.window_lengths_s
        for name, cands in CANDIDATE_SETS.items()
        for load in result.plan.loads
    }

    def ok(e: DecisionEvidence) -> bool:
        return e.check.healthy_confirmed_runs == 0 and e.check.broken_outer_confirmed_runs == e.check.broken_outer_runs

    eligible = {w: all(ok(table[(w, "all", load)]) for load in result.plan.loads) for w in result.plan.window_lengths_s}
    score = {w: float(np.mean([table[(w, "all", load)].check.fault_alarm_share for load in result.plan.loads])) for w in eligible}
    candidates = [w for w in sorted(eligible) if eligible[w]] or sorted(eligible)
    best = max(score[w] for w in candidates)
    chosen_w = min(w for w in candidates if score[w] >= best - WINDOW_TIE)
    chosen = {load: table[(chosen_w, "all", load)] for load in result.plan.loads}
    return DefaultsEvidence(table, eligible, chosen_w, chosen, confirm_k, confirm_n)


# --------------------------------------------------------------------------------------------
# Per-run means, for the figures


def run_means(result: StudyResult, window_s: float | None = None, **where: Any) -> NDArray[np.float64]:
    """(runs, 8): each matching run's mean over its windows."""
    w = result.default_window_s if window_s is None else window_s
    by_run = _windows_by_run(result, w, result.run_mask(**where))
    return np.array([v.mean(axis=0) for v in by_run.values()]) if by_run else np.empty((0, len(INDICATORS)))


# --------------------------------------------------------------------------------------------
# The report: README.md, defaults.md, table4.json and the figures


DISCUSSION_FILE = "discussion.md"  # hand-written, beside the report; included verbatim when present
FIGURES = (
    ("fig3_full_rear_outer.png", "type_a.full.rear_outer", "rear outer coil, full load (cf. the paper's Fig. 3)"),
    ("fig4_tare_rear_outer.png", "type_a.tare.rear_outer", "rear outer coil, tare (cf. the paper's Fig. 4)"),
    ("fig5_full_type_b.png", "type_b.full", "friction damper (Type B), full load (cf. the paper's Fig. 5)"),
)


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %" if math.isfinite(x) else "n/a"


def _tick(flag: bool) -> str:
    return "✓" if flag else "✗"


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _case_label(key: str) -> str:
    kind, load, *position = key.split(".")
    what = position[0].replace("_", " ") + " coil" if position else "friction damper"
    return f"{'A' if kind == 'type_a' else 'B'}, {load}, {what}"


def render_figures(result: StudyResult, out_dir: os.PathLike[str] | str) -> list[str]:
    """The paper-like figures: each indicator against severity, mean and spread over runs, one line
    per speed and track. Needs the `report` extra (matplotlib); draws headless."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pathlib import Path

    folder = Path(out_dir) / "figures"
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    rows = table4_cases()
    for name, key, title in FIGURES:
        if key not in rows or key.split(".")[1] not in result.plan.loads:
            continue
        load = key.split(".")[1]
        fig, axes = plt.subplots(2, 4, figsize=(16, 7.5), constrained_layout=True)
        for cond in result.plan.conditions:
            xs, means, spreads = [], [], []
            for sev in sorted({*rows[key], HEALTHY_SEVERITY}):
                where = {"key": HEALTHY, "load": load} if sev == HEALTHY_SEVERITY else {"key": key, "severity": sev}
                per_run = run_means(result, group="", condition=cond, **where)
                xs.append(sev)
                means.append(per_run.mean(axis=0))
                spreads.append(per_run.std(axis=0))
            m, s = np.array(means), np.array(spreads)
            for j, ind in enumerate(INDICATORS):
                axes.flat[j].errorbar(xs, m[:, j], yerr=s[:, j], marker="o", ms=4, capsize=3, lw=1.2, label=cond.label)
        for j, ind in enumerate(INDICATORS):
            ax = axes.flat[j]
            ax.axvline(HEALTHY_SEVERITY, color="0.7", lw=0.8, ls=":")
            ax.set(title=LABELS[ind], xlabel="severity (fraction of nominal; 1 = healthy)")
            ax.grid(alpha=0.3)
        axes.flat[0].set_ylabel("raw")
        axes.flat[4].set_ylabel("normalised")
        axes.flat[3].legend(fontsize=8)
        fig.suptitle(
            f"{title}: fault at {result.plan.fault_corner.value}, {result.default_window_s:g} s windows; "
            "mean over runs of each run's mean, bars +/- 1 std over runs (track realisations)"
        )
        fig.savefig(folder / name, dpi=90)
        plt.close(fig)
        written.append(f"figures/{name}")
    return written


def _plan_text(result: StudyResult) -> list[str]:
    plan = result.plan
    rows = {k: v for k, v in table4_cases().items() if k.split(".")[1] in plan.loads}
    n_fault_cells = sum(len(v) for v in rows.values())
    main = [r for r in result.runs if r.group == ""]
    lines = [
        "| what | value |",
        "|---|---|",
        f"| loads | {', '.join(plan.loads)} (carbody 80.6 t / 6.86 t, the paper's) |",
        f"| cases | healthy + {n_fault_cells} fault cells: {', '.join(f'{k} ({len(v)} severities)' for k, v in rows.items())} |",
        f"| fault corner | {plan.fault_corner.value} of the monitored (leading) bogie: the corner of sensor a1 |",
        f"| speeds and tracks | {'; '.join(c.label for c in plan.conditions)} |",
        f"| runs | {plan.healthy_runs} healthy runs per load and condition, {plan.fault_runs} per fault severity and condition; each an independent track realisation |",
        f"| run length | {plan.duration_s:g} s at {result.settings.fs_hz:g} Hz, after the simulator's pre-roll |",
        f"| sensors | the config's corners ({', '.join(c.value for c in result.geometry.corners)}), white noise {plan.noise_mps2:g} m/s^2 per sample (MEMS class) |",
        f"| processing | the config's: windows of {', '.join(f'{w:g}' for w in sorted(result.windows))} s (report at {result.default_window_s:g} s), hop {result.settings.hop_s:g} s, lags +/-{result.settings.max_lag_s:g} s, high-pass {result.settings.highpass_hz:g} Hz, I3's low-pass {result.settings.lowpass_hz:g} Hz |",
        f"| main matrix | {len(main)} runs, {len(main) * plan.duration_s / 3600:.1f} h of simulated running |",
    ]
    if plan.sensitivities:
        assert plan.sensitivity_condition is not None
        extra = sum(r.group not in THRESHOLD_GROUPS for r in result.runs)
        lines.append(
            f"| sensitivity | {extra} more runs at {plan.sensitivity_condition.label}: "
            + "; ".join(s.name for s in plan.sensitivities)
            + " |"
        )
    if plan.envelope_conditions:
        lines.append(
            f"| envelope | {plan.envelope_runs} healthy runs per load at each of "
            + "; ".join(c.label for c in plan.envelope_conditions)
            + ": the rest of the speeds the daemon judges, for its thresholds (not for Table 4) |"
        )
    return lines


def _rule_text() -> list[str]:
    return [
        "Stated before any result was looked at, and not changed after (it is the module docstring of",
        "`simulator/study.py`):",
        "",
        "- For one load, speed, track and window length, the **healthy reference** is every window of the",
        "  healthy runs: per indicator, the median m and the 99th percentile h of the deviation |x - m|.",
        "- A window is **flagged** when |x - m| > h (a per-window false-alarm rate of 1 % in-sample).",
        "- A severity's **detection share** is the share of its windows that are flagged, pooled over the",
        "  speeds and tracks of the matrix, each window against the reference of its own speed and track.",
        f"- A case (a row of Table 4) is **identified** by an indicator when the detection share is at least "
        f"**{RULE_MIN_SHARE:g}** for **every** severity of the case: the median faulty window lies beyond the",
        "  healthy 1 % tail.",
        f"- The rule's out-of-sample false-alarm rate (two-fold over the healthy runs: the reference from the "
        f"even-numbered runs judges the odd-numbered ones and back) must stay at or below **{RULE_MAX_FALSE_ALARM:.0%}**.",
        "",
        "The paper's Table 4 columns are the raw indicators I1..I4; the normalised I1n..I4n are judged by",
        "the same rule and shown beside them.",
    ]


def _evidence_json(case: CaseEvidence) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for j, ind in enumerate(INDICATORS):
        out[LABELS[ind]] = {
            "identified": bool(case.identified[j]),
            "min_detection_share": float(case.min_share[j]),
            "per_severity": {
                f"{s.severity:g}": {
                    "detection_share": float(s.detection_share[j]),
                    "auc": float(s.auc[j]),
                    "median_shift": float(s.median_shift[j]),
                    "n_windows": s.n_windows,
                    "n_runs": s.n_runs,
                    "share_per_condition": {c: float(v[j]) for c, v in s.share_per_condition.items()},
                }
                for s in case.severities
            },
        }
    return out


def ceil_significant(x: float, digits: int = 3) -> float:
    """x rounded up to `digits` significant digits (levels for the config: never below the rule's)."""
    if x <= 0 or not math.isfinite(x):
        return x
    scale = 10.0 ** (math.floor(math.log10(x)) - digits + 1)
    return float(f"{math.ceil(x / scale - 1e-9) * scale:.{digits}g}")


def _threshold_toml(chosen: Mapping[str, DecisionEvidence]) -> list[str]:
    lines = []
    for load, e in chosen.items():
        for name in e.indicators:
            t = e.thresholds[name]
            lines += [
                f"[decision.thresholds.{load}.{name}]",
                f"center = {t.center:.3g}",
                f"warning = {ceil_significant(t.warning):.3g}",
                f"alarm = {ceil_significant(t.alarm):.3g}",
                "",
            ]
    return lines


def write_report(
    result: StudyResult,
    out_dir: os.PathLike[str] | str,
    command: str = "bogiemon study -o docs/study",
    confirm_k: int = 3,
    confirm_n: int = 5,
    figures: bool = True,
    configured: Mapping[str, Mapping[str, Levels]] | None = None,
    min_excitation_rms_mps2: float = 0.3,
) -> dict[str, Any]:
    """Write README.md, defaults.md, table4.json (and the figures) into out_dir; returns the JSON.

    `configured`: the daemon's thresholds (load -> indicator -> levels) for windows of
    result.settings.window_s, checked on the study's runs beside the ones the study derives.
    """
    import json
    from pathlib import Path

    started = time.perf_counter()
    folder = Path(out_dir)
    folder.mkdir(parents=True, exist_ok=True)
    paper = {k: v for k, v in paper_table4().items() if k.split(".")[1] in result.plan.loads}
    ours = identify(result)
    false_alarm = rule_false_alarm(result)
    detection = rule_detection_rate(result)
    sens = {s.name: identify(result, group=s.name) for s in result.plan.sensitivities}
    sens_fa = {s.name: rule_false_alarm(result, group=s.name) for s in result.plan.sensitivities if s.own_healthy}
    gate = min_excitation_rms_mps2
    defaults = defaults_evidence(result, confirm_k, confirm_n, gate)
    configured_here = {load: configured[load] for load in result.plan.loads if configured and configured.get(load)}
    shipped = {
        load: check_thresholds(result, load, result.default_window_s, t, confirm_k, confirm_n, min_excitation_rms_mps2=gate)
        for load, t in configured_here.items()
    }
    # Why the envelope runs are in the thresholds' population: the same rule on the matrix's healthy
    # runs alone, judged on the envelope's healthy runs.
    matrix_only: dict[str, ThresholdCheck] = {}
    if any(r.group == ENVELOPE for r in result.runs):
        w = defaults.chosen_window_s
        for load, e in defaults.chosen.items():
            fit = _judged(result, w, gate, group="", key=HEALTHY, load=load)
            limits = {n: calibrate_thresholds(fit[:, INDICATORS.index(n)]) for n in e.indicators}
            matrix_only[load] = check_thresholds(result, load, w, limits, confirm_k, confirm_n, frozenset({ENVELOPE}), gate)
    written = render_figures(result, folder) if figures else []

    agreements = {k: [paper[k][j] == bool(ours[k].identified[j]) for j in range(4)] for k in paper if k in ours}
    n_agree = sum(sum(v) for v in agreements.values())
    n_cells = sum(len(v) for v in agreements.values())
    report_s = time.perf_counter() - started
    timing = {
        "study_s": round(result.elapsed_s, 1),
        "report_s": round(report_s, 1),
        "total_s": round(result.elapsed_s + report_s, 1),
        "simulated_s": result.simulated_s,
        "runs": len(result.runs),
        "cpu_count": result.cpu_count,
    }

    doc: dict[str, Any] = {
        "format": "bogiemon-study/1",
        "plan": result.plan.name,
        "command": command,
        "timing": timing,
        "rule": {
            "reference": "per load, speed, track and window length: median m and 99th percentile h of |x - m| over healthy windows",
            "flag": "|x - m| > h",
            "identified": f"detection share >= {RULE_MIN_SHARE} for every severity of the case, pooled over speeds and tracks",
            "quantile": RULE_QUANTILE,
            "min_share": RULE_MIN_SHARE,
            "max_false_alarm": RULE_MAX_FALSE_ALARM,
        },
        "settings": {
            "window_s": result.default_window_s,
            "hop_s": result.settings.hop_s,
            "max_lag_s": result.settings.max_lag_s,
            "fs_hz": result.settings.fs_hz,
            "fault_corner": result.plan.fault_corner.value,
            "conditions": [dataclasses.asdict(c) for c in result.plan.conditions],
            "duration_s": result.plan.duration_s,
            "healthy_runs": result.plan.healthy_runs,
            "fault_runs": result.plan.fault_runs,
            "noise_mps2": result.plan.noise_mps2,
            "stick_stiffness_n_per_m": float(default_parameter_set()["vehicle"]["primary"]["stick_stiffness_n_per_m"]),
        },
        "indicators": [LABELS[i] for i in PAPER_INDICATORS],
        "cases": {
            key: {
                "paper": list(paper[key]),
                "ours": [bool(ours[key].identified[j]) for j in range(4)],
                "agree": agreements[key],
                "severities": [s.severity for s in ours[key].severities],
                "indicators": _evidence_json(ours[key]),
            }
            for key in paper
            if key in ours
        },
        "agreement": {"cells": n_cells, "agree": n_agree},
        "rates": {
            load: {
                "rule_detection_per_window": {LABELS[i]: float(detection[load][j]) for j, i in enumerate(INDICATORS)},
                "rule_false_alarm_per_window_held_out": {LABELS[i]: float(false_alarm[load][j]) for j, i in enumerate(INDICATORS)},
            }
            for load in result.plan.loads
        },
        "sensitivity": {
            name: {
                key: {LABELS[i]: {"identified": bool(ev.identified[j]), "min_detection_share": float(ev.min_share[j])} for j, i in enumerate(INDICATORS)}
                for key, ev in cases.items()
            }
            for name, cases in sens.items()
        },
        "min_excitation_rms_mps2": result.min_excitation_rms_mps2,
    }
    if defaults is not None:
        doc["defaults"] = {
            "window_s": defaults.chosen_window_s,
            "confirm": f"{confirm_k} of {confirm_n}",
            "per_load": {load: _decision_json(e) for load, e in defaults.chosen.items()},
            "by_window_and_set": {
                f"{w:g}s/{name}/{load}": _decision_json(e) for (w, name, load), e in defaults.table.items()
            },
            "eligible_windows": {f"{w:g}": v for w, v in defaults.eligible.items()},
        }
        for load in result.plan.loads:
            e = defaults.chosen[load]
            doc["rates"][load]["defaults_alarm_detection_per_window"] = e.check.fault_alarm_share
            doc["rates"][load]["defaults_alarm_false_alarm_per_window"] = e.check.healthy_alarm_windows / e.check.healthy_windows
            doc["rates"][load]["defaults_held_out_alarm_false_alarm_per_window"] = e.held_out_alarm_windows / e.check.healthy_windows
    for load, c in shipped.items():
        doc["rates"][load]["configured_alarm_detection_per_window"] = c.fault_alarm_share
        doc["rates"][load]["configured_alarm_false_alarm_per_window"] = c.healthy_alarm_windows / c.healthy_windows
        doc["rates"][load]["configured_warning_false_alarm_per_window"] = c.healthy_warning_windows / c.healthy_windows
    doc["envelope"] = {
        "conditions": [dataclasses.asdict(c) for c in result.plan.envelope_conditions],
        "runs_per_load_and_condition": result.plan.envelope_runs,
        "gated_share": {load: gated_share(result, ENVELOPE, result.default_window_s, gate, load=load) for load in result.plan.loads},
        "matrix_only_thresholds_on_envelope_runs": {load: _check_json(c) for load, c in matrix_only.items()},
    }
    doc["configured_thresholds"] = {
        load: {
            "window_s": c.window_s,
            "thresholds": {n: {"center": t.center, "warning": t.warning, "alarm": t.alarm} for n, t in configured[load].items()},  # type: ignore[index]
            **_check_json(c),
        }
        for load, c in shipped.items()
    }
    (folder / "table4.json").write_text(json.dumps(doc, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")

    discussion_path = folder / DISCUSSION_FILE
    discussion = discussion_path.read_text(encoding="utf-8") if discussion_path.is_file() else None
    readme = _readme(result, paper, ours, agreements, false_alarm, detection, sens, sens_fa, defaults, shipped, gate, written, timing, command, discussion)
    (folder / "README.md").write_text(readme, encoding="utf-8")
    if defaults is not None:
        (folder / "defaults.md").write_text(_defaults_md(result, defaults, shipped, matrix_only, gate, timing, command, confirm_k, confirm_n), encoding="utf-8")
    return doc


def _check_json(c: ThresholdCheck) -> dict[str, Any]:
    return {
        "indicators": [LABELS[n] for n in c.indicators],
        "alarm_detection_share": c.fault_alarm_share,
        "healthy_windows": c.healthy_windows,
        "healthy_windows_total": c.healthy_windows_total,
        "healthy_alarm_windows": c.healthy_alarm_windows,
        "healthy_warning_windows": c.healthy_warning_windows,
        "healthy_runs": c.healthy_runs,
        "healthy_confirmed_runs": c.healthy_confirmed_runs,
        "healthy_confirmed_by_condition": c.healthy_confirmed_by_condition,
        "broken_outer_runs": c.broken_outer_runs,
        "broken_outer_confirmed_runs": c.broken_outer_confirmed_runs,
        "broken_outer_median_confirm_s": _json_float(c.broken_outer_median_confirm_s),
        "confirmed_share_per_case": c.confirmed_share_per_case,
    }


def _decision_json(e: DecisionEvidence) -> dict[str, Any]:
    return {
        **_check_json(e.check),
        "thresholds": {
            n: {"center": t.center, "warning": t.warning, "alarm": t.alarm, "robust_sigma": t.robust_sigma, "max_deviation": t.max_deviation}
            for n, t in e.thresholds.items()
        },
        "per_indicator_alarm_detection_share": {LABELS[n]: v for n, v in e.per_indicator_share.items()},
        "held_out_alarm_windows": e.held_out_alarm_windows,
        "held_out_confirmed_runs": e.held_out_confirmed_runs,
        "held_out_confirmed_by_condition": e.held_out_confirmed_by_condition,
    }


def _readme(
    result: StudyResult,
    paper: Mapping[str, tuple[bool, ...]],
    ours: Mapping[str, CaseEvidence],
    agreements: Mapping[str, list[bool]],
    false_alarm: Mapping[str, NDArray[np.float64]],
    detection: Mapping[str, NDArray[np.float64]],
    sens: Mapping[str, Mapping[str, CaseEvidence]],
    sens_fa: Mapping[str, Mapping[str, NDArray[np.float64]]],
    defaults: DefaultsEvidence,
    shipped: Mapping[str, ThresholdCheck],
    gate: float,
    figures: Sequence[str],
    timing: Mapping[str, Any],
    command: str,
    discussion: str | None,
) -> str:
    n_agree = sum(sum(v) for v in agreements.values())
    n_cells = sum(len(v) for v in agreements.values())
    stick = float(default_parameter_set()["vehicle"]["primary"]["stick_stiffness_n_per_m"])
    out = [
        "# The detection study: the paper's Table 4 on our simulator",
        "",
        "Generated by `simulator/study.py`; do not edit by hand (the discussion comes from "
        f"`{DISCUSSION_FILE}` beside this file). Regenerate with:",
        "",
        f"    {command}",
        "",
        f"This run ({result.plan.name} plan): **{timing['total_s'] / 60:.1f} min** wall time on a {timing['cpu_count']}-core "
        f"machine ({timing['study_s']:.0f} s simulating and analysing {timing['runs']} runs, "
        f"{timing['simulated_s'] / 3600:.1f} h of simulated running; {timing['report_s']:.0f} s for the evidence and figures). "
        "The same numbers, comparable by a program, are in [`table4.json`](table4.json); the evidence for the "
        "daemon's defaults is in [`defaults.md`](defaults.md).",
        "",
        f"**Every conclusion here holds for the simulator's Lenoir-damper stick stiffness of {stick / 1e6:g} MN/m** "
        "(not published for the Y25; docs/simulator.md shows the fault's effect on C_PR(0) growing "
        "from +0.04 to +0.60 between 2 and 50 MN/m). The sensitivity section below repeats the key cases "
        "at 10 and 50 MN/m.",
        "",
        "## The matrix",
        "",
        *_plan_text(result),
        "",
        "Why these: 60 and 100 km/h bracket a loaded Y25 wagon's service speeds (100 km/h is the loaded "
        "maximum of the S regime), ERRI low and high level are the two standard European irregularity spectra "
        "(a good main line and a poor one), and the fault sits at the corner of sensor a1, as in the "
        "simulator's documentation (the sensitivity section moves it to the other three corners). Runs are "
        "long enough to hold 19 windows of 120 s, and the many healthy runs give the 99th percentiles "
        "and the false-alarm counts their sample. The paper states none of these choices.",
        "",
        "## The rule",
        "",
        *_rule_text(),
        "",
        f"## (a) Table 4, the paper's beside ours: {n_agree} of {n_cells} cells agree",
        "",
        f"Each cell: paper / ours (✓ identified, ✗ not); **bold** where they disagree. Windows of {result.default_window_s:g} s.",
        "",
        "| case | I1 | I2 | I3 | I4 | agree |",
        "|---|---|---|---|---|---|",
    ]
    for key, agree in agreements.items():
        cells = []
        for j in range(4):
            text = f"{_tick(paper[key][j])} / {_tick(bool(ours[key].identified[j]))}"
            cells.append(text if agree[j] else f"**{text}**")
        out.append(f"| {key} ({_case_label(key)}) | {' | '.join(cells)} | {sum(agree)}/4 |")
    out += [
        "",
        "The numbers behind it: the smallest detection share over the case's severities (identified when "
        f">= {RULE_MIN_SHARE:g}), for the raw indicators (Table 4's) and the normalised ones.",
        "",
        "| case | " + " | ".join(LABELS[i] for i in INDICATORS) + " |",
        "|---|" + "---|" * len(INDICATORS),
    ]
    for key, ev in ours.items():
        cells = [f"**{ev.min_share[j]:.2f}**" if ev.identified[j] else f"{ev.min_share[j]:.2f}" for j in range(len(INDICATORS))]
        out.append(f"| {key} | {' | '.join(cells)} |")
    out += [
        "",
        "Per severity (detection share pooled over speeds and tracks; ROC AUC of the deviation, faulty "
        "against healthy, in `table4.json`):",
        "",
        "| case | severity | " + " | ".join(LABELS[i] for i in INDICATORS) + " |",
        "|---|---|" + "---|" * len(INDICATORS),
    ]
    for key, ev in ours.items():
        for s in ev.severities:
            out.append(f"| {key} | {s.severity:g} | " + " | ".join(f"{v:.2f}" for v in s.detection_share) + " |")
    out += ["", "## (b) Indicators against fault severity", ""]
    for (name, key, title), path in zip([f for f in FIGURES if f"figures/{f[0]}" in figures], figures, strict=True):
        out += [f"**{title}**", "", f"![{title}]({path})", ""]
    out += [
        "Each point: the mean over runs of each run's mean indicator; bars: +/- 1 standard deviation over "
        "runs (independent track realisations); severity 1 is the healthy wagon. I1, I2 in their units "
        "((m/s^2)(rad/s^2) and (rad/s^2)^2); I3, I4 in (rad/s^2)^2; the normalised ones dimensionless.",
        "",
        "## (c) Detection and false-alarm rates per window, over the whole matrix",
        "",
        "Under the rule (each window against its own load, speed and track's healthy 99th percentile): the share "
        "of all fault windows (every case, severity, speed and track of the load) that are flagged, and the "
        "out-of-sample share of healthy windows that are flagged.",
        "",
        "| load | rate | " + " | ".join(LABELS[i] for i in INDICATORS) + " |",
        "|---|---|" + "---|" * len(INDICATORS),
    ]
    for load in result.plan.loads:
        out.append(f"| {load} | detection | " + " | ".join(_pct(v) for v in detection[load]) + " |")
        out.append(f"| {load} | false alarm (held out) | " + " | ".join(_pct(v) for v in false_alarm[load]) + " |")
    worst_fa = max(float(v.max()) for v in false_alarm.values())
    out += [
        "",
        f"The rule's largest held-out false-alarm rate is {_pct(worst_fa)} "
        f"({'within' if worst_fa <= RULE_MAX_FALSE_ALARM else 'ABOVE'} the stated {RULE_MAX_FALSE_ALARM:.0%}).",
        "",
    ]
    checks = shipped or {load: e.check for load, e in defaults.chosen.items()}
    which = "configured" if shipped else "derived (not yet in the config)"
    out += [
        f"With the daemon's {which} thresholds (one set per load for every speed and track, windows of "
        f"{result.default_window_s:g} s, confirmation at {defaults.confirm_k} of {defaults.confirm_n} judged windows), per window and per run:",
        "",
        *_check_rows(checks),
        "",
        _healthy_note(result),
        "",
        "See [`defaults.md`](defaults.md) for how they were chosen and the confirmation per case.",
        "",
    ]
    if sens:
        out += [
            "## Sensitivity",
            "",
            f"At {result.plan.sensitivity_condition.label if result.plan.sensitivity_condition else ''}, "
            f"{result.plan.fault_runs} runs per severity, windows of {result.default_window_s:g} s; the main "
            "matrix's row at this one condition for comparison. Cells: smallest detection share over the "
            "severities run (bold: identified).",
            "",
            "| variant | case | severities | " + " | ".join(LABELS[i] for i in INDICATORS) + " |",
            "|---|---|---|" + "---|" * len(INDICATORS),
        ]
        base = _single_condition_identify(result)
        for key in sorted({k for cases in sens.values() for k in cases}):
            severity_sets = sorted({tuple(s.severity for s in cases[key].severities) for cases in sens.values() if key in cases})
            for sevs in severity_sets:
                label = ", ".join(f"{v:g}" for v in sevs)
                ev = base.get(key)
                if ev is not None:  # the main matrix on the same severities, at the same condition
                    ev = CaseEvidence(key, tuple(s for s in ev.severities if s.severity in sevs))
                    out.append(f"| main ({stick / 1e6:g} MN/m, {result.plan.fault_corner.value}) | {key} | {label} | " + _share_cells(ev) + " |")
                for name, cases in sens.items():
                    if key in cases and tuple(s.severity for s in cases[key].severities) == sevs:
                        out.append(f"| {name} | {key} | {label} | " + _share_cells(cases[key]) + " |")
        if sens_fa:
            fa = max(float(v.max()) for per in sens_fa.values() for v in per.values())
            out += ["", f"The sensitivity runs' own healthy references give held-out false-alarm rates up to {_pct(fa)}."]
        out.append("")
    disagreements = [
        (key, j) for key, agree in agreements.items() for j in range(4) if not agree[j]
    ]
    out += ["## (d) Where we disagree with the paper", ""]
    if disagreements:
        for key, j in disagreements:
            ev = ours[key]
            per_sev = ", ".join(f"{s.severity:g}: {s.detection_share[j]:.2f}" for s in ev.severities)
            out.append(
                f"- **{key}, I{j + 1}**: paper {'identified' if paper[key][j] else 'not identified'}, ours "
                f"{'identified' if ev.identified[j] else 'not identified'} (detection share per severity {per_sev})."
            )
    else:
        out.append("- none")
    out.append("")
    if discussion:
        out += ["### Likely physical causes", "", discussion.strip(), ""]
    else:
        out += [f"(No `{DISCUSSION_FILE}` beside this report: the physical discussion is not included.)", ""]
    out += [
        "## Notes",
        "",
        f"- Every window of the study would be judged by the daemon: the smallest median channel RMS of any window "
        f"is {result.min_excitation_rms_mps2:.2f} m/s^2 (the daemon's gate: {gate:g}).",
        "- Inner-coil faults in tare are not in Table 4 (the paper did not run them); in this simulator they are "
        "exactly identical to the healthy wagon (docs/simulator.md), so no indicator can see them.",
        "- Type B at full load uses Table 3's published Fs (11.6, 16.74, 27.91, 33.49 kN) against Table 1's healthy "
        "16.51 kN: its '0.75' case is 101 % of the healthy value, i.e. practically healthy (docs/simulator.md).",
        "",
    ]
    return "\n".join(out)


def implied_alarm_rate(thresholds: Mapping[str, ThresholdEstimate]) -> float:
    """The per-window false-alarm rate under the threshold rule's normal model: the two-sided tail
    beyond each alarm level in robust sigmas, summed over the indicators (a union bound)."""
    return float(sum(2 * stats.norm.sf(t.alarm / t.robust_sigma) for t in thresholds.values() if t.robust_sigma > 0))


def _check_rows(checks: Mapping[str, ThresholdCheck], healthy_only: bool = False) -> list[str]:
    head = "| load | indicators | healthy windows judged | at warning | at alarm | healthy runs confirmed |"
    rule = "|---|---|---|---|---|---|"
    if not healthy_only:
        head += " fault windows at alarm | broken outer coil runs confirmed | median time to confirm (fault from the start) |"
        rule += "---|---|---|"
    rows = [head, rule]
    for load, c in checks.items():
        where = ", ".join(f"{n} at {label}" for label, n in c.healthy_confirmed_by_condition.items())
        row = (
            f"| {load} | {', '.join(LABELS[n] for n in c.indicators)} | {c.healthy_windows} of {c.healthy_windows_total} | "
            f"{c.healthy_warning_windows} ({_pct(c.healthy_warning_windows / max(c.healthy_windows, 1))}) | "
            f"{c.healthy_alarm_windows} | {c.healthy_confirmed_runs} of {c.healthy_runs}{f' ({where})' if where else ''} |"
        )
        if not healthy_only:
            broken = f"{c.broken_outer_confirmed_runs} of {c.broken_outer_runs}" if c.broken_outer_runs else "-"
            confirm = f"{c.broken_outer_median_confirm_s:g} s" if math.isfinite(c.broken_outer_median_confirm_s) else "-"
            row += f" {_pct(c.fault_alarm_share)} | {broken} | {confirm} |"
        rows.append(row)
    return rows


def _healthy_note(result: StudyResult) -> str:
    """One sentence naming the healthy and fault runs behind the thresholds and their checks."""
    plan = result.plan
    text = (
        f"Healthy runs: the matrix's ({plan.healthy_runs} per load and condition at "
        + "; ".join(c.label for c in plan.conditions)
        + ")"
    )
    if plan.envelope_conditions:
        text += (
            f" and the envelope's ({plan.envelope_runs} per load and condition at "
            + "; ".join(c.label for c in plan.envelope_conditions)
            + "), which the thresholds also come from"
        )
    return text + ". Fault runs: the matrix's."


def _share_cells(ev: CaseEvidence) -> str:
    return " | ".join(f"**{ev.min_share[j]:.2f}**" if ev.identified[j] else f"{ev.min_share[j]:.2f}" for j in range(len(INDICATORS)))


def _single_condition_identify(result: StudyResult) -> dict[str, CaseEvidence]:
    """The main matrix judged at the sensitivity condition alone (the sensitivity rows' baseline)."""
    cond = result.plan.sensitivity_condition
    assert cond is not None
    narrowed = dataclasses.replace(result, plan=dataclasses.replace(result.plan, conditions=(cond,)))
    return identify(narrowed)


def _defaults_md(
    result: StudyResult,
    defaults: DefaultsEvidence,
    shipped: Mapping[str, ThresholdCheck],
    matrix_only: Mapping[str, ThresholdCheck],
    gate: float,
    timing: Mapping[str, Any],
    command: str,
    confirm_k: int,
    confirm_n: int,
) -> str:
    w0 = defaults.chosen_window_s
    out = [
        "# Evidence for the daemon's defaults: window length, normalisation, thresholds",
        "",
        f"Generated by `simulator/study.py` from the detection study (`{command}`, {timing['total_s'] / 60:.1f} min); "
        "the study itself is described in [README.md](README.md).",
        "",
        "## The rules (`simulator/study.py`; the envelope's share in the thresholds was added after the first full run, see below)",
        "",
        f"- **Thresholds**: daemon/calibrate.py's rule (warning and alarm at per-window false-alarm targets "
        f"{WARNING_RATE:g} and {ALARM_RATE:g} under a normal model with a robust sigma, 1.4826 MAD; the warning at least the "
        f"empirical {1 - WARNING_RATE:.0%} quantile of the deviation, the alarm at least {ALARM_MARGIN:g} x the largest healthy "
        "deviation), applied per load to every healthy window of the study pooled over its speeds and tracks, the "
        "matrix's and the envelope's (the daemon knows the load, not the speed or the track). "
        + _healthy_note(result),
        f"- **Indicators** per load: forward selection on the share of fault windows (every case, severity, speed and "
        f"track of the load) at alarm level; start with the best indicator and add the next best while it raises "
        f"the share by at least {SELECTION_MIN_GAIN * 100:g} points, at most {SELECTION_MAX_INDICATORS}.",
        f"- **Window length**: the highest combined share averaged over the loads; a shorter window within "
        f"{WINDOW_TIE * 100:g} points of the best wins. Eligible only if no healthy run of the study (matrix or "
        f"envelope) confirms an alarm ({confirm_k} of {confirm_n} judged windows at alarm level) and every full-load "
        "broken-outer-coil run (front or rear, all speeds and tracks of the matrix) does. The hop stays at "
        f"{result.settings.hop_s:g} s (not varied).",
        "",
        "## Window length x normalisation",
        "",
        "Alarm-level detection share over all fault windows of the load, with the indicators selected from each "
        "candidate set (raw I1..I4, normalised I1n..I4n, or all eight) and their calibrated thresholds:",
        "",
        "| window | load | raw: selected | raw: share | normalised: selected | normalised: share | all: selected | all: share | healthy runs confirmed (all) | broken outer coil confirmed (all) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for w in result.plan.window_lengths_s:
        for load in result.plan.loads:
            cells = []
            for name in CANDIDATE_SETS:
                e = defaults.table[(w, name, load)]
                cells += [", ".join(LABELS[n] for n in e.indicators), _pct(e.check.fault_alarm_share)]
            e = defaults.table[(w, "all", load)]
            broken = f"{e.check.broken_outer_confirmed_runs} of {e.check.broken_outer_runs}" if e.check.broken_outer_runs else "-"
            out.append(f"| {w:g} s | {load} | {' | '.join(cells)} | {e.check.healthy_confirmed_runs} of {e.check.healthy_runs} | {broken} |")
    out += [
        "",
        "Each indicator alone (alarm-level detection share over the load's fault windows, at its own calibrated thresholds):",
        "",
        "| window | load | " + " | ".join(LABELS[i] for i in INDICATORS) + " |",
        "|---|---|" + "---|" * len(INDICATORS),
    ]
    for w in result.plan.window_lengths_s:
        for load in result.plan.loads:
            e = defaults.table[(w, "all", load)]
            out.append(f"| {w:g} s | {load} | " + " | ".join(_pct(e.per_indicator_share[i]) for i in INDICATORS) + " |")
    scores = {w: float(np.mean([defaults.table[(w, "all", load)].check.fault_alarm_share for load in result.plan.loads])) for w in result.plan.window_lengths_s}
    out += [
        "",
        "Combined share averaged over the loads: "
        + ", ".join(f"{w:g} s: {_pct(s)}{'' if defaults.eligible[w] else ' (not eligible)'}" for w, s in scores.items())
        + f". **Chosen: {w0:g} s.**",
        "",
        "## The defaults",
        "",
        "```toml",
        "[processing]",
        f"window_s = {w0:g}",
        f"hop_s = {result.settings.hop_s:g}",
        "",
        *_threshold_toml(defaults.chosen),
        "```",
        "",
        "(Levels rounded up to three significant digits, the center to the nearest.)",
        "",
        "| load | indicator | center | warning | alarm | robust sigma | largest healthy deviation | healthy windows |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for load, e in defaults.chosen.items():
        for n in e.indicators:
            t = e.thresholds[n]
            out.append(
                f"| {load} | {LABELS[n]} (`{n}`) | {t.center:+.3g} | {t.warning:.3g} | {t.alarm:.3g} | {t.robust_sigma:.3g} | {t.max_deviation:.3g} | {t.n_windows} |"
            )
    out += [
        "",
        "## What they do on the study's runs",
        "",
        f"The derived thresholds at {w0:g} s, judged as the daemon would (windows under its excitation gate of "
        f"{gate:g} m/s^2 are not judged; CONFIRMED at {confirm_k} of {confirm_n} judged windows at alarm level) on every "
        "healthy run of the study and every fault run of the matrix:",
        "",
        *_check_rows({load: e.check for load, e in defaults.chosen.items()}),
        "",
        "Out of sample (thresholds from the even-numbered healthy runs judge the odd-numbered ones, and back): "
        + "; ".join(
            f"{load}: {e.held_out_alarm_windows} of {e.check.healthy_windows} windows at alarm level, "
            f"{e.held_out_confirmed_runs} of {e.check.healthy_runs} runs confirmed"
            + (
                " (" + ", ".join(f"{n} at {c}" for c, n in e.held_out_confirmed_by_condition.items()) + ")"
                if e.held_out_confirmed_by_condition
                else ""
            )
            for load, e in defaults.chosen.items()
        )
        + ".",
        "",
    ]
    if shipped:
        same = all(
            shipped[load].indicators == e.indicators and result.default_window_s == w0 for load, e in defaults.chosen.items() if load in shipped
        )
        out += [
            f"The thresholds of the config the study ran with (windows of {result.default_window_s:g} s"
            f"{', the indicators chosen above' if same else ', NOT the set chosen above'}):",
            "",
            *_check_rows(shipped),
            "",
        ]
    if matrix_only:
        out += [
            "**Why the envelope's healthy runs are in the thresholds' population** (a revision of this rule after the "
            "first full run of the study, which derived them from the matrix's 60 and 100 km/h alone): the same rule "
            "and indicators with thresholds from the matrix's healthy runs only, judged on the envelope's healthy runs:",
            "",
            *_check_rows(matrix_only, healthy_only=True),
            "",
        ]
    lines = []
    for load, e in defaults.chosen.items():
        n = e.check.healthy_windows
        independent = n * result.settings.hop_s / w0  # overlapping windows: about this many independent ones
        where = ", ".join(f"{k} at {c}" for c, k in e.held_out_confirmed_by_condition.items())
        rate = (
            f"{e.held_out_alarm_windows} of {n} healthy windows at alarm level ({_pct(e.held_out_alarm_windows / n)} per window)"
            if e.held_out_alarm_windows
            else f"none of {n} healthy windows at alarm level (about {independent:.0f} independent ones: below about "
            f"{3 / independent:.0e} per window, 95 %)"
        )
        lines.append(
            f"- **{load}**: {rate}; {e.held_out_confirmed_runs} of {e.check.healthy_runs} healthy runs of "
            f"{result.plan.duration_s:g} s confirmed{f' ({where})' if where else ''}. The rule's normal model would claim "
            f"{implied_alarm_rate(e.thresholds):.1e} per window."
        )
    in_alarm = sum(e.check.healthy_alarm_windows for e in defaults.chosen.values())
    in_confirmed = sum(e.check.healthy_confirmed_runs for e in defaults.chosen.values())
    out += [
        f"**The per-window false-alarm rate they imply.** In-sample, {in_alarm} healthy windows of the study reach an "
        f"alarm level and {in_confirmed} healthy runs confirm (the alarm is at least {ALARM_MARGIN:g} x the largest "
        "healthy deviation). The honest figure is out of sample, thresholds from the even-numbered healthy runs "
        "judging the odd-numbered ones and back:",
        "",
        *lines,
        "",
        "Where the held-out rate exceeds the normal model's, the healthy tail is heavier than normal: trust the "
        "held-out figure. CONFIRMED needs "
        f"{confirm_k} of {confirm_n} windows at alarm level, but consecutive windows overlap by "
        f"{1 - result.settings.hop_s / w0:.0%}: one rare excursion lasting a window can confirm by itself, so the "
        "confirmed false-alarm rate per window is about the per-window alarm rate, not its cube.",
        "",
        "## Confirmation per fault case (share of runs confirmed, all speeds and tracks)",
        "",
        "| case@severity | " + " | ".join(defaults.chosen) + " |",
        "|---|" + "---|" * len(defaults.chosen),
    ]
    keys = sorted({k for e in defaults.chosen.values() for k in e.check.confirmed_share_per_case})
    for k in keys:
        out.append(f"| {k} | " + " | ".join(_pct(e.check.confirmed_share_per_case[k]) if k in e.check.confirmed_share_per_case else "" for e in defaults.chosen.values()) + " |")
    out.append("")
    return "\n".join(out)
