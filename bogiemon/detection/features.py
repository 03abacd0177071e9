"""Features of one window derived from its band cross-spectra: couplings, load shape, layout checks.

Pure functions of a WindowSpectra and the sensors' geometry (numpy only), used by the daemon's
judgement and by the evaluation that fits its models. None of them is a fast path: each is a
few small matrix products per window, on the 3 x 3 band matrices the core already keeps.

Bands are detection.spectra.BANDS_HZ: 0 = 0.5-1 Hz, 1 = 1-2, 2 = 2-4, 3 = 4-8, 4 = 8-16,
5 = 16-32, 6 = 32-64 Hz, the judged ones; 7 = 64-128, 8 = 128-181 and 9 = 181-256 Hz, the
noise-floor bands, are read by the sensor health check alone (judgement/health.py).
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection.kinematics import BogieGeometry
from bogiemon.detection.spectra import BANDS_HZ, N_JUDGED_BANDS, WindowSpectra, coherency, modal_spectra

# Modal indices in the modal cross-spectral matrix.
BOUNCE, PITCH, ROLL = 0, 1, 2

# The coupling vector judged by the fused score: the zero-lag coherency (real part) of pitch and
# roll and of bounce and roll in the bands from 2 to 64 Hz. Below 2 Hz the frame follows the
# carbody's modes, where a corner fault shows little and the estimates scatter most. Bounce and
# pitch are left out: below 16 Hz their coupling carries the wheelbase delay of the track input,
# which flips with the direction of travel, and above it the sensors' gain errors dominate it
# (docs/robust/README.md, "Choosing the features").
COUPLING_FEATURES: tuple[tuple[str, int, int, int], ...] = tuple(
    [(f"c_pr_{b}", PITCH, ROLL, b) for b in range(2, 7)] + [(f"c_br_{b}", BOUNCE, ROLL, b) for b in range(2, 7)]
)
COUPLING_NAMES: tuple[str, ...] = tuple(name for name, *_ in COUPLING_FEATURES)

# The load-state features: log share of a mode's power in one band, of its power over all bands.
LOAD_FEATURES: tuple[tuple[str, int, int], ...] = tuple(
    (f"{mode}_share_{b}", m, b) for m, mode in enumerate(("bounce", "pitch", "roll")) for b in range(N_JUDGED_BANDS)
)
LOAD_NAMES: tuple[str, ...] = tuple(name for name, *_ in LOAD_FEATURES)


def band_label(band: int) -> str:
    return f"{BANDS_HZ[band]:g}-{BANDS_HZ[band + 1]:g} Hz"


class WindowFeatures:
    """The features of one window's spectra for one sensor geometry, each computed once, when first
    read: the daemon judges a window by several of them (load, couplings, sensor checks), all from
    the same modal cross-spectra."""

    def __init__(self, spectra: WindowSpectra, geometry: BogieGeometry) -> None:
        self.spectra = spectra
        self.geometry = geometry

    @functools.cached_property
    def modal(self) -> NDArray[np.complex128]:
        """(n_bands, 3, 3) cross-spectra of a_bounce, a_pitch, a_roll."""
        return modal_spectra(self.spectra.matrix, self.geometry)

    @functools.cached_property
    def modal_coherency(self) -> NDArray[np.complex128]:
        """(n_bands, 3, 3) coherency of a_bounce, a_pitch, a_roll per band."""
        return coherency(self.modal)

    @functools.cached_property
    def coupling(self) -> NDArray[np.float64]:
        """The COUPLING_FEATURES, in that order (NaN where a mode has no power)."""
        coh = self.modal_coherency
        return np.array([coh[b, i, j].real for _, i, j, b in COUPLING_FEATURES])

    @functools.cached_property
    def load(self) -> NDArray[np.float64]:
        """The LOAD_FEATURES: log(mode power in band / mode power in all judged bands)."""
        power = np.real(np.diagonal(self.modal[:N_JUDGED_BANDS], axis1=1, axis2=2))  # (bands, 3)
        with np.errstate(divide="ignore", invalid="ignore"):
            share = np.log(power / power.sum(axis=0, keepdims=True))
        return np.array([share[b, m] for _, m, b in LOAD_FEATURES])


def modal_coherency(spectra: WindowSpectra, geometry: BogieGeometry) -> NDArray[np.complex128]:
    """(n_bands, 3, 3) coherency of a_bounce, a_pitch, a_roll per band."""
    return WindowFeatures(spectra, geometry).modal_coherency


def coupling_vector(spectra: WindowSpectra, geometry: BogieGeometry) -> NDArray[np.float64]:
    """The COUPLING_FEATURES of one window, in that order (NaN where a mode has no power)."""
    return WindowFeatures(spectra, geometry).coupling


def load_vector(spectra: WindowSpectra, geometry: BogieGeometry) -> NDArray[np.float64]:
    """The LOAD_FEATURES of one window: log(mode power in band / mode power in all judged bands)."""
    return WindowFeatures(spectra, geometry).load


# --------------------------------------------------------------------------------------------
# The sensor layout: does the data have the rigid-body structure the configured corners imply?

# Bands of each check (module docstring of judgement/health.py says why these).
LOW_BANDS = (0, 1)  # 0.5-2 Hz: the frame follows the carbody, every corner moves alike
HIGH_BANDS = (5, 6)  # 16-64 Hz: the frame pitches and rolls about its centre, held by the bowl
QUADRATURE_BANDS = (0, 1, 2)  # 0.5-4 Hz: the wheelbase delay couples bounce and pitch


@dataclass(frozen=True)
class LayoutStatistics:
    """What the layout checks look at, for one window and one assignment of channels to corners.

    low_coherence[i]: the larger of channel i's two pair coherences (real part) at 0.5-2 Hz,
    positive when every channel reads the same way up; diagonal_coherence: of the pair at
    diagonal corners, at 16-64 Hz, near -1 (a frame rotating about its centre moves diagonal
    corners in opposition); other_coherence: the smaller of the other two pairs' there;
    quadrature_bp, quadrature_br: |imaginary coherency| of bounce with pitch and with roll at
    0.5-4 Hz (bounce and pitch share the rails' input, delayed by the wheelbase; roll does not).
    """

    low_coherence: tuple[float, float, float]
    diagonal_coherence: float
    other_coherence: float
    quadrature_bp: float
    quadrature_br: float


def diagonal_pair(geometry: BogieGeometry) -> tuple[int, int]:
    """The two channels at diagonal corners (different axle and rail)."""
    c = geometry.corners
    for i, j in ((0, 1), (0, 2), (1, 2)):
        if c[i].x_sign != c[j].x_sign and c[i].y_sign != c[j].y_sign:
            return i, j
    raise AssertionError("three corners of a rectangle always include a diagonal pair")  # pragma: no cover


def layout_statistics(
    matrix: NDArray[np.complex128], geometry: BogieGeometry, mapping: Sequence[int] = (0, 1, 2), signs: Sequence[float] = (1.0, 1.0, 1.0)
) -> LayoutStatistics:
    """The layout statistics if channel mapping[i] were at corner i with sign signs[i].

    matrix: the window's (n_bands, 3, 3) band cross-spectra of the channels as received.
    """
    p = np.zeros((3, 3))
    for i, (m, s) in enumerate(zip(mapping, signs, strict=True)):
        p[i, m] = s
    s_mat = np.einsum("ai,bij,cj->bac", p, matrix, p)
    coh = coherency(s_mat).real
    low = coh[list(LOW_BANDS)].mean(axis=0)
    low_per_channel = tuple(float(max(low[i, j] for j in range(3) if j != i)) for i in range(3))
    high = coh[list(HIGH_BANDS)].mean(axis=0)
    d = diagonal_pair(geometry)
    others = [high[i, j] for i, j in ((0, 1), (0, 2), (1, 2)) if (i, j) != d]
    mcoh = coherency(modal_spectra(s_mat, geometry))
    q = list(QUADRATURE_BANDS)
    return LayoutStatistics(
        low_coherence=(low_per_channel[0], low_per_channel[1], low_per_channel[2]),
        diagonal_coherence=float(high[d]),
        other_coherence=float(min(others)),
        quadrature_bp=float(np.abs(mcoh[q, BOUNCE, PITCH].imag).mean()),
        quadrature_br=float(np.abs(mcoh[q, BOUNCE, ROLL].imag).mean()),
    )

