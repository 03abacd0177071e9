"""Signal conditioning: gravity/drift removal and the 10 Hz low-pass of indicator 3, streaming.

Why a high-pass rather than subtracting each window's mean: the mean of a 60 s window still
carries sensor drift and the slow part of the gravity projection, and it is not a streaming
operation (each window would need its own offset, so block products could not be shared between
overlapping windows). A causal 2nd-order Butterworth high-pass at 0.5 Hz removes the 9.81 m/s^2
offset and any drift slower than a few seconds, and passes the bogie frame's content (carbody
modes from ~1.5 Hz, primary suspension and wheelset modes from ~5 Hz up) within 3 % at 1 Hz.
The same filter runs on every channel, so in every cross-spectrum its phase cancels and only
|H(f)|^2 weights the correlations: no lag error is introduced. The filter's state starts at
steady state for the first sample, so the gravity step at start-up causes no transient.

Why the filters are designed and run here rather than by scipy.signal: importing scipy.signal
imports scipy.stats, which costs a gateway about 45 MiB of memory and a second of start-up for
three functions. The design is scipy's (the Butterworth prototype, the pre-warped bilinear
transform, the 'nearest' pairing into sections); tests/detection/test_filters.py checks it,
sosfilt_zi and the streaming filter against scipy.signal.
"""

from __future__ import annotations

from decimal import Decimal, localcontext

import numpy as np
from numpy.typing import NDArray

# Samples per chunk of the streaming filter: each output costs CHUNK_N + 2 n_states
# multiply-adds in matrix products, each chunk a few more in the scan. Of 16 to 128, 32 was the
# fastest overall for 1 s and 10 s blocks at 200 Hz to 2 kHz.
CHUNK_N = 32
# OpenBLAS runs a matrix product of more than 65536 * 4 multiply-adds on several threads; for
# products this small that is seldom faster and, on a busy machine, often ten times slower.
SINGLE_THREAD_PRODUCT = 65536 * 4


def butter_sos(order: int, cutoff_hz: float, fs_hz: float, btype: str) -> NDArray[np.float64]:
    """Second-order sections of a digital Butterworth filter ('lowpass' or 'highpass').

    The same sections as scipy.signal.butter(order, cutoff_hz, btype, fs=fs_hz, output='sos'),
    in the same order (the poles nearest the unit circle last), with the gain in the first section.
    """
    nyquist_hz = fs_hz / 2.0
    if not 0.0 < cutoff_hz < nyquist_hz:
        raise ValueError(f"cutoff {cutoff_hz} Hz must lie between 0 and Nyquist ({nyquist_hz} Hz)")
    if order < 1:
        raise ValueError(f"filter order must be >= 1, got {order}")
    if btype not in ("lowpass", "highpass"):
        raise ValueError(f"filter type must be 'lowpass' or 'highpass', got {btype!r}")
    lowpass = btype == "lowpass"
    # The analog prototype's poles, -exp(i pi m / 2N), m = -N+1, -N+3, ..., N-1, on the left half
    # of the unit circle; m < 0 are the upper halves of the conjugate pairs, m = 0 the real pole.
    m = np.arange(-order + 1, order, 2)
    prototype = -np.exp(1j * np.pi * m / (2 * order))
    # The cutoff pre-warped so that the bilinear transform z = (1 + s) / (1 - s) (s in units of
    # 2 fs) puts it at cutoff_hz exactly.
    warped = np.tan(np.pi * cutoff_hz / fs_hz)
    analog = warped * prototype if lowpass else warped / prototype
    poles = (1.0 + analog) / (1.0 - analog)
    zero = -1.0 if lowpass else 1.0  # all N zeros: at Nyquist for a low-pass, at DC for a high-pass
    complex_poles = list(_sorted_as_scipy(poles[m < 0]))
    real_poles = [float(p.real) for p in poles[m == 0]]
    zeros = [zero] * order
    if order % 2:
        # The real pole's section gets a pole and a zero at the origin, as scipy pads it.
        real_poles = sorted([*real_poles, 0.0])
        zeros.append(0.0)
    sections = _pair_nearest(complex_poles, real_poles, zeros)
    sos = np.array([np.concatenate([np.poly(z).real, np.poly(p).real]) for z, p in sections])
    # Unit gain where the filter passes, DC for a low-pass and Nyquist for a high-pass (z = -zero:
    # z^-1 = -zero, z^-2 = 1), set on the coefficients as rounded: scipy's gain, from the poles,
    # misses 1 by up to 4e-10 when the cutoff is 1e-4 fs.
    at_pass = np.array([1.0, -zero, 1.0])
    sos[0, :3] *= float(np.prod(sos[:, 3:] @ at_pass) / np.prod(sos[:, :3] @ at_pass))
    return sos


def _sorted_as_scipy(poles: NDArray[np.complex128]) -> NDArray[np.complex128]:
    # zpk2sos sees the upper halves of the pairs sorted by real part, then |imag|: the order its
    # ties are broken in.
    return poles[np.lexsort((np.abs(poles.imag), poles.real))]


def _pair_nearest(
    complex_poles: list[complex], real_poles: list[float], zeros: list[float]
) -> list[tuple[list[complex], list[complex]]]:
    """(zeros, poles) of each section, first to last, by scipy.signal.zpk2sos's 'nearest' rule.

    The pole nearest the unit circle goes into the last section, with its conjugate (or the next
    real pole nearest the circle) and the two zeros nearest to it; then the next, and so on. All
    zeros here are real, which leaves out the rule's cases for complex zeros.
    """
    poles: list[complex] = [*complex_poles, *real_poles]
    free_zeros = list(zeros)

    def worst(candidates: list[complex]) -> int:
        return int(np.argmin([abs(1.0 - abs(p)) for p in candidates]))

    def take_nearest_zero(p: complex) -> complex:
        return free_zeros.pop(int(np.argmin([abs(z - p) for z in free_zeros])))

    sections = []
    while poles:
        p1 = poles.pop(worst(poles))
        if isinstance(p1, complex):
            pair = [p1, p1.conjugate()]
        else:
            reals = [i for i, p in enumerate(poles) if not isinstance(p, complex)]
            pair = [p1, poles.pop(reals[worst([poles[i] for i in reals])])]
        section_zeros = [take_nearest_zero(p1) for _ in range(min(2, len(free_zeros)))]
        sections.append((section_zeros, pair))
    return sections[::-1]


def sosfilt_zi(sos: NDArray[np.float64]) -> NDArray[np.float64]:
    """(n_sections, 2) state of scipy.signal.sosfilt's sections at steady state for a unit step.

    As scipy.signal.sosfilt_zi: the state once the input has been 1 forever, in sosfilt's
    convention (transposed direct form II: y = b0 u + z1, z1' = b1 u - a1 y + z2, z2' = b2 u - a2 y).
    Each section's output level is its input level times its DC gain, sum(b) / sum(a); written
    out rather than solved, so a section with a zero at DC gives exactly zero downstream.
    """
    sos = _validated_sos(sos)
    zi = np.empty((sos.shape[0], 2))
    level = 1.0
    for k, (b0, b1, b2, _, a1, a2) in enumerate(sos):
        out = level * (b0 + b1 + b2) / (1.0 + a1 + a2)
        zi[k] = (out - b0 * level, b2 * level - a2 * out)
        level = out
    return zi


def _validated_sos(sos: NDArray[np.float64]) -> NDArray[np.float64]:
    sos = np.asarray(sos, dtype=np.float64)
    if sos.ndim != 2 or sos.shape[1] != 6 or sos.shape[0] < 1:
        raise ValueError(f"sos must have shape (n_sections, 6), got {sos.shape}")
    if not np.all(sos[:, 3] == 1.0):
        raise ValueError("sos[:, 3] (each section's a0) must be 1")
    return sos


def _section_realization(
    section: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64]]:
    """(A, B, C, d, V^-1) of one section; V^-1 takes sosfilt's state (z1, z2) to this one's.

    Complex poles sigma +- i omega get the coupled form A = [[sigma, omega], [-omega, sigma]],
    whose powers have norm |pole|^k < 1, with the state scaled so that |B| = |C|. sosfilt's own
    A = [[-a1, 1], [-a2, 0]] is far from normal when the poles are close to 1: for the 0.5 Hz
    high-pass at 2 kHz |A^32| = 62 and |A^k| reaches 580, and the chunked filter, which applies
    such powers, came out a thousand times less accurate in it. The few constants are computed
    in 40 digits from the coefficients as stored (b1 - a1 b0 cancels for a high-pass) and rounded
    once. Real poles keep sosfilt's form.
    """
    with localcontext() as ctx:
        ctx.prec = 40
        b0, b1, b2, _, a1, a2 = (Decimal(float(v)) for v in section)
        beta1, beta2 = b1 - a1 * b0, b2 - a2 * b0  # sosfilt's B
        disc = a2 - a1 * a1 / 4
        if disc <= 0:
            return (
                np.array([[-float(a1), 1.0], [-float(a2), 0.0]]),
                np.array([float(beta1), float(beta2)]),
                np.array([1.0, 0.0]),
                float(b0),
                np.eye(2),
            )
        sigma, omega = -a1 / 2, disc.sqrt()
        # sosfilt's state is V s with V = [[sigma, omega], [-a2, 0]] (the real and imaginary parts
        # of the eigenvector (lambda, -a2) of its A), before scaling.
        inv = [[Decimal(0), -1 / a2], [1 / omega, sigma / (a2 * omega)]]
        b_hat = [inv[0][1] * beta2, inv[1][0] * beta1 + inv[1][1] * beta2]
        c_hat = [sigma, omega]
        norm_b = (b_hat[0] ** 2 + b_hat[1] ** 2).sqrt()
        norm_c = (c_hat[0] ** 2 + c_hat[1] ** 2).sqrt()
        scale = (norm_b / norm_c).sqrt() if norm_b > 0 else Decimal(1)
        a_hat = np.array([[float(sigma), float(omega)], [-float(omega), float(sigma)]])
        return (
            a_hat,
            np.array([float(v / scale) for v in b_hat]),
            np.array([float(v * scale) for v in c_hat]),
            float(b0),
            np.array([[float(v / scale) for v in row] for row in inv]),
        )


def _cascade(
    sos: NDArray[np.float64],
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], float, NDArray[np.float64]]:
    """(A, B, C, D, V^-1) of the sections in series; states section by section, two each."""
    n_states = 2 * sos.shape[0]
    a = np.zeros((n_states, n_states))
    b = np.zeros(n_states)
    c = np.zeros(n_states)
    d = 1.0
    to_internal = np.zeros((n_states, n_states))
    for k, section in enumerate(sos):
        a_k, b_k, c_k, d_k, inv_k = _section_realization(section)
        i = slice(2 * k, 2 * k + 2)
        # Section k's input is the output so far, c s + d x.
        a[i, : 2 * k] = np.outer(b_k, c[: 2 * k])
        a[i, i] = a_k
        b[i] = b_k * d
        c[: 2 * k] *= d_k
        c[i] = c_k
        d *= d_k
        to_internal[i, i] = inv_k
    return a, b, c, d, to_internal


class StreamingSOS:
    """A causal SOS filter over (n, channels) blocks whose state carries from block to block.

    Filtering a signal block by block gives the same samples as filtering it in one call, and as
    scipy.signal.sosfilt, to rounding; the sample axis is 0. With ``start_at_steady_state`` the
    state is initialised, on the first sample after construction or reset(), as if that sample
    had been applied forever (this is what removes the gravity step for a high-pass).

    How: the cascade is one state-space system s' = A s + B x, y = C s + D x. A block is cut into
    chunks x_j of L = CHUNK_N samples; from the state S_j at a chunk's start,

        y_j = T x_j + O S_j,    S_(j+1) = A^L S_j + K x_j

    with T the L x L lower-triangular Toeplitz matrix of the impulse response, O the rows C A^k
    and K the columns A^(L-1-k) B. T x_j and K x_j of every chunk and channel are two matrix
    products, the recursion over chunks a prefix scan in log2(chunks) steps (A^L, A^2L, A^4L, ...),
    O S_j one more product. A last partial chunk of r samples is padded with zeros (its first r
    outputs do not see them) and the state after it is A^r S_j plus K's last r columns times it.
    """

    def __init__(self, sos: NDArray[np.float64], n_channels: int, start_at_steady_state: bool) -> None:
        self._sos = _validated_sos(sos)
        self._n_channels = n_channels
        self._start_at_steady_state = start_at_steady_state
        a, b, c, d, to_internal = _cascade(self._sos)
        self._unit_state = to_internal @ sosfilt_zi(self._sos).ravel()  # (n_states,) for a unit step
        chunk_n = self._chunk_n = CHUNK_N
        powers = np.empty((chunk_n + 1, *a.shape))  # A^k, k = 0..L
        powers[0] = np.eye(a.shape[0])
        for k in range(1, chunk_n + 1):
            powers[k] = a @ powers[k - 1]
        observe = powers[:chunk_n].transpose(0, 2, 1) @ c  # (L, n_states): row k is C A^k
        impulse = np.concatenate([[d], observe[:-1] @ b])  # h[0] = D, h[k] = C A^(k-1) B
        toeplitz = np.zeros((chunk_n, chunk_n))
        for k in range(chunk_n):
            toeplitz[np.arange(k, chunk_n), np.arange(chunk_n - k)] = impulse[k]
        inject = powers[chunk_n - 1 :: -1] @ b  # (L, n_states): row k is (A^(L-1-k) B)^T
        # All transposed, as they multiply chunks held as rows (one per channel and chunk).
        self._toeplitz_t = np.ascontiguousarray(toeplitz.T)
        self._inject_t = inject
        self._observe_t = np.ascontiguousarray(observe.T)
        self._powers_t = np.ascontiguousarray(powers.transpose(0, 2, 1))
        # (A^(2^i L))^T for the scan, i < 40: blocks of up to 2^40 chunks.
        self._scan_t = [self._powers_t[chunk_n]]
        for _ in range(39):
            self._scan_t.append(self._scan_t[-1] @ self._scan_t[-1])
        self._state: NDArray[np.float64] | None = None  # (n_channels, n_states)
        self._scratch = np.empty(0)

    def reset(self) -> None:
        """Forget the state: the next sample starts a new, independent signal."""
        self._state = None

    def process(self, block: NDArray[np.float64]) -> NDArray[np.float64]:
        """The filtered (n, channels) block (a transposed view of a channel-major array)."""
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 2 or x.shape[1] != self._n_channels:
            raise ValueError(f"expected an (n, {self._n_channels}) block, got shape {x.shape}")
        n = x.shape[0]
        if n == 0:
            return x.copy()
        if self._state is None:
            if self._start_at_steady_state:
                self._state = x[0][:, None] * self._unit_state[None, :]
            else:
                self._state = np.zeros((self._n_channels, self._unit_state.size))
        return self._filter(x).T

    def _filter(self, x: NDArray[np.float64]) -> NDArray[np.float64]:
        """(channels, n) filtered x, from and to self._state."""
        n, n_ch = x.shape
        chunk_n = self._chunk_n
        n_full, rest = divmod(n, chunk_n)
        n_chunks = n_full + (rest > 0)
        rows = n_ch * n_chunks
        if self._scratch.size < 2 * rows * chunk_n:
            # Kept from block to block (as large as the largest block so far): a fresh array for a
            # 10 s block at 2 kHz costs more in page faults than the products that fill it.
            self._scratch = np.empty(2 * rows * chunk_n)
        # One row per (channel, chunk), channel-major, so that filling it and reading the output
        # back are 2-D transposes (a 3-D shuffle costs more than the products). The last chunk is
        # padded with zeros.
        chunks = self._scratch[: rows * chunk_n].reshape(n_ch, n_chunks * chunk_n)
        chunks[:, :n] = x.T
        chunks[:, n:] = 0.0
        chunks = chunks.reshape(rows, chunk_n)
        y = _product(chunks, self._toeplitz_t, np.empty((rows, chunk_n)))  # T x_j: from a zero state
        # K x_j, plus the block's starting state carried through the first chunk; the scan makes
        # row j the state after full chunk j.
        ends = _product(chunks, self._inject_t, np.empty((rows, self._inject_t.shape[1]))).reshape(n_ch, n_chunks, -1)
        if n_full:
            ends[:, 0] += self._state @ self._scan_t[0]
        shift = 1
        for power_t in self._scan_t:
            if shift >= n_full:
                break
            ends[:, shift:n_full] += ends[:, : n_full - shift] @ power_t
            shift *= 2
        starts = np.empty_like(ends)
        starts[:, 0] = self._state
        starts[:, 1:] = ends[:, :-1]
        from_starts = self._scratch[rows * chunk_n : 2 * rows * chunk_n].reshape(rows, chunk_n)
        y += _product(starts.reshape(rows, -1), self._observe_t, from_starts)  # O S_j
        if rest:
            tail = x[n_full * chunk_n :]
            self._state = starts[:, n_full] @ self._powers_t[rest] + tail.T @ self._inject_t[chunk_n - rest :]
        else:
            self._state = ends[:, n_full - 1].copy()
        return y.reshape(n_ch, n_chunks * chunk_n)[:, :n]


def _product(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> NDArray[np.float64]:
    """a @ b into out, in slices of a's rows small enough for OpenBLAS to keep to one thread."""
    rows = max(1, SINGLE_THREAD_PRODUCT // (a.shape[1] * b.shape[1]))
    for start in range(0, a.shape[0], rows):
        np.matmul(a[start : start + rows], b, out=out[start : start + rows])
    return out
