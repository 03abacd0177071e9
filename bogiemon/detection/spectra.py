"""Band cross-spectra of the three channels per window: the features beyond the paper's four.

The paper's indicators sum every frequency into one number; a corner fault, though, couples the
modes most in a few bands (where the faulty corner's damper sticks or slides unlike the others)
and, depending on the band, with either sign, so part of the coupling cancels in C_PR(0). The
cross-spectral matrix of a1, a2, a3 in octave bands keeps that apart, cheaply, and carries
everything else the daemon judges: the couplings of bounce, pitch and roll per band (a linear
map of this matrix), the spectral shape that tells a loaded wagon from an empty one, and the
rigid-body structure between the channels that a swapped or inverted sensor breaks.

Estimator: per hop, the hop's H high-passed samples of each channel are weighted by a periodic
Hann window w and transformed, X_i[k] = sum_n w[n] a_i[n] e^(-2 pi i k n / H); per octave band

    S_ij = 2 / (H sum(w^2)) * sum_{k: f_lo <= f_k < f_hi} X_i[k] conj(X_j[k])

(the one-sided cross-spectral density summed over the band's bins times their width: Re S_ii is
the mean square of a_i in the band, and Re S_ij its zero-lag covariance with a_j). A window's
matrix is the mean over its hops (Welch's estimate without overlap), so it uses exactly the
window's samples and is final when its last hop arrives, like the correlations. The same high-pass
runs on every channel, so its phase cancels in every S_ij.

Sign convention: S_ij = X_i conj(X_j); if a_j(t) = a_i(t - d) then Im S_ij > 0 for small d > 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy import fft
from numpy.typing import NDArray

from bogiemon.detection.kinematics import BogieGeometry

# Octave bands from the high-pass up to 64 Hz: the JUDGED bands, everything the suspension's
# features read (detection/features.py). Above that model A's frame spectrum is not representative
# (no wheelset masses, no track flexibility: docs/simulator.md), and a real wagon's is dominated by
# wheel and rail defects; no judgement of the suspension should depend on it.
JUDGED_BANDS_HZ: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0)
N_JUDGED_BANDS = len(JUDGED_BANDS_HZ) - 1
# Above them the NOISE-FLOOR bands, 64-128 Hz and the two half octaves 128-181 and 181-256 Hz (no
# bin lies beyond Nyquist: at the default 500 Hz the last one ends at 250 Hz, in the accelerometers'
# anti-alias roll-off, where a bogie frame gives least and white noise that enters after the filter
# stands out by orders of magnitude; at a lower rate the bands above Nyquist are empty). Only the
# sensor health check reads them (judgement/noise_floor.py).
BANDS_HZ: tuple[float, ...] = JUDGED_BANDS_HZ + (128.0, 181.0, 256.0)
N_BANDS = len(BANDS_HZ) - 1
# The channel pairs of the off-diagonal entries, in the order stored.
PAIRS: tuple[tuple[int, int], ...] = ((0, 1), (0, 2), (1, 2))

@dataclass(frozen=True, eq=False)
class WindowSpectra:
    """The band cross-spectral matrix of a1, a2, a3 over one window. (m/s^2)^2 per band.

    matrix[b] is the Hermitian 3 x 3 S_ij of band b = [bands_hz[b], bands_hz[b + 1]), kept as the
    one array every reader uses (read-only: a window's record never changes); power and cross are
    views of it in the shape the windows dataset stores (fleet/rows.py).
    """

    bands_hz: tuple[float, ...]
    matrix: NDArray[np.complex128]  # (n_bands, 3, 3)

    def __post_init__(self) -> None:
        if self.matrix.shape != (len(self.bands_hz) - 1, 3, 3):
            raise ValueError(f"a spectra matrix of {len(self.bands_hz) - 1} bands is (n_bands, 3, 3), got {self.matrix.shape}")
        self.matrix.flags.writeable = False

    def __eq__(self, other: object) -> bool:
        """The same bands and every entry identical (a record read back is the record written)."""
        if not isinstance(other, WindowSpectra):
            return NotImplemented
        return self.bands_hz == other.bands_hz and bool(np.array_equal(self.matrix, other.matrix, equal_nan=True))

    __hash__ = None  # type: ignore[assignment]  # equal by value, and mutable in principle: never a key

    @property
    def power(self) -> NDArray[np.float64]:
        """(n_bands, 3): S_11, S_22, S_33 per band."""
        return np.real(np.diagonal(self.matrix, axis1=1, axis2=2))

    @property
    def cross(self) -> NDArray[np.complex128]:
        """(n_bands, 3): S_12, S_13, S_23 per band (PAIRS' order)."""
        return np.stack([self.matrix[:, i, j] for i, j in PAIRS], axis=1)

    @classmethod
    def from_parts(cls, power: NDArray[np.float64], cross: NDArray[np.complex128], bands_hz: tuple[float, ...] = BANDS_HZ) -> WindowSpectra:
        """The matrix from its diagonal (n_bands, 3) and upper triangle (n_bands, 3), as stored."""
        n = power.shape[0]
        matrix = np.zeros((n, 3, 3), dtype=np.complex128)
        for c in range(3):
            matrix[:, c, c] = power[:, c]
        for p, (i, j) in enumerate(PAIRS):
            matrix[:, i, j] = cross[:, p]
            matrix[:, j, i] = np.conj(cross[:, p])
        return cls(tuple(float(b) for b in bands_hz), matrix)


def band_bins(n_fft: int, fs_hz: float, bands_hz: tuple[float, ...] = BANDS_HZ) -> NDArray[np.intp]:
    """For each rfft bin of an n_fft-point transform, its band index, or -1 outside every band."""
    freqs = np.fft.rfftfreq(n_fft, 1.0 / fs_hz)
    index = np.searchsorted(np.asarray(bands_hz), freqs, side="right") - 1
    index[(freqs < bands_hz[0]) | (freqs >= bands_hz[-1])] = -1
    return index.astype(np.intp)


def hann_periodic(n: int) -> NDArray[np.float64]:
    """The periodic Hann window of n >= 2 samples, 0.5 - 0.5 cos(2 pi k / n).

    What scipy.signal.get_window("hann", n) returns: periodic rather than symmetric, the window
    for spectral analysis (its n-point DFT has only three non-zero bins).
    """
    return 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(n) / n)


class WindowedSpectra:
    """Feed whole hops of (hop_n, 3) conditioned samples; after a full window, each hop returns it."""

    def __init__(self, hops_per_window: int, hop_n: int, fs_hz: float, bands_hz: tuple[float, ...] = BANDS_HZ) -> None:
        if hops_per_window < 1 or hop_n < 2:
            raise ValueError(f"need at least one hop per window and two samples per hop, got {hops_per_window}, {hop_n}")
        self.hops_per_window = hops_per_window
        self.hop_n = hop_n
        self.bands_hz = tuple(float(b) for b in bands_hz)
        self._taper = hann_periodic(hop_n)
        self._scale = 2.0 / (hop_n * float(np.sum(self._taper**2)))
        bins = band_bins(hop_n, fs_hz, self.bands_hz)
        n_bands = len(self.bands_hz) - 1
        # Band sums with np.add.reduceat over each band's run of bins (the bands are contiguous),
        # never a BLAS product: a (bands x bins) product past OpenBLAS's threading threshold
        # (m n k of about 2^18, crossed at 10 bands) woke its worker pool, which then spun a core
        # for tens of milliseconds after every hop (README, Performance).
        inside = np.flatnonzero(bins >= 0)
        counts = np.bincount(bins[inside], minlength=n_bands)
        # A hop too short for any band (a few samples) keeps every band at zero.
        self._bins = slice(int(inside[0]), int(inside[-1]) + 1) if inside.size else slice(0, 0)
        self._nonempty = counts > 0  # bands above Nyquist at a low rate hold no bin
        self._starts = (np.cumsum(counts) - counts)[self._nonempty]
        # The one-sided density doubles every bin but DC and (for an even hop) Nyquist, which
        # have no mirror image.
        weight = np.full(bins.size, self._scale)
        weight[0] *= 0.5
        if hop_n % 2 == 0:
            weight[-1] *= 0.5
        self._weight = weight[self._bins, None]
        # Per hop and band, the matrix's six distinct entries (_ENTRIES): the lower triangle is the
        # upper's conjugate, and a window's record is built from these (WindowSpectra.from_parts).
        self._hops = np.zeros((hops_per_window, n_bands, len(_ENTRIES)), dtype=np.complex128)
        self._n_hops = 0

    def reset(self) -> None:
        self._n_hops = 0

    def push_hop(self, hop: NDArray[np.float64]) -> WindowSpectra | None:
        spec = fft.rfft(hop * self._taper[:, None], axis=0)[self._bins]  # (bins in a band, 3)
        # Channel-major, each entry one product of contiguous rows: half the time of the (bins, 3, 3)
        # broadcast, and the same products, bit for bit.
        weighted = np.ascontiguousarray((spec * self._weight).T)
        conjugate = np.conj(np.ascontiguousarray(spec.T))
        products = np.empty((spec.shape[0], len(_ENTRIES)), dtype=np.complex128)  # (bins, entries)
        for k, (i, j) in enumerate(_ENTRIES):
            np.multiply(weighted[i], conjugate[j], out=products[:, k])
        slot = self._n_hops % self.hops_per_window
        self._hops[slot] = 0.0
        if self._starts.size:
            self._hops[slot, self._nonempty] = np.add.reduceat(products, self._starts, axis=0)
        self._n_hops += 1
        if self._n_hops < self.hops_per_window:
            return None
        # Exactly Hermitian, from the diagonal's real part and the upper triangle: the sums leave a
        # power an imaginary part of 1e-25, and a stored record (fleet/rows.py keeps just these)
        # reads back identical.
        mean = self._hops.mean(axis=0)
        return WindowSpectra.from_parts(np.real(mean[:, _DIAGONAL]), mean[:, _UPPER], self.bands_hz)


# The entries of a band's matrix kept per hop: the diagonal and the upper triangle (PAIRS' order).
_ENTRIES: tuple[tuple[int, int], ...] = ((0, 0), (1, 1), (2, 2), *PAIRS)
_DIAGONAL = [0, 1, 2]
_UPPER = [3, 4, 5]


# --------------------------------------------------------------------------------------------
# Derived features: pure functions of a window's matrix.


def modal_spectra(matrix: NDArray[np.complex128], geometry: BogieGeometry) -> NDArray[np.complex128]:
    """(n_bands, 3, 3) cross-spectra of a_bounce, a_pitch, a_roll: T S T^T with T the modal matrix."""
    t = geometry.modal_matrix()
    return np.einsum("ai,bij,cj->bac", t, matrix, t)


def coherency(matrix: NDArray[np.complex128]) -> NDArray[np.complex128]:
    """S_ij / sqrt(S_ii S_jj) per band: complex, |.| <= 1; NaN where a channel has no power."""
    power = np.real(np.diagonal(matrix, axis1=1, axis2=2))
    with np.errstate(invalid="ignore", divide="ignore"):
        norm = np.sqrt(power[:, :, None] * power[:, None, :])
        return np.where(norm > 0, matrix / np.where(norm > 0, norm, 1.0), np.nan)
