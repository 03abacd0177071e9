"""Measures the diagnosis (issue 16): does a CONFIRMED fault name its corner, a wrong one, or "unknown"?

    .venv/bin/python -m bogiemon.lab.robust.diagnosis_check [--model a|b] [--wagons 4] [--runs 2]
        [--commissioning 6] [--trend] [--shifts] [--linear]

THE MEASUREMENT. A fleet of the robustness evaluation's varied wagons (lab/robust/wagons.py: masses,
coils, dampers and sensors drawn per wagon, each corner's own tolerance; on model B the same draws
on its own parameter set), other seeds than the evaluation's and the training fleet's. Each wagon
is commissioned per load with `calibrate`'s own code on its healthy commissioning runs, then every
fault case of the paper's tables at every severity appears at each of the four corners in `runs`
single runs (a healthy lead-in, then the fault), on drawn tracks, speeds and directions of travel
(scenario_for mirrors sensors and corners for a reversed run). Every run is judged by the
daemon's WindowJudge (the default fused method); the first CONFIRMED after the onset is taken,
and its diagnosis is right (the fault's corner), wrong (another corner) or unknown. With --trend,
a trend sequence per case, severity and corner as well (the fault stays while the wagon runs on).

THE TARGETS (issue 16): of the confirmed broken springs (a coil at 0 %), the corner right in at
least 90 % and wrong in at most 5 %, on a model the rule was not tuned on (model B).

--shifts: the check of the sign relation judgement/diagnosis.py rests on. The nominal wagon, every
case at every corner on a few seeds paired with a healthy run on the same track and speed: the
mean coupling shift per band, times the sign a softer corner should give (x y for pitch-roll, y
for bounce-roll), averaged over the corners ("*": the corners do not all agree in sign).
--linear: the same signs from model A linearised (dampers all stuck, or all sliding), a 30 %
softer and a 30 % stiffer corner, from the frequency response to the rails' spectra: the
first-order physics without the friction's non-linearity.
"""

from __future__ import annotations

import argparse
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.judgement.diagnosis import SIGN_BANDS, Diagnosis, softer_signs
from bogiemon.judgement.models import UNKNOWN, coupling_features
from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.detection.features import COUPLING_FEATURES, COUPLING_NAMES, PITCH
from bogiemon.detection.spectra import JUDGED_BANDS_HZ as BANDS_HZ
from bogiemon.lab.robust.fleet import EvaluationData, EvaluationPlan, RunSpec, fault_cells, simulate_plan
from bogiemon.lab.robust.judge import DaemonMethod, judge_runs, with_overrides
from bogiemon.lab.study.plan import table4_cases

CHECK_SEED = 16_300  # this check's wagons: other seeds than the evaluation's (2026) and the health check's
OUTCOMES = ("right", "wrong", "unknown")


def check_plan(model: str, wagons: int, runs: int, commissioning: int, trend: bool) -> EvaluationPlan:
    """Commissioning and fault runs (and with `trend` the trend sequences) of the check's fleet."""
    return EvaluationPlan(
        name="diagnosis-check", n_wagons=wagons, n_training_wagons=1, calibration_runs=commissioning, calibration_s=600.0,
        healthy_runs=0, fault_runs=runs, lead_in_s=150.0, fault_s=240.0, trend_runs=3 if trend else 0, trend_run_s=450.0,
        training_healthy_runs=0, training_fault_runs=0, sensor_runs=0, fleet_seed=CHECK_SEED, model=model,
    )  # fmt: skip


def case_label(key: str, severity: float) -> str:
    """'full rear_outer 0 %', 'tare friction 150 %'."""
    parts = key.split(".")
    what = "friction" if parts[0] == "type_b" else parts[2]
    return f"{parts[1]} {what} {100 * severity:g} %"


def is_broken_spring(key: str, severity: float) -> bool:
    """A coil at 0 % that touches the frame (the tare inner coils never do)."""
    return key.startswith("type_a") and severity == 0.0 and not (".tare." in key and key.endswith("inner"))


@dataclass
class Tally:
    """Confirmed faults per case, corner and outcome; runs per case."""

    outcomes: dict[tuple[str, float], dict[str, Counter[str]]] = field(default_factory=lambda: defaultdict(lambda: defaultdict(Counter)))
    runs: Counter[tuple[str, float]] = field(default_factory=Counter)

    def add(self, spec: RunSpec, diagnosis: Diagnosis | None, confirmed: bool) -> None:
        assert spec.corner is not None
        cell = (spec.key, spec.severity)
        self.runs[cell] += 1
        if not confirmed:
            return
        corner = diagnosis.corner if diagnosis is not None else UNKNOWN
        outcome = "unknown" if corner == UNKNOWN else "right" if corner == spec.corner.value else "wrong"
        self.outcomes[cell][spec.corner.value][outcome] += 1

    def total(self, cells: Sequence[tuple[str, float]]) -> Counter[str]:
        out: Counter[str] = Counter()
        for cell in cells:
            for per in self.outcomes.get(cell, {}).values():
                out.update(per)
        return out


def tally_runs(data: EvaluationData, config: BogiemonConfig) -> tuple[Tally, Tally, list[str]]:
    """(single fault runs, trend sequences, a line per confirmed fault): the daemon's default
    method, commissioned per wagon."""
    method = DaemonMethod("fused, calibrated", "the daemon's default", with_overrides(config, {"method": "fused"}), calibrated=True)
    judged = judge_runs(data, method)
    runs, sequences = Tally(), Tally()
    lines = []
    for r in judged.runs:
        if r.run.role == "fault":
            runs.add(r.run, r.diagnosis, r.confirmed_s is not None)
            if r.confirmed_s is not None and r.run.corner is not None:
                d = r.diagnosis
                lines.append(f"  {case_label(r.run.key, r.run.severity):24} {r.run.corner.value:14} {'reversed' if r.reversed else 'forward ':8} "
                             f"{r.trigger or '':7} -> {d.corner if d else UNKNOWN:14} {d.best_match if d else ''}")  # fmt: skip
    for s in judged.sequences:
        sequences.add(s.first, s.diagnosis, s.confirmed_after_s is not None)
    return runs, sequences, lines


def share(counts: Counter[str]) -> str:
    n = sum(counts.values())
    if not n:
        return "none confirmed"
    return ", ".join(f"{o} {counts[o]} ({100 * counts[o] / n:.0f} %)" for o in OUTCOMES) + f" of {n}"


def report(title: str, tally: Tally) -> list[str]:
    lines = [title, f"  {'case':24} {'runs':>4} {'confirmed':>9}  " + "  ".join(f"{c.value:>14}" for c in Corner) + "   (right/wrong/unknown)"]
    for key, severities in fault_cells().items():
        for severity in severities:
            cell = (key, severity)
            if not tally.runs[cell]:
                continue
            per = tally.outcomes.get(cell, {})
            confirmed = sum(sum(c.values()) for c in per.values())
            cols = "  ".join(f"{'/'.join(str(per.get(c.value, Counter())[o]) for o in OUTCOMES):>14}" for c in Corner)
            lines.append(f"  {case_label(key, severity):24} {tally.runs[cell]:4} {confirmed:9}  {cols}")
    cells = [c for c in tally.runs]
    groups = {
        "broken springs (the target)": [c for c in cells if is_broken_spring(*c)],
        "  of them full load": [c for c in cells if is_broken_spring(*c) and ".full." in c[0]],
        "  of them tare": [c for c in cells if is_broken_spring(*c) and ".tare." in c[0]],
        "softer springs (50 %)": [c for c in cells if c[0].startswith("type_a") and c[1] == 0.5],
        "stiffer springs (150, 200 %)": [c for c in cells if c[0].startswith("type_a") and c[1] > 1.0],
        "friction lower (50, 75 %)": [c for c in cells if c[0].startswith("type_b") and c[1] < 1.0],
        "friction higher (125, 150 %)": [c for c in cells if c[0].startswith("type_b") and c[1] > 1.0],
        "every confirmed fault": cells,
    }
    lines += [f"  {name:30} {share(tally.total(group))}" for name, group in groups.items()]
    return lines


# --------------------------------------------------------------------------------------------
# The sign relation on the simulator


def paired_shifts(
    model: str,
    load: str,
    seeds: int = 3,
    duration_s: float = 250.0,
    features: Callable[[WindowIndicators, BogieGeometry], np.ndarray | None] = coupling_features,
    cells: Sequence[tuple[str, float]] | None = None,
) -> dict[tuple[str, float], dict[Corner, np.ndarray]]:
    """Per case and corner: the mean shift of `features` (by default the fused score's coupling
    vector) against a healthy run on the same track and speed (mean over the seeds), the nominal
    wagon of the model, forward running; every case of the paper's Table 4 at `load`, or `cells`."""
    from bogiemon.simulator.run import simulate_batch  # the kernel: only when running
    from bogiemon.simulator.scenario import Scenario, SpeedProfile
    from bogiemon.simulator.suspension import Fault

    settings, geometry = ProcessingSettings(), BogieGeometry()
    tracks = ("erri-low", "fra-5", "erri-high", "fra-4", "fra-6")
    if cells is None:
        cells = [(key, s) for key, sev in table4_cases().items() if key.split(".")[1] == load for s in sev]
    labels: list[tuple[int, tuple[str, float] | None, Corner | None]] = []
    scenarios = []
    for seed in range(seeds):
        common = {"load": load, "speed": SpeedProfile.constant(60.0 + 15.0 * seed), "track": tracks[seed % len(tracks)], "duration_s": duration_s,
                  "seed": 9000 + seed, "model": model}  # fmt: skip
        labels.append((seed, None, None))
        scenarios.append(Scenario(**common))  # type: ignore[arg-type]
        for key, severity in cells:
            kind, _, *position = key.split(".")
            for corner in Corner:
                fault = Fault(kind=kind, corner=corner, position=position[0] if position else None, severity=severity)
                labels.append((seed, (key, severity), corner))
                scenarios.append(Scenario(**common, faults=(fault,)))  # type: ignore[arg-type]
    means: dict[tuple[int, tuple[str, float] | None, Corner | None], np.ndarray] = {}
    for first in range(0, len(scenarios), 16):
        for label, result in zip(labels[first : first + 16], simulate_batch(scenarios[first : first + 16]), strict=True):
            xs = [features(w, geometry) for w in IndicatorStream(settings, geometry).process(result.accel_mps2)]
            means[label] = np.nanmean([x for x in xs if x is not None], axis=0)
    out: dict[tuple[str, float], dict[Corner, np.ndarray]] = {}
    for cell in cells:
        out[cell] = {c: np.mean([means[(s, cell, c)] - means[(s, None, None)] for s in range(seeds)], axis=0) for c in Corner}
    return out


def softer_pattern(corner: Corner) -> np.ndarray:
    """Per COUPLING_FEATURES entry: the sign its shift takes when `corner` gets softer."""
    pr, br = softer_signs(corner)
    return np.array([pr if i == PITCH else br for _, i, _, _ in COUPLING_FEATURES], dtype=np.float64)


def sign_table(shifts: dict[tuple[str, float], dict[Corner, np.ndarray]], title: str) -> list[str]:
    lines = [title, "  " + " " * 24 + " ".join(f"{n:>7}" for n in COUPLING_NAMES)]
    for (key, severity), per in shifts.items():
        aligned = np.array([per[c] * softer_pattern(c) for c in Corner])
        agree = np.all(np.sign(aligned) == np.sign(aligned.mean(axis=0)), axis=0)
        cols = " ".join(f"{m:+6.2f}{' ' if a else '*'}" for m, a in zip(aligned.mean(axis=0), agree, strict=True))
        lines.append(f"  {case_label(key, severity):24}{cols}")
    return lines


def linear_signs(load: str, stuck: bool, change: float, speed_kmh: float = 80.0, track: str = "erri-low") -> dict[Corner, np.ndarray]:
    """Model A linearised about its rest (every damper stuck or every one sliding): the coherency
    shift per COUPLING_FEATURES entry when one corner's stiffness changes by the factor (1 - change)
    (change > 0: softer), from the frame's response to the rails' level and cross-level spectra
    (uncorrelated with each other, each axle delayed by its distance: the wheelbase delay)."""
    from bogiemon.simulator.params import default_parameter_set
    from bogiemon.simulator.suspension import CORNER_ORDER
    from bogiemon.simulator.track import shaped_psd, track_spectrum
    from bogiemon.simulator.vehicle import build_model, static_equilibrium

    model = build_model(default_parameter_set(), load)
    p = model.params
    g = model.corner_rows()
    compression = -g @ static_equilibrium(model).q
    k0 = np.array([c.tangent_stiffness_n_per_m(float(u)) + (c.stick_stiffness_n_per_m if stuck else 0.0) for c, u in zip(model.corners, compression, strict=True)])
    c0 = np.array([c.damping_n_s_per_m for c in model.corners])
    bowl, bearer = model.bowl_rows(), model.side_bearer_rows()
    k_body = p.bowl_stiffness_n_per_m * bowl.T @ bowl + p.side_bearer_stiffness_n_per_m * bearer.T @ bearer
    c_body = p.bowl_damping_n_s_per_m * bowl.T @ bowl + p.side_bearer_damping_n_s_per_m * bearer.T @ bearer
    mass = np.diag(model.mass_diag)
    spectrum = track_spectrum(track)
    level, cross = shaped_psd(spectrum.level_psd), shaped_psd(spectrum.cross_level_psd)
    speed_mps = speed_kmh / 3.6
    axle = np.repeat(np.arange(4), 2)  # boxes in corner order: axle 1 left, right, axle 2 ...
    side = np.tile([1.0, -1.0], 4)
    delay_s = np.asarray(p.axle_offsets_m)[axle] / speed_mps
    lever = p.axle_box_spacing_m / p.contact_spacing_m

    def couplings(k: np.ndarray) -> np.ndarray:
        out = []
        for band in range(len(BANDS_HZ) - 1):
            s = np.zeros((3, 3), dtype=np.complex128)
            for f_hz in np.linspace(BANDS_HZ[band], BANDS_HZ[band + 1], 120):
                w = 2 * np.pi * f_hz
                wavenumber = np.array([w / speed_mps])
                phase = np.exp(-1j * w * delay_s)
                boxes = np.outer(phase, phase.conj()) * (level(wavenumber)[0] + lever**2 / 4 * cross(wavenumber)[0] * np.outer(side, side))
                z = -(w**2) * mass + 1j * w * (c_body + g.T @ (c0[:, None] * g)) + k_body + g.T @ (k[:, None] * g)
                frame = -(w**2) * np.linalg.solve(z, g.T @ np.diag(k + 1j * w * c0))[3:6]  # a_bounce, a_pitch, a_roll of the leading frame
                s += frame @ boxes @ frame.conj().T
            sd = np.sqrt(np.real(np.diag(s)))
            coh = (s / np.outer(sd, sd)).real
            out.append((coh[1, 2], coh[0, 2]))
        pr, br = np.array(out).T
        return np.array([(pr if i == PITCH else br)[b] for _, i, _, b in COUPLING_FEATURES])

    healthy = couplings(k0)
    out = {}
    for index, corner in enumerate(CORNER_ORDER):  # the simulator's corner order
        k = k0.copy()
        k[index] *= 1.0 - change
        out[corner] = couplings(k) - healthy
    return out


def linear_table() -> list[str]:
    lines = ["MODEL A LINEARISED: the coupling shift times the softer sign, mean over the corners ('*': the corners disagree)",
             "  " + " " * 24 + " ".join(f"{n:>7}" for n in COUPLING_NAMES)]  # fmt: skip
    for load in ("full", "tare"):
        for stuck in (True, False):
            for change in (0.3, -0.3):
                per = linear_signs(load, stuck, change)
                aligned = np.array([per[c] * softer_pattern(c) for c in Corner])
                agree = np.all(np.sign(aligned) == np.sign(aligned.mean(axis=0)), axis=0)
                what = f"{load} {'stuck' if stuck else 'sliding'} {'softer' if change > 0 else 'stiffer'}"
                lines.append(f"  {what:24}" + " ".join(f"{m:+6.2f}{' ' if a else '*'}" for m, a in zip(aligned.mean(axis=0), agree, strict=True)))
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--model", default="a", choices=("a", "b"), help="wagon model (default a)")
    parser.add_argument("--wagons", type=int, default=4, help="wagons of the fleet (default 4)")
    parser.add_argument("--runs", type=int, default=2, help="single fault runs per case, severity and corner (default 2)")
    parser.add_argument("--commissioning", type=int, default=6, help="commissioning runs of 600 s per wagon and load (default 6)")
    parser.add_argument("--trend", action="store_true", help="also a trend sequence of 3 x 450 s per case, severity and corner")
    parser.add_argument("--shifts", action="store_true", help="the sign check on the nominal wagon instead of the fleet")
    parser.add_argument("--linear", action="store_true", help="the sign check on model A linearised instead of the fleet")
    parser.add_argument("-v", "--verbose", action="store_true", help="also every confirmed fault run's diagnosis and its statistic")
    args = parser.parse_args(argv)
    if args.linear:
        print("\n".join(linear_table()))
        return 0
    if args.shifts:
        for load in ("full", "tare"):
            title = (f"MODEL {args.model.upper()} {load}: mean coupling shift times the softer sign, over the corners "
                     f"('*': the corners disagree); the diagnosis reads bands {SIGN_BANDS[load]}")  # fmt: skip
            print("\n".join(sign_table(paired_shifts(args.model, load), title)))
        return 0
    config = BogiemonConfig()
    plan = check_plan(args.model, args.wagons, args.runs, args.commissioning, args.trend)
    roles = ("calibration", "fault") + (("trend",) if args.trend else ())
    data = simulate_plan(plan, config.processing_settings(), config.bogie_geometry(), roles=roles)
    runs, sequences, lines = tally_runs(data, config)
    print(f"MODEL {args.model.upper()}: {args.wagons} wagons, {args.runs} run(s) per case, severity and corner, "
          f"{data.simulated_s / 3600:.0f} h simulated in {data.elapsed_s / 60:.1f} min")  # fmt: skip
    print("\n".join(report("single fault runs: the first CONFIRMED after the onset", runs)))
    if args.trend:
        print("\n".join(report("trend sequences: the first CONFIRMED after the onset", sequences)))
    if args.verbose:
        print("\n".join(["every confirmed fault run: case, corner, direction, trigger -> diagnosis, statistic", *lines]))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
