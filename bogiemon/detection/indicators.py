"""The four fault indicators of METHOD.md, per window, from a stream of three accelerations.

    I1 = std over lags -L..+L of C_BR(tau)          [(m/s^2)(rad/s^2)]
    I2 = std over lags -L..+L of C_PR(tau)          [(rad/s^2)^2]
    I3 = C_PR(0) of aP, aR low-passed (10 Hz)        [(rad/s^2)^2]
    I4 = C_PR(0) of the unfiltered aP, aR            [(rad/s^2)^2]

"Unfiltered" means after the gravity/drift high-pass only (conditioning.py). The standard
deviation over lags is the population one (ddof = 0) over the 2K + 1 lag samples.

The normalised variants divide each by the RMS values of the two signals over the same window
(sigma_x^2 = C_xx(0); the high-passed signals have zero mean, so this is their standard
deviation), so I3n and I4n are correlation coefficients in [-1, 1] and I1n,
I2n are the standard deviations of correlation-coefficient functions. They are dimensionless
and do not scale with speed or track roughness, which scale both signals together. They are
NaN when a signal is exactly zero over the window (a dead channel).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection.channel_stats import ChannelStats, WindowedChannelStats
from bogiemon.detection.conditioning import StreamingSOS, butter_sos
from bogiemon.detection.hops import HopAssembler
from bogiemon.detection.kinematics import BogieGeometry
from bogiemon.detection.spectra import WindowedSpectra, WindowSpectra
from bogiemon.detection.xcorr import StreamingCrossCorrelator, WindowCorrelations


# Sample rates the core accepts: below 1 Hz no filter or window of the method fits, above 100 kHz
# is no accelerometer stream of a bogie (the method needs 0.5-10 Hz; sensors run at 0.1-5 kHz).
MIN_FS_HZ = 1.0
MAX_FS_HZ = 100_000.0
MAX_FILTER_ORDER = 32  # Butterworth sections beyond this lose their precision in float64
# Below fs_hz * 1e-6 a Butterworth section's poles round to 1 in float64 and the filter returns NaN.
MIN_CUTOFF_FRACTION = 1e-6
# What the correlator keeps per window, in samples: hops per window x (hop + lags) of cross-
# spectra, 64 bytes each (detection/xcorr.py), so at most 256 MiB. 120 s windows every 10 s with
# 10 s lags at 500 Hz hold 120 000; the bound stops settings that would exhaust a gateway's memory.
MAX_CORRELATOR_SAMPLES = 1 << 22


@dataclass(frozen=True)
class ProcessingSettings:
    """How the accelerations are conditioned and windowed. Times in seconds, rates in hertz.

    Settings the core cannot run raise ValueError when built, naming the setting and the bound,
    so that valid settings always build an IndicatorStream.
    """

    fs_hz: float = 500.0
    window_s: float = 120.0
    hop_s: float = 10.0
    max_lag_s: float = 10.0
    highpass_hz: float = 0.5
    highpass_order: int = 2
    lowpass_hz: float = 10.0
    lowpass_order: int = 4

    def __post_init__(self) -> None:
        for name in ("fs_hz", "window_s", "hop_s", "max_lag_s", "highpass_hz", "lowpass_hz"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value):
                raise ValueError(f"{name} must be a finite number, got {value!r}")
        for name in ("highpass_order", "lowpass_order"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 1 <= int(value) <= MAX_FILTER_ORDER:
                raise ValueError(f"{name} must be a whole number from 1 to {MAX_FILTER_ORDER}, got {value!r}")
        fs = self.fs_hz
        if not MIN_FS_HZ <= fs <= MAX_FS_HZ:
            raise ValueError(f"fs_hz {fs:g} Hz is outside the sample rates the core handles, {MIN_FS_HZ:g} to {MAX_FS_HZ:g} Hz")
        nyquist_hz = fs / 2.0
        for name in ("highpass_hz", "lowpass_hz"):
            cutoff_hz = getattr(self, name)
            if not 0.0 < cutoff_hz < nyquist_hz:
                raise ValueError(f"{name} ({cutoff_hz:g} Hz) must lie between 0 and Nyquist (fs_hz / 2 = {nyquist_hz:g} Hz)")
            if cutoff_hz < MIN_CUTOFF_FRACTION * fs:
                raise ValueError(
                    f"{name} ({cutoff_hz:g} Hz) is below fs_hz x {MIN_CUTOFF_FRACTION:g} = {MIN_CUTOFF_FRACTION * fs:g} Hz: "
                    "the filter cannot be computed in double precision"
                )
        if self.window_s <= 0 or self.hop_s <= 0 or self.max_lag_s < 0:
            raise ValueError(
                f"window_s and hop_s must be positive and max_lag_s not negative, got {self.window_s:g}, {self.hop_s:g}, {self.max_lag_s:g}"
            )
        for name in ("window_s", "hop_s", "max_lag_s"):  # in samples before rounding: inf or 1e300 never reaches int()
            duration_s = getattr(self, name)
            if not duration_s * fs <= MAX_CORRELATOR_SAMPLES:
                raise ValueError(
                    f"{name} ({duration_s:g} s) is {duration_s * fs:.3g} samples at {fs:g} Hz, more than the "
                    f"{MAX_CORRELATOR_SAMPLES} the core allows"
                )
        window_n, hop_n, lag_n = self.window_n, self.hop_n, self.max_lag_n
        if hop_n < 2:
            raise ValueError(f"hop_s ({self.hop_s:g} s) is {hop_n} sample(s) at {fs:g} Hz: a hop needs at least 2 samples")
        if window_n < hop_n or window_n % hop_n:
            raise ValueError(
                f"window {self.window_s:g} s must be a whole number of hops ({self.hop_s:g} s): at {fs:g} Hz "
                f"that is {window_n} samples and hops of {hop_n}"
            )
        if lag_n >= window_n:
            raise ValueError(
                f"max_lag_s ({self.max_lag_s:g} s, {lag_n} samples at {fs:g} Hz) must be shorter than the window ({window_n} samples)"
            )
        held_n = (window_n // hop_n) * (hop_n + lag_n)
        if held_n > MAX_CORRELATOR_SAMPLES:
            raise ValueError(
                f"windows of {self.window_s:g} s every {self.hop_s:g} s with lags of {self.max_lag_s:g} s at {fs:g} Hz hold "
                f"{held_n} samples of cross-spectra, more than the {MAX_CORRELATOR_SAMPLES} the core allows: "
                "use fewer hops per window, shorter lags or a lower rate"
            )

    def samples(self, duration_s: float) -> int:
        """A duration in whole samples at fs_hz (rounded to the nearest)."""
        return int(round(duration_s * self.fs_hz))

    @property
    def window_n(self) -> int:
        return self.samples(self.window_s)

    @property
    def hop_n(self) -> int:
        return self.samples(self.hop_s)

    @property
    def max_lag_n(self) -> int:
        return self.samples(self.max_lag_s)


@dataclass(frozen=True)
class WindowIndicators:
    """The indicators of one window. Times in seconds on the source's time axis."""

    start_s: float
    end_s: float
    i1: float
    i2: float
    i3: float
    i4: float
    i1_norm: float
    i2_norm: float
    i3_norm: float
    i4_norm: float
    rms_mps2: tuple[float, float, float]  # a1, a2, a3 after the high-pass
    rms_bounce_mps2: float
    rms_pitch_radps2: float
    rms_roll_radps2: float
    channels: ChannelStats  # raw statistics of a1, a2, a3, for judging the sensors
    # Band cross-spectra of a1, a2, a3 after the high-pass (detection/spectra.py); None only in
    # records built by hand without them.
    spectra: WindowSpectra | None = None

    @property
    def raw(self) -> tuple[float, float, float, float]:
        return (self.i1, self.i2, self.i3, self.i4)

    @property
    def normalised(self) -> tuple[float, float, float, float]:
        return (self.i1_norm, self.i2_norm, self.i3_norm, self.i4_norm)


# Columns of the conditioned stream fed to the correlator.
_B, _P, _R, _P_LP, _R_LP, _A1, _A2, _A3 = range(8)
_LAGGED_PAIRS = ((_B, _R), (_P, _R))
_ZERO_LAG_PAIRS = (
    (_B, _B), (_P, _P), (_R, _R),
    (_P_LP, _R_LP), (_P_LP, _P_LP), (_R_LP, _R_LP),
    (_A1, _A1), (_A2, _A2), (_A3, _A3),
)  # fmt: skip


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0.0 else float("nan")


class IndicatorStream:
    """Streaming detection core: (n, 3) blocks of a1, a2, a3 in m/s^2 in, WindowIndicators out.

    Blocks may have any length; every hop after the first full window yields one record. Call
    restart() after a gap: windows never span it, and the filters start afresh.
    """

    def __init__(
        self,
        settings: ProcessingSettings,
        geometry: BogieGeometry,
        start_s: float = 0.0,
        clip_level_mps2: float = np.inf,
    ) -> None:
        self.settings = settings  # valid by construction (ProcessingSettings.__post_init__)
        self.geometry = geometry
        self._to_modal = geometry.modal_matrix().T
        self._highpass = StreamingSOS(
            butter_sos(settings.highpass_order, settings.highpass_hz, settings.fs_hz, "highpass"),
            n_channels=3,
            start_at_steady_state=True,
        )
        self._lowpass = StreamingSOS(
            butter_sos(settings.lowpass_order, settings.lowpass_hz, settings.fs_hz, "lowpass"),
            n_channels=2,
            start_at_steady_state=False,
        )
        # Whole hops go through the filters: a few calls per hop, whatever the sources' block size.
        self._hops = HopAssembler(settings.hop_n, 3)
        self._stream = np.empty((settings.hop_n, 8))
        self._correlator = StreamingCrossCorrelator(
            n_channels=8,
            pairs=_LAGGED_PAIRS,
            window_n=settings.window_n,
            hop_n=settings.hop_n,
            max_lag_n=settings.max_lag_n,
            zero_lag_pairs=_ZERO_LAG_PAIRS,
        )
        self._channel_stats = WindowedChannelStats(settings.window_n // settings.hop_n, settings.hop_n, settings.fs_hz, clip_level_mps2)
        self._spectra = WindowedSpectra(settings.window_n // settings.hop_n, settings.hop_n, settings.fs_hz)
        self.restart(start_s)

    def restart(self, start_s: float) -> None:
        """Begin a new segment whose first sample is at start_s."""
        self._start_s = start_s
        self._hops.reset()
        self._highpass.reset()
        self._lowpass.reset()
        self._correlator.reset()
        self._channel_stats.reset()
        self._spectra.reset()

    def process(self, accel_mps2: NDArray[np.float64]) -> list[WindowIndicators]:
        return [ind for ind, _ in self.process_with_correlations(accel_mps2)]

    def process_with_correlations(
        self, accel_mps2: NDArray[np.float64]
    ) -> list[tuple[WindowIndicators, WindowCorrelations]]:
        """As process(), with each window's C_BR (row 0) and C_PR (row 1) over lags -K..K."""
        out = []
        stream = self._stream
        for hop in self._hops.split(accel_mps2):
            stats = self._channel_stats.push_hop(hop)
            stream[:, _A1 : _A3 + 1] = self._highpass.process(hop)
            stream[:, _B : _R + 1] = stream[:, _A1 : _A3 + 1] @ self._to_modal
            stream[:, _P_LP : _R_LP + 1] = self._lowpass.process(stream[:, _P : _R + 1])
            spectra = self._spectra.push_hop(stream[:, _A1 : _A3 + 1])
            # Whole hops in, so at most one window out, on the same hop as its channel stats.
            for w in self._correlator.push(stream):
                assert stats is not None and spectra is not None
                out.append((self._indicators(w, stats, spectra), w))
        return out

    def _indicators(self, w: WindowCorrelations, stats: ChannelStats, spectra: WindowSpectra) -> WindowIndicators:
        fs_hz = self.settings.fs_hz
        start_s = self._start_s + w.start_index / fs_hz
        c_br, c_pr = w.lagged
        (ms_b, ms_p, ms_r, c_pr_lp0, ms_p_lp, ms_r_lp, ms_a1, ms_a2, ms_a3) = w.zero_lag
        sd_b, sd_p, sd_r, sd_p_lp, sd_r_lp = np.sqrt(np.maximum([ms_b, ms_p, ms_r, ms_p_lp, ms_r_lp], 0.0))
        rms_a = np.sqrt(np.maximum([ms_a1, ms_a2, ms_a3], 0.0))
        i1 = float(np.std(c_br))
        i2 = float(np.std(c_pr))
        i3 = float(c_pr_lp0)
        i4 = float(c_pr[self.settings.max_lag_n])
        return WindowIndicators(
            start_s=start_s,
            end_s=start_s + self.settings.window_n / fs_hz,
            i1=i1,
            i2=i2,
            i3=i3,
            i4=i4,
            i1_norm=_ratio(i1, sd_b * sd_r),
            i2_norm=_ratio(i2, sd_p * sd_r),
            i3_norm=_ratio(i3, sd_p_lp * sd_r_lp),
            i4_norm=_ratio(i4, sd_p * sd_r),
            rms_mps2=(float(rms_a[0]), float(rms_a[1]), float(rms_a[2])),
            rms_bounce_mps2=float(sd_b),
            rms_pitch_radps2=float(sd_p),
            rms_roll_radps2=float(sd_r),
            channels=stats,
            spectra=spectra,
        )
