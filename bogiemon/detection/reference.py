"""Reference implementation of the indicators: whole signals at once, one window at a time.

Direct and slow on purpose: it filters each signal in one call (scipy.signal.sosfilt), transforms
with the textbook formulas, correlates every window with one dot product per lag and takes band
spectra from scipy.signal.csd. The streaming core is checked against it (tests/detection) and the
naive benchmark baseline is built on the same window loop. Nothing the daemon runs imports it
(scipy.signal would cost the gateway scipy.stats too).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from bogiemon.detection.channel_stats import channel_stats_reference
from bogiemon.detection.conditioning import butter_sos
from bogiemon.detection.indicators import ProcessingSettings, WindowIndicators
from bogiemon.detection.kinematics import BogieGeometry
from bogiemon.detection.spectra import BANDS_HZ, WindowSpectra
from bogiemon.detection.xcorr import xcorr_direct


def condition_reference(
    accel_mps2: NDArray[np.float64], settings: ProcessingSettings
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """High-passed (n, 3) accelerations and, separately, the low-pass of the same (n, 3), whole-signal."""
    accel = np.asarray(accel_mps2, dtype=np.float64)
    hp = butter_sos(settings.highpass_order, settings.highpass_hz, settings.fs_hz, "highpass")
    zi = signal.sosfilt_zi(hp)[:, :, None] * accel[0][None, None, :]
    high, _ = signal.sosfilt(hp, accel, axis=0, zi=zi)
    lp = butter_sos(settings.lowpass_order, settings.lowpass_hz, settings.fs_hz, "lowpass")
    low = signal.sosfilt(lp, high, axis=0)
    return high, low


def spectra_reference(
    window: NDArray[np.float64], hop_n: int, fs_hz: float, bands_hz: tuple[float, ...] = BANDS_HZ
) -> WindowSpectra:
    """The band cross-spectral matrix of one (n, 3) window of conditioned samples, with scipy.signal.csd.

    Welch's method with non-overlapping Hann segments of hop_n samples and no detrending, as the
    stream computes it; the density times the bin width, summed over each band's bins.
    """
    n_bands = len(bands_hz) - 1
    matrix = np.zeros((n_bands, 3, 3), dtype=np.complex128)
    for i in range(3):
        for j in range(3):
            # csd(x, y) = conj(X) Y: S_ij = X_i conj(X_j) is csd(a_j, a_i).
            freqs, density = signal.csd(
                window[:, j], window[:, i], fs=fs_hz, window="hann", nperseg=hop_n, noverlap=0,
                detrend=False, scaling="density", average="mean",
            )  # fmt: skip
            df_hz = freqs[1] - freqs[0]
            for b in range(n_bands):
                inside = (freqs >= bands_hz[b]) & (freqs < bands_hz[b + 1])
                matrix[b, i, j] = density[inside].sum() * df_hz
    return WindowSpectra(tuple(float(b) for b in bands_hz), matrix)


def modal_reference(accel: NDArray[np.float64], geometry: BogieGeometry) -> NDArray[np.float64]:
    """METHOD.md's formulas written out for the paper's layout, generalised by re-labelling corners.

    Finds which sensor shares an axle and which a rail with the others, then applies
    aB = mean of the two diagonal sensors, aP = difference along the rail / 2l,
    aR = difference across the track / 2b, with signs from the corners' positions.
    """
    corners = geometry.corners
    two_l, two_b = geometry.wheelbase_m, geometry.sensor_spacing_m
    # The "L" vertex shares its axle with one sensor and its rail with the other.
    for v in range(3):
        others = [i for i in range(3) if i != v]
        same_axle = [i for i in others if corners[i].x_sign == corners[v].x_sign]
        same_rail = [i for i in others if corners[i].y_sign == corners[v].y_sign]
        if len(same_axle) == 1 and len(same_rail) == 1:
            across, along = same_axle[0], same_rail[0]
            break
    else:  # pragma: no cover - three distinct corners always form an L
        raise AssertionError("no L vertex")
    a_v, a_across, a_along = accel[:, v], accel[:, across], accel[:, along]
    bounce = (a_across + a_along) / 2.0
    pitch = corners[v].x_sign * (a_v - a_along) / two_l
    roll = corners[v].y_sign * (a_v - a_across) / two_b
    return np.column_stack([bounce, pitch, roll])


def indicators_reference(
    accel_mps2: NDArray[np.float64],
    settings: ProcessingSettings,
    geometry: BogieGeometry,
    start_s: float = 0.0,
    clip_level_mps2: float = np.inf,
) -> list[WindowIndicators]:
    """Every full window of one continuous segment, computed directly."""
    accel_mps2 = np.asarray(accel_mps2, dtype=np.float64)
    high, low = condition_reference(accel_mps2, settings)
    modal = modal_reference(high, geometry)
    modal_low = modal_reference(low, geometry)
    n_win, n_hop, k = settings.window_n, settings.hop_n, settings.max_lag_n
    out = []
    for s in range(0, high.shape[0] - n_win + 1, n_hop):
        b, p, r = (modal[s : s + n_win, c] for c in range(3))
        p_lp, r_lp = modal_low[s : s + n_win, 1], modal_low[s : s + n_win, 2]
        c_br = xcorr_direct(b, r, k)
        c_pr = xcorr_direct(p, r, k)
        sd_b, sd_p, sd_r = (float(np.sqrt(np.mean(v**2))) for v in (b, p, r))
        sd_p_lp, sd_r_lp = float(np.sqrt(np.mean(p_lp**2))), float(np.sqrt(np.mean(r_lp**2)))
        i1, i2 = float(np.std(c_br)), float(np.std(c_pr))
        i3 = float(np.mean(p_lp * r_lp))
        i4 = float(np.mean(p * r))
        t0 = start_s + s / settings.fs_hz
        rms = np.sqrt(np.mean(high[s : s + n_win] ** 2, axis=0))
        out.append(
            WindowIndicators(
                start_s=t0,
                end_s=t0 + n_win / settings.fs_hz,
                i1=i1,
                i2=i2,
                i3=i3,
                i4=i4,
                i1_norm=i1 / (sd_b * sd_r),
                i2_norm=i2 / (sd_p * sd_r),
                i3_norm=i3 / (sd_p_lp * sd_r_lp),
                i4_norm=i4 / (sd_p * sd_r),
                rms_mps2=(float(rms[0]), float(rms[1]), float(rms[2])),
                rms_bounce_mps2=sd_b,
                rms_pitch_radps2=sd_p,
                rms_roll_radps2=sd_r,
                channels=channel_stats_reference(accel_mps2[s : s + n_win], settings.fs_hz, clip_level_mps2, hop_n=n_hop),
                spectra=spectra_reference(high[s : s + n_win], n_hop, settings.fs_hz),
            )
        )
    return out
