"""What three vertical accelerometers on a bogie frame can observe of a fault (issue 16).

    .venv/bin/python -m bogiemon.lab.robust.observability --data build/transfer.pkl   # visibility
    .venv/bin/python -m bogiemon.lab.robust.observability --signs [--model a|b]       # the corner

Two of issue 16's targets were missed in every judgement of docs/robust/transfer, on the model the
priors were fitted on as much as on the other: broken front coils at full load, and the corner.
This asks whether any statistic of the three sensors could meet them, not only the daemon's.

VISIBILITY (--data FILE, a file written by `bogiemon evaluate --transfer --data FILE`): on the
TRAINING fleets of both wagon models (never the evaluation fleets), each training wagon and load
gets a healthy reference from its commissioning runs (the mean and covariance of one feature
set over its windows, the covariance shrunk towards its diagonal with the weight p / (p + n_eff),
n_eff the independent windows: the daemon's rule, without a shipped prior), and its later healthy
runs give the reference's 99.9th percentile of the Mahalanobis score. The share of a fault run's
windows after the onset above that percentile is the fault's visibility to the feature set: about
0.001 for a fault nothing sees, 1 for one every window shows. A window alarm needs three of five
windows far above it (judgement/rules.py), so a fault with a visibility of a few tenths is confirmed
late or never within ten minutes. The feature sets, each over the judged bands 2-64 Hz:

    fused     the daemon's couplings: real coherency of pitch-roll and bounce-roll (detection/features.py)
    real      the real coherency of all three pairs, bounce-pitch too
    complex   the real and imaginary coherency of all three pairs
    shares    each mode's log power share per band (the spectral shape a stiffness change moves)
    all       complex and shares together

SIGNS (--signs): the corner. The nominal wagon, each broken coil at each corner, paired with a
healthy run on the same track, speed and seed (forward running); the mean shift of
the real coherency of every pair and band times the sign a softer corner gives it (x for
bounce-pitch, y for bounce-roll, x y for pitch-roll: judgement/diagnosis.py). A front coil's Lenoir
damper grips more when the coil breaks (the paper's Table 1), so the corner is stiffer in effect
where the dampers stick: its bounce-pitch and bounce-roll shifts take the sign of the diagonally
opposite corner softening, and pitch-roll, whose second-order part keeps the sign x y either way,
agrees with both. The table shows whether any band tells the two apart.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.diagnosis import softer_signs
from bogiemon.judgement.models import coupling_features
from bogiemon.detection import BogieGeometry, Corner, WindowIndicators
from bogiemon.detection.features import BOUNCE, PITCH, ROLL, band_label, modal_coherency
from bogiemon.detection.spectra import N_JUDGED_BANDS, modal_spectra
from bogiemon.lab.robust.fleet import EvaluationData

QUANTILE = 0.999
BANDS = tuple(range(2, N_JUDGED_BANDS))  # 2-64 Hz, the fused score's bands
PAIRS: dict[str, tuple[int, int]] = {"bounce-pitch": (BOUNCE, PITCH), "bounce-roll": (BOUNCE, ROLL), "pitch-roll": (PITCH, ROLL)}
BROKEN_COILS = ("front_outer", "front_inner", "rear_outer", "rear_inner")

Features = Callable[[WindowIndicators, BogieGeometry], NDArray[np.float64] | None]
# Per broken-coil case ("full front_outer"), per feature set: each training fault run's visibility.
Visibility = dict[str, dict[str, list[float]]]


def _finite(x: NDArray[np.float64]) -> NDArray[np.float64] | None:
    return x if bool(np.all(np.isfinite(x))) else None


def _coherency(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.complex128] | None:
    return None if window.spectra is None else modal_coherency(window.spectra, geometry)


def real_couplings(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    """The real coherency of every pair (PAIRS order) in BANDS."""
    coh = _coherency(window, geometry)
    return None if coh is None else _finite(np.concatenate([coh[list(BANDS), i, j].real for i, j in PAIRS.values()]))


def complex_couplings(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    """The real and imaginary coherency of every pair in BANDS."""
    coh = _coherency(window, geometry)
    if coh is None:
        return None
    parts = [coh[list(BANDS), i, j].real for i, j in PAIRS.values()] + [coh[list(BANDS), i, j].imag for i, j in PAIRS.values()]
    return _finite(np.concatenate(parts))


def power_shares(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    """Each mode's log share of its power over BANDS, per band in BANDS."""
    if window.spectra is None:
        return None
    power = np.real(np.diagonal(modal_spectra(window.spectra.matrix[list(BANDS)], geometry), axis1=1, axis2=2))  # (bands, 3)
    with np.errstate(divide="ignore", invalid="ignore"):
        return _finite((np.log(power) - np.log(power.sum(axis=0, keepdims=True))).ravel())


def everything(window: WindowIndicators, geometry: BogieGeometry) -> NDArray[np.float64] | None:
    a, b = complex_couplings(window, geometry), power_shares(window, geometry)
    return None if a is None or b is None else np.concatenate([a, b])


FEATURE_SETS: dict[str, Features] = {
    "fused": coupling_features,
    "real": real_couplings,
    "complex": complex_couplings,
    "shares": power_shares,
    "all": everything,
}


# --------------------------------------------------------------------------------------------
# Visibility


@dataclass(frozen=True)
class Reference:
    """A healthy reference of one feature set: z = whitening (x - center), score |z|^2."""

    center: NDArray[np.float64]
    whitening: NDArray[np.float64]

    def scores(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        z = (np.atleast_2d(x) - self.center) @ self.whitening.T
        return np.einsum("ij,ij->i", z, z)


def fit_reference(x: NDArray[np.float64], overlap: float) -> Reference:
    """The mean and the covariance of the rows x, shrunk towards its diagonal with the weight
    p / (p + n_eff), n_eff = rows / overlap (consecutive windows overlap that many times)."""
    n, p = x.shape
    if n < 2:
        raise ValueError(f"a reference needs at least 2 windows, got {n}")
    covariance = np.atleast_2d(np.cov(x.T))
    lam = p / (p + max(n / overlap, 1.0))
    shrunk = (1.0 - lam) * covariance + lam * np.diag(np.diag(covariance))
    return Reference(x.mean(axis=0), np.linalg.inv(np.linalg.cholesky(shrunk)))


def visible_share(healthy_scores: NDArray[np.float64], fault_scores: NDArray[np.float64], quantile: float = QUANTILE) -> float:
    """The share of the fault's scores above the healthy scores' `quantile`."""
    if healthy_scores.size == 0 or fault_scores.size == 0:
        raise ValueError("both healthy and fault scores are needed")
    return float(np.mean(fault_scores > np.quantile(healthy_scores, quantile)))


def _rows(windows: Sequence[WindowIndicators], geometry: BogieGeometry, features: Features, after_s: float = 0.0) -> NDArray[np.float64]:
    rows = [x for w in windows if w.start_s >= after_s and (x := features(w, geometry)) is not None]
    return np.array(rows)


def case_of(key: str, severity: float) -> str | None:
    """'full front_outer' for a broken coil (severity 0) of the plan's cases; None for the others."""
    parts = key.split(".")
    if parts[0] != "type_a" or severity != 0.0 or len(parts) != 3:
        return None
    return f"{parts[1]} {parts[2]}"


def visibility(data: EvaluationData, feature_sets: Mapping[str, Features] = FEATURE_SETS) -> Visibility:
    """Per broken-coil case, per feature set: the visibility of each training fault run (module
    docstring), against its own training wagon's reference in the run's load."""
    overlap = data.settings.window_s / data.settings.hop_s
    by_wagon: dict[tuple[int, str], dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for r in data.runs:
        if r.run.role == "train-healthy":
            by_wagon[(r.run.wagon, r.run.load)]["commissioning" if r.run.commissioning else "healthy"].append(r)
        elif r.run.role == "train-fault" and case_of(r.run.key, r.run.severity):
            by_wagon[(r.run.wagon, r.run.load)]["fault"].append(r)
    out: Visibility = defaultdict(lambda: defaultdict(list))
    for runs in by_wagon.values():
        if not (runs["commissioning"] and runs["healthy"] and runs["fault"]):
            continue
        for name, features in feature_sets.items():
            reference = fit_reference(_rows([w for r in runs["commissioning"] for w in r.windows], data.geometry, features), overlap)
            healthy = reference.scores(_rows([w for r in runs["healthy"] for w in r.windows], data.geometry, features))
            for f in runs["fault"]:
                rows = _rows(f.windows, data.geometry, features, after_s=f.run.onset_s)
                if len(rows):
                    out[str(case_of(f.run.key, f.run.severity))][name].append(visible_share(healthy, reference.scores(rows)))
    return out


@dataclass(frozen=True)
class CaseVisibility:
    """One broken-coil case's visibility per feature set: the median over its fault runs."""

    case: str
    runs: int
    median: dict[str, float]


def summarize(shares: Visibility) -> list[CaseVisibility]:
    """Per case (sorted), the median visibility of its runs under each feature set."""
    return [
        CaseVisibility(case, len(next(iter(per.values()))), {name: float(np.median(v)) for name, v in per.items()})
        for case, per in sorted(shares.items())
    ]


def visibility_table(model: str, shares: Visibility) -> list[str]:
    names = list(FEATURE_SETS)
    lines = [f"MODEL {model.upper()}, training fleet: the share of a broken coil's windows above the healthy 99.9th percentile (median over runs)",
             f"  {'case':20} {'runs':>4} " + " ".join(f"{n:>8}" for n in names)]  # fmt: skip
    for c in summarize(shares):
        lines.append(f"  {c.case:20} {c.runs:4} " + " ".join(f"{c.median[n]:8.2f}" for n in names))
    return lines


# --------------------------------------------------------------------------------------------
# The corner's signs


def softer_sign(pair: str, corner: Corner) -> int:
    """The sign a pair's real coherency shifts by when `corner` gets softer: the diagnosis's rule
    for pitch-roll and bounce-roll (judgement/diagnosis.py softer_signs), x for bounce-pitch."""
    pitch_roll, bounce_roll = softer_signs(corner)
    return {"bounce-pitch": corner.x_sign, "bounce-roll": bounce_roll, "pitch-roll": pitch_roll}[pair]


def aligned_shifts(shifts: Mapping[Corner, NDArray[np.float64]]) -> NDArray[np.float64]:
    """(corners, pairs, bands): each corner's real_couplings shift times its softer signs."""
    n = len(BANDS)
    return np.array([[shifts[c][k * n : (k + 1) * n] * softer_sign(pair, c) for k, pair in enumerate(PAIRS)] for c in Corner])


def sign_table(model: str, load: str, seeds: int) -> list[str]:
    from bogiemon.lab.robust.diagnosis_check import paired_shifts

    coils = BROKEN_COILS if load == "full" else ("front_outer", "rear_outer")
    cells = [(f"type_a.{load}.{coil}", 0.0) for coil in coils]
    shifts = paired_shifts(model, load, seeds=seeds, features=real_couplings, cells=cells)
    head = "  ".join(f"{band_label(b).removesuffix(' Hz'):>7}" for b in BANDS)
    lines = [f"MODEL {model.upper()} {load}: broken coil, the shift of the real coherency times a softer corner's sign, mean over the "
             f"corners and {seeds} seeds ('*': a corner's sign differs); + means it reads as its own corner softening, - as the diagonal one",
             f"  {'coil':12} {'pair':13} {head}"]  # fmt: skip
    for (key, _), per in shifts.items():
        aligned = aligned_shifts(per)
        mean = aligned.mean(axis=0)
        agree = np.all(np.sign(aligned) == np.sign(mean), axis=0)
        for k, pair in enumerate(PAIRS):
            cols = "  ".join(f"{m:+6.3f}{' ' if a else '*'}" for m, a in zip(mean[k], agree[k], strict=True))
            lines.append(f"  {key.split('.')[2]:12} {pair:13} {cols}")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--data", type=Path, help="a data file of `bogiemon evaluate --transfer --data`: the visibility on its training fleets")
    parser.add_argument("--signs", action="store_true", help="the corner's sign table on the nominal wagon (simulates)")
    parser.add_argument("--model", choices=("a", "b"), action="append", help="with --signs: the wagon model (default both)")
    parser.add_argument("--seeds", type=int, default=3, help="with --signs: tracks and speeds per case (default 3)")
    args = parser.parse_args(argv)
    if not args.data and not args.signs:
        parser.error("give --data FILE, --signs or both")
    if args.data:
        from bogiemon.lab.robust.evaluate import EvaluateError, read_cache

        try:
            cached = read_cache(args.data)
        except EvaluateError as exc:
            print(f"observability: error: {exc}", file=sys.stderr)
            return 2
        for model, data in (cached.items() if isinstance(cached, dict) else [(cached.plan.model, cached)]):
            print("\n".join(visibility_table(model, visibility(data))))
    if args.signs:
        for model in args.model or ("a", "b"):
            for load in ("full", "tare"):
                print("\n".join(sign_table(model, load, args.seeds)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
