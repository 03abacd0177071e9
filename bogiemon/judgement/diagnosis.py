"""Diagnosis of a confirmed fault from the bogie's geometry: the corner, or "unknown".

No pattern fitted on a model: the corner follows from the signs of the coupling shift that
confirmed the alarm, read where rigid-body mechanics fixes them.

THE SIGN RELATION. A corner at (x_c, y_c) of the frame (x towards the leading axle, y towards the
left rail: detection/kinematics.py) whose vertical stiffness changes by dK adds dK g g^T to the
frame's stiffness in (bounce, pitch, roll), g = (1, x_c, y_c): a pitch-roll term dK x_c y_c and a
bounce-roll term dK y_c, nothing else off the diagonal. Well below the frame's own pitch and roll
modes the frame's response is its compliance times what drives it; to first order the change of
compliance is -K^-1 dK g g^T K^-1, so a softer corner (dK < 0) moves more, and with it the frame
pitches and rolls towards it: the modal accelerations acquire correlations of the signs

    sign(c_pr shift) = sign(x_c y_c),   sign(c_br shift) = sign(y_c)        (a softer corner)

and both flipped for a stiffer one. Above a frame mode the response's phase turns by 180 degrees
and so do the signs; at a mode the coupling is in quadrature and its real part says nothing.
Healthy, the frame is symmetric and both shifts are zero in expectation.

What it cannot tell. Mirroring the frame across the track (y -> -y) maps a corner onto its
neighbour on the same axle and flips both couplings (each holds roll once), so to first order a
corner that got softer gives exactly the shift of its neighbour across the track getting stiffer
by as much. The pitch-roll term adds a second catch: when the frame's pitch and roll stiffness
come from the primary springs alone (a Y25 at full load, its dampers stuck), its first-order part
cancels (the change only feeds the frame's warp, which rigid-body pitch and roll do not see) and
the second-order part, of sign x_c y_c whatever the sign of dK, remains. The couplings judged
here therefore fix the corner only up to the sign of the change; the corner named is the one
that got softer in effect: a broken or sagging spring, or a damper that grips less and slides
where the others stick (friction dominates the corner's effective stiffness whenever the dampers
stick, and on a Y25 a broken front coil raises the Lenoir damper's grip: that corner can read as
stiffer). The kind is therefore "unknown": these couplings tell neither the sign of dK nor a spring
from a damper.

THE BANDS (SIGN_BANDS, per load state): where the relation holds, below the frame's pitch and roll
modes in every friction regime, and away from the wheelbase delay. That is 4-8 Hz in both load
states: model A's frame pitches and rolls near 38 Hz at full load and 36 Hz in tare with its
dampers stuck (Kz + k_stick), near 13 Hz and 8-9 Hz with them sliding (docs/simulator.md), and
model B's, built independently, keeps the same signs there (below). Below 4 Hz the wheelbase delay
of the rails' input couples bounce and pitch with a sign that flips with the direction of travel
and leaks into both couplings; above 8 Hz lies a mode of one regime or the other, and there the
signs depend on the wagon: model A's full-load faults keep them at 16-32 Hz, model B's do not, and
the tare faults of both take the flipped sign of a frame above its modes. Chosen on the training
fleets of both wagon models (lab/robust: never their evaluation fleets): reading 4-8 Hz alone named
19 of 37 confirmed broken springs right and none wrong, where 4-8 and 16-32 Hz at full load (the
earlier choice, from model A alone) named 17 right and 4 wrong, all on model A's full load.
`python -m bogiemon.lab.robust.diagnosis_check --linear` gives the signs of the linearised model A
band by band (both regimes, softer and stiffer), `--shifts` those of the simulated faults, and
without either it measures the rule on simulated fleets.

THE EVIDENCE. The mean raw shift d = mean(x - center) of the windows that confirmed (x - center =
L^-1 z from their whitened shifts z), or the trend's mean shift. Its uncertainty is the healthy
spread of the baseline, covariance C = (L^T L)^-1, which averaging a few consecutive, overlapping
windows does not reduce (the healthy wagon's offset moves with track and speed, not from window to
window), plus the scatter of the confirming windows' own shifts over their number; the trend's
mean averages half an hour of running, and its healthy spread is C times the ratio of the trend's
alarm level to the window score's (both set on the same healthy fleet). Per coupling (pitch-roll,
bounce-roll), the bands' shifts in units of their healthy spread are summed, and the sum's
standard score T (over its standard deviation, from the same covariance: the bands are
correlated) says how clear its sign is.

THE PAIR. The pitch-roll sign is x_c y_c whatever the sign of the change (above): it fixes the
diagonal the corner lies on, {leading-left, trailing-right} or {leading-right, trailing-left}. The
bounce-roll sign, y_c for a softer corner, would pick one of the two, but on a Y25 a broken front
coil makes its corner stiffer in effect (its Lenoir damper grips more) and gives the bounce-roll
sign of a broken rear coil at the diagonally opposite corner: measured on both wagon models' fleets
(lab/robust/observability.py, `--signs`: every band from 2 to 64 Hz, at full load and in tare but
for two band-pairs where the front coil's shift is small), and met on the independently built
model too, where every wrong corner named was exactly the diagonal one. No rule on these signs
can be right for the front and the rear coils alike, so the diagnosis names the pair when the
pitch-roll sign is clear (|T_pr| at least MIN_SCORE, no read band against it by more than
CONTRADICTION standard deviations), "unknown" otherwise, and never one corner alone; the
bounce-roll sign stays in best_match as the corner that softened if it did. What tells the two
corners of a pair apart is a measurement these three accelerometers do not make (the static sag
at each axle box, or the dampers' force).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.models import UNKNOWN, Baseline
from bogiemon.detection.features import BOUNCE, COUPLING_FEATURES, PITCH, band_label
from bogiemon.detection.kinematics import Corner

# The bands (detection.spectra.BANDS_HZ indices) where the sign relation is read, per load state
# (the module docstring says why these).
SIGN_BANDS: Mapping[str, tuple[int, ...]] = {"full": (3,), "tare": (3,)}
# A sign is clear at this standard score: healthy scatter of the stated spread reads a sign wrong
# with probability 0.6 % (the one-sided normal tail), both of a corner's at most 1.2 %, a quarter
# of the 5 % of wrong corners issue 16 allows, the rest left for the physics' own exceptions.
MIN_SCORE = 2.5
# A read band whose shift lies this many of its standard deviations against its coupling's sign
# contradicts it: the bands disagree and the corner is unknown.
CONTRADICTION = 1.0
# The largest confidence a pair is given. On the independent wagon model (issue 26's probe) every
# one of the 17 confirmed broken springs that named a corner named it or its diagonal opposite: the
# pair held the corner 17 times in 17. Laplace's rule of succession makes that (17 + 1) / (17 + 2)
# = 0.947, not 1: a clear sign is never a certainty about another wagon. The transfer evaluation
# (docs/robust/transfer) reports the share measured on both models beside it.
PAIR_CONFIDENCE_MAX = 0.95


@dataclass(frozen=True)
class Diagnosis:
    """What the couplings say about a confirmed fault (a CONFIRMED event's diagnosis).

    corners: the corners it could be, as the signs fix them: () unknown; a diagonal pair (the
        pitch-roll sign alone: THE PAIR in the module docstring), the corner that softened in
        effect first; never one corner alone (the bounce-roll sign that would pick it is the one a
        broken front coil turns round: measured, module docstring). An event stored by a version
        before the pair may name one corner.
    kind: always "unknown" from these couplings (module docstring); the field stays for the schema
        (an event stored by an older version may name one).
    corner_confidence: the probability that the fault's corner is among `corners`: that healthy
        scatter of the stated spread did not flip the pitch-roll sign, Phi(|T_pr|), never above
        PAIR_CONFIDENCE_MAX (what the pair was measured to hold on another wagon model, so that a
        sign read clearly is never a certainty about the wagon). 0 without evidence; for an
        unknown corner, that of the likeliest pair (bands that disagree can leave it high).
    kind_confidence: 0.0 (no kind is told).
    best_match: the statistic in words, e.g. "pitch-roll +4.1, bounce-roll +3.2 sd at 4-8 Hz:
        leading-left or trailing-right (leading-left if softer)"; for an unknown corner why no pair
        is named, and never a pair ("pitch-roll -0.2, bounce-roll +1.1 sd at 4-8 Hz: the pitch-roll
        sign is within the noise (under 2.5 sd), no pair named"); "" without evidence.
    cosine: the agreement of the read bands with the likeliest corner's sign pattern: the cosine
        between the bands' standard scores and those signs, 1 when every band has the predicted
        sign, below 0 when most disagree.
    windows: how many windows' shifts were averaged (1 for the trend's mean).
    """

    corners: tuple[Corner, ...]
    kind: str
    corner_confidence: float
    kind_confidence: float
    best_match: str
    cosine: float
    windows: int

    @property
    def corner(self) -> str:
        """The corners in words: "unknown", or "leading-left or trailing-right"."""
        return " or ".join(c.value for c in self.corners) if self.corners else UNKNOWN

    def stated(self) -> Diagnosis:
        """The diagnosis as an event states it: the confidences and the cosine to 3 decimals."""
        return dataclasses.replace(
            self, corner_confidence=round(self.corner_confidence, 3), kind_confidence=round(self.kind_confidence, 3), cosine=round(self.cosine, 3)
        )


NO_EVIDENCE = Diagnosis((), UNKNOWN, 0.0, 0.0, "", 0.0, 0)


def softer_signs(corner: Corner) -> tuple[int, int]:
    """The signs (pitch-roll, bounce-roll) of the coupling shift of a corner that got softer."""
    return corner.x_sign * corner.y_sign, corner.y_sign


def corner_of(pr_sign: int, br_sign: int) -> Corner:
    """The corner whose softening gives these signs of the pitch-roll and bounce-roll shifts."""
    return next(c for c in Corner if softer_signs(c) == (pr_sign, br_sign))


@dataclass(frozen=True)
class SignEvidence:
    """The sign statistics of one coupling shift: per coupling its standard score T and the read
    bands' own standard scores (in SIGN_BANDS order)."""

    bands: tuple[int, ...]
    score_pr: float
    score_br: float
    band_scores_pr: tuple[float, ...]
    band_scores_br: tuple[float, ...]


def sign_evidence(
    shift: NDArray[np.float64], error_covariance: NDArray[np.float64], healthy_covariance: NDArray[np.float64], bands: Sequence[int]
) -> SignEvidence:
    """The standard scores of a raw coupling shift (COUPLING_FEATURES order) in the given bands.

    error_covariance: the shift's uncertainty; healthy_covariance: the baseline's spread, whose
    standard deviations weigh the bands (each band's shift counts in units of its healthy spread).
    """
    scale = np.sqrt(np.diag(healthy_covariance))
    sd = np.sqrt(np.diag(error_covariance))
    out: dict[int, tuple[float, tuple[float, ...]]] = {}
    for mode in (PITCH, BOUNCE):
        index = [k for k, (_, i, j, b) in enumerate(COUPLING_FEATURES) if i == mode and b in bands]
        w = np.zeros(shift.size)
        w[index] = 1.0 / scale[index]
        spread = math.sqrt(float(w @ error_covariance @ w))
        out[mode] = (float(w @ shift) / spread, tuple(float(shift[k] / sd[k]) for k in index))
    return SignEvidence(tuple(bands), out[PITCH][0], out[BOUNCE][0], out[PITCH][1], out[BOUNCE][1])


def _phi(t: float) -> float:
    return 0.5 * (1.0 + math.erf(t / math.sqrt(2.0)))


def diagonal_of(corner: Corner) -> Corner:
    """The corner across the frame's centre from corner (x -> -x, y -> -y)."""
    return next(c for c in Corner if c.x_sign == -corner.x_sign and c.y_sign == -corner.y_sign)


def judge_signs(evidence: SignEvidence, windows: int) -> Diagnosis:
    """The diagonal pair from sign evidence, or unknown (module docstring: MIN_SCORE, CONTRADICTION)."""
    t_pr, t_br = evidence.score_pr, evidence.score_br
    pr_sign, br_sign = (1 if t_pr >= 0 else -1), (1 if t_br >= 0 else -1)
    likeliest = corner_of(pr_sign, br_sign)
    scores = np.array(evidence.band_scores_pr + evidence.band_scores_br)
    predicted = np.array([pr_sign] * len(evidence.band_scores_pr) + [br_sign] * len(evidence.band_scores_br), dtype=np.float64)
    norm = float(np.linalg.norm(scores))
    cosine = float(scores @ predicted) / (norm * math.sqrt(predicted.size)) if norm > 0 else 0.0
    pr_against = np.array(evidence.band_scores_pr) * pr_sign
    # The pair needs the pitch-roll sign alone, clear and not contradicted by a band it reads.
    clear = abs(t_pr) >= MIN_SCORE and bool(np.all(pr_against > -CONTRADICTION))
    pair = (likeliest, diagonal_of(likeliest))
    bands = ", ".join(band_label(b).removesuffix(" Hz") for b in evidence.bands)
    read = f"pitch-roll {t_pr:+.1f}, bounce-roll {t_br:+.1f} sd at {bands} Hz"
    if clear:
        described = f"{read}: {pair[0].value} or {pair[1].value} ({likeliest.value} if softer)"
    elif not bool(np.all(pr_against > -CONTRADICTION)):
        # An unknown corner names no pair: a sign read within the noise would point at one.
        described = f"{read}: a band contradicts the pitch-roll sign, no pair named"
    else:
        described = f"{read}: the pitch-roll sign is within the noise (under {MIN_SCORE:g} sd), no pair named"
    return Diagnosis(
        corners=pair if clear else (),
        kind=UNKNOWN,
        corner_confidence=min(_phi(abs(t_pr)), PAIR_CONFIDENCE_MAX),
        kind_confidence=0.0,
        best_match=described,
        cosine=cosine,
        windows=windows,
    )


def raw_shift(baseline: Baseline, whitened: NDArray[np.float64]) -> NDArray[np.float64]:
    """x - center from z = L (x - center)."""
    return np.linalg.solve(baseline.whitening, whitened).astype(np.float64, copy=False)


def healthy_covariance(baseline: Baseline) -> NDArray[np.float64]:
    """The baseline's spread of x around its center: (L^T L)^-1."""
    inverse = np.linalg.inv(baseline.whitening)
    return inverse @ inverse.T


def diagnose(shifts: Sequence[Sequence[float] | NDArray[np.float64]], baseline: Baseline, load: str, trend: bool = False) -> Diagnosis:
    """The diagnosis from whitened coupling shifts z = L (x - center) of `baseline`.

    shifts: the confirming windows' shifts, or (trend=True) the one mean shift of the trend.
    load: the load state they were judged in, which chooses the bands (SIGN_BANDS).
    """
    bands = SIGN_BANDS.get(load)
    z = np.asarray(shifts, dtype=np.float64)
    if bands is None or z.ndim != 2 or z.shape[0] == 0 or z.shape[1] != len(COUPLING_FEATURES) or not np.all(np.isfinite(z)):
        return NO_EVIDENCE
    raw = np.array([raw_shift(baseline, row) for row in z])
    healthy = healthy_covariance(baseline)
    if trend:
        error = healthy * (baseline.levels.trend_alarm / baseline.levels.alarm)
    else:
        error = healthy + (np.cov(raw, rowvar=False) / raw.shape[0] if raw.shape[0] > 1 else 0.0)
    return judge_signs(sign_evidence(raw.mean(axis=0), error, healthy, bands), raw.shape[0])
