"""Diagnosis of a confirmed fault: the likely corner and kind, with a confidence, or "unknown".

A fault at one corner couples the frame's modes in a pattern set by where the corner is: the
sign of the pitch-roll coupling follows the product of the corner's x and y (the diagonal pair
LL/TR against LR/TL), the bounce-roll coupling its side, and the band where each appears how the
corner's damper sticks or slides compared with the other three. A stiffer corner and a softer one
at the diagonally opposite corner share their signs, so the bands decide between them.

The judgement compares the whitened coupling shift of the windows that confirmed the alarm (the
mean of their z = L (x - center)) with each shipped signature, the mean shift of one fault class
at one corner on the training fleet, as unit vectors: the cosine c_j. A softmax over the
signatures, p_j = exp(kappa c_j) / sum_k exp(kappa c_k), gives each corner's and each kind's
probability as the sum over its signatures. Below the shipped minimum confidence the answer is
"unknown": a shift that matches no signature well, or two corners about equally.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.daemon.models import KINDS, UNKNOWN, SignatureSet

CORNER_NAMES = ("leading-left", "leading-right", "trailing-left", "trailing-right")


@dataclass(frozen=True)
class Diagnosis:
    corner: str  # a corner's name or "unknown"
    kind: str  # "spring-softer", "spring-stiffer", "friction" or "unknown"
    corner_confidence: float  # the probability of the most likely corner
    kind_confidence: float
    best_match: str  # the label of the closest signature
    cosine: float  # its cosine similarity
    windows: int  # how many windows' shifts were averaged

    def as_dict(self) -> dict[str, object]:
        return {
            "corner": self.corner,
            "kind": self.kind,
            "corner_confidence": round(self.corner_confidence, 3),
            "kind_confidence": round(self.kind_confidence, 3),
            "best_match": self.best_match,
            "cosine": round(self.cosine, 3),
            "windows": self.windows,
        }


NO_EVIDENCE = Diagnosis(UNKNOWN, UNKNOWN, 0.0, 0.0, "", 0.0, 0)


def diagnose(shifts: Sequence[Sequence[float]], signatures: SignatureSet) -> Diagnosis:
    """The diagnosis of the mean of some windows' whitened coupling shifts."""
    if not shifts:
        return NO_EVIDENCE
    mean = np.mean(np.asarray(shifts, dtype=np.float64), axis=0)
    norm = float(np.linalg.norm(mean))
    if not np.isfinite(norm) or norm == 0.0:
        return NO_EVIDENCE
    return _classify(mean / norm, signatures, len(shifts))


def _classify(unit: NDArray[np.float64], signatures: SignatureSet, windows: int) -> Diagnosis:
    cosines = np.array([s.direction @ unit for s in signatures.signatures])
    logits = signatures.sharpness * (cosines - cosines.max())
    p = np.exp(logits) / np.exp(logits).sum()
    corner_p = {c: float(sum(pj for pj, s in zip(p, signatures.signatures, strict=True) if s.corner == c)) for c in CORNER_NAMES}
    kind_p = {k: float(sum(pj for pj, s in zip(p, signatures.signatures, strict=True) if s.kind == k)) for k in KINDS}
    corner, corner_conf = max(corner_p.items(), key=lambda kv: kv[1])
    kind, kind_conf = max(kind_p.items(), key=lambda kv: kv[1])
    best = int(np.argmax(cosines))
    return Diagnosis(
        corner=corner if corner_conf >= signatures.min_confidence else UNKNOWN,
        kind=kind if kind_conf >= signatures.min_confidence else UNKNOWN,
        corner_confidence=corner_conf,
        kind_confidence=kind_conf,
        best_match=signatures.signatures[best].label,
        cosine=float(cosines[best]),
        windows=windows,
    )
