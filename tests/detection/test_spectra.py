"""Band cross-spectra: the streaming estimate against scipy.signal.csd, scaling, sign convention."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.detection.reference import spectra_reference
from bogiemon.detection.spectra import BANDS_HZ, WindowedSpectra, WindowSpectra, band_bins, coherency, hann_periodic

FS_HZ = 500.0


def stream_windows(x: np.ndarray, hops_per_window: int, hop_n: int) -> list[WindowSpectra]:
    stream = WindowedSpectra(hops_per_window, hop_n, FS_HZ)
    out = []
    for start in range(0, x.shape[0] - hop_n + 1, hop_n):
        w = stream.push_hop(x[start : start + hop_n])
        if w is not None:
            out.append(w)
    return out


@settings(max_examples=25, deadline=None)
@given(hops_per_window=st.integers(1, 5), hop_n=st.integers(64, 700), seed=st.integers(0, 2**16))
def test_the_streaming_band_matrix_equals_welch_csd_of_each_window(hops_per_window, hop_n, seed) -> None:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((hop_n * (hops_per_window + 3), 3)) @ rng.standard_normal((3, 3))
    got = stream_windows(x, hops_per_window, hop_n)
    assert len(got) == 4
    for k, window in enumerate(got):
        want = spectra_reference(x[k * hop_n : (k + hops_per_window) * hop_n], hop_n, FS_HZ)
        np.testing.assert_allclose(window.matrix, want.matrix, rtol=1e-9, atol=1e-12)


def test_a_sine_puts_its_mean_square_into_its_band() -> None:
    t = np.arange(50_000) / FS_HZ
    amplitude = 0.7
    x = np.column_stack([amplitude * np.sin(2 * np.pi * 5.0 * t), np.zeros_like(t), np.zeros_like(t)])
    (window,) = stream_windows(x[:10_000], 2, 5_000)
    power = np.array(window.power)[:, 0]
    band = int(np.searchsorted(BANDS_HZ, 5.0, side="right") - 1)  # 4-8 Hz
    assert power[band] == pytest.approx(amplitude**2 / 2, rel=1e-3)
    assert np.delete(power, band).sum() < 1e-6 * power[band]


def test_a_delayed_copy_gives_a_positive_imaginary_cross_spectrum() -> None:
    rng = np.random.default_rng(3)
    a = rng.standard_normal(20_000)
    delay_n = 2
    x = np.column_stack([a, np.r_[np.zeros(delay_n), a[:-delay_n]], rng.standard_normal(20_000)])
    (window,) = stream_windows(x[:10_000], 2, 5_000)
    coh = coherency(window.matrix)
    # a_2(t) = a_1(t - d): S_12 = X_1 conj(X_2) has a positive phase, growing with frequency.
    assert np.all(coh[2:6, 0, 1].imag > 0)
    assert np.all(np.abs(coh[:6, 0, 1]) > 0.95)
    # Independent noise: small where a band holds many bins (the lowest hold a few, and scatter).
    assert np.all(np.abs(coh[3:, 0, 2]) < 0.2)


def test_identical_channels_are_fully_coherent_and_the_matrix_is_hermitian() -> None:
    rng = np.random.default_rng(4)
    a = rng.standard_normal(10_000)
    x = np.column_stack([a, 2.0 * a, -a])
    (window,) = stream_windows(x, 2, 5_000)
    m = window.matrix
    np.testing.assert_allclose(m, np.conj(np.transpose(m, (0, 2, 1))))
    coh = coherency(m)
    np.testing.assert_allclose(coh[:, 0, 1].real, 1.0, atol=1e-12)
    np.testing.assert_allclose(coh[:, 0, 2].real, -1.0, atol=1e-12)


def test_bins_outside_the_bands_belong_to_none() -> None:
    bins = band_bins(5_000, FS_HZ)
    freqs = np.fft.rfftfreq(5_000, 1 / FS_HZ)
    assert np.all(bins[freqs < BANDS_HZ[0]] == -1)
    assert np.all(bins[freqs >= BANDS_HZ[-1]] == -1)
    inside = (freqs >= BANDS_HZ[0]) & (freqs < BANDS_HZ[-1])
    assert np.all(np.asarray(BANDS_HZ)[bins[inside]] <= freqs[inside])
    assert np.all(freqs[inside] < np.asarray(BANDS_HZ)[bins[inside] + 1])


@settings(max_examples=50, deadline=None)
@given(n=st.integers(2, 20_000))
def test_the_taper_is_scipys_periodic_hann_window(n: int) -> None:
    np.testing.assert_allclose(hann_periodic(n), signal.get_window("hann", n), rtol=0, atol=2e-15)
