"""The indicators: streaming core against the reference, and signals with a known correlation."""

import dataclasses
import itertools
import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings, from_modal
from bogiemon.detection.reference import indicators_reference

FAST = ProcessingSettings(fs_hz=100.0, window_s=6.0, hop_s=2.0, max_lag_s=1.5, lowpass_hz=10.0)
GRAVITY = np.array([9.81, 9.81, 9.81])


def run_stream(stream: IndicatorStream, accel: np.ndarray, sizes: list[int]) -> list:
    out, pos, i = [], 0, 0
    while pos < len(accel):
        out += stream.process(accel[pos : pos + sizes[i % len(sizes)]])
        pos += sizes[i % len(sizes)]
        i += 1
    return out


def flat_fields(record) -> dict[str, np.ndarray]:
    out = {}
    for name, value in dataclasses.asdict(record).items():
        if isinstance(value, dict):
            out.update({f"{name}.{k}": np.asarray(v) for k, v in value.items()})
        else:
            out[name] = np.asarray(value)
    return out


def assert_records_close(got, want, rel: float) -> None:
    """Each field within rel of the largest magnitude in it: an entry of a band matrix far below
    the others (a small imaginary cross-spectrum) carries the whole matrix's rounding."""
    assert len(got) == len(want)
    for a, b in zip(got, want, strict=True):
        fa, fb = flat_fields(a), flat_fields(b)
        assert fa.keys() == fb.keys()
        for name in fa:
            finite = np.abs(fb[name][np.isfinite(fb[name])])
            scale = float(finite.max()) if finite.size else 0.0
            np.testing.assert_allclose(fa[name], fb[name], rtol=rel, atol=rel * scale, err_msg=name)


@settings(max_examples=25, deadline=None)
@given(
    hops_per_window=st.integers(1, 4),
    hop_s=st.sampled_from([0.5, 1.0, 2.0]),
    lag_fraction=st.floats(0.0, 0.9),
    sizes=st.lists(st.integers(1, 500), min_size=1, max_size=8),
    layout=st.sampled_from(list(itertools.permutations(Corner, 3))),
    seed=st.integers(0, 2**32 - 1),
)
def test_streaming_core_equals_reference(hops_per_window, hop_s, lag_fraction, sizes, layout, seed) -> None:
    window_s = hops_per_window * hop_s
    s = dataclasses.replace(FAST, window_s=window_s, hop_s=hop_s, max_lag_s=round(lag_fraction * window_s, 2))
    geometry = BogieGeometry(1.8, 2.0, layout)
    rng = np.random.default_rng(seed)
    # Quantised to 0.25 m/s^2 so that repeated samples and clipping occur.
    n = int(rng.integers(s.window_n, s.window_n + 700))
    accel = np.round(4 * (rng.standard_normal((n, 3)) + GRAVITY)) / 4
    got = run_stream(IndicatorStream(s, geometry, start_s=12.5, clip_level_mps2=11.0), accel, sizes)
    want = indicators_reference(accel, s, geometry, start_s=12.5, clip_level_mps2=11.0)
    # Only data that exercise the repeat and clip counts (a short window may hold neither).
    assume(any(w.channels.repeat_fraction[0] > 0 and w.channels.clipped_fraction[1] > 0 for w in want))
    assert_records_close(got, want, rel=1e-9)


def test_default_settings_streaming_equals_reference_on_three_windows() -> None:
    s = ProcessingSettings()
    accel = np.random.default_rng(7).standard_normal((int(80 * s.fs_hz), 3)) + GRAVITY
    got = IndicatorStream(s, BogieGeometry()).process(accel)
    assert_records_close(got, indicators_reference(accel, s, BogieGeometry()), rel=1e-9)


def band_noise(n: int, fs_hz: float, rng: np.random.Generator) -> np.ndarray:
    """A sum of sines between 2 and 8 Hz: inside both filters' pass bands."""
    t = np.arange(n) / fs_hz
    freqs = rng.uniform(2.0, 8.0, size=40)
    phases = rng.uniform(0, 2 * np.pi, size=40)
    return np.sin(2 * np.pi * freqs[:, None] * t[None, :] + phases[:, None]).sum(axis=0) / np.sqrt(20)


def sensors_from_modal(bounce, pitch, roll, geometry) -> np.ndarray:
    return from_modal(np.column_stack([bounce, pitch, roll]), geometry) + GRAVITY


@pytest.mark.parametrize("layout", list(itertools.permutations(Corner, 3))[::5])
@pytest.mark.parametrize("gain", [0.7, -0.4])
def test_pitch_proportional_to_roll_gives_unit_correlation_with_its_sign(layout, gain) -> None:
    geometry = BogieGeometry(1.8, 2.0, layout)
    rng = np.random.default_rng(8)
    n = int(30 * FAST.fs_hz)
    roll = band_noise(n, FAST.fs_hz, rng)
    bounce = band_noise(n, FAST.fs_hz, rng)
    out = IndicatorStream(FAST, geometry).process(sensors_from_modal(bounce, gain * roll, roll, geometry))
    for ind in out:
        assert ind.i4_norm == pytest.approx(np.sign(gain), abs=1e-9)
        assert ind.i3_norm == pytest.approx(np.sign(gain), abs=1e-9)
        assert ind.i4 == pytest.approx(gain * ind.rms_roll_radps2**2, rel=1e-9)
        assert ind.rms_pitch_radps2 == pytest.approx(abs(gain) * ind.rms_roll_radps2, rel=1e-9)


def test_pitch_lagging_roll_peaks_at_the_lag() -> None:
    rng = np.random.default_rng(9)
    fs, lag_s = FAST.fs_hz, 0.37
    n = int(30 * fs)
    roll = band_noise(n + 100, fs, rng)
    lag_n = int(round(lag_s * fs))
    pitch = roll[100 - lag_n : 100 - lag_n + n]  # pitch(t) = roll(t - 0.37 s)
    roll = roll[100 : 100 + n]
    geometry = BogieGeometry()
    bounce = band_noise(n, fs, rng)
    results = IndicatorStream(FAST, geometry).process_with_correlations(
        sensors_from_modal(bounce, pitch, roll, geometry)
    )
    assert results
    k = FAST.max_lag_n
    for _, corr in results:
        c_pr = corr.lagged[1]
        assert (int(np.argmax(c_pr)) - k) / fs == pytest.approx(lag_s, abs=0.5 / fs)


def test_independent_modes_give_small_couplings() -> None:
    rng = np.random.default_rng(10)
    n = int(120 * FAST.fs_hz)
    geometry = BogieGeometry()
    accel = sensors_from_modal(
        rng.standard_normal(n), rng.standard_normal(n), rng.standard_normal(n), geometry
    )
    out = IndicatorStream(FAST, geometry).process(accel)
    n_window = FAST.window_n
    for ind in out:
        # A correlation coefficient of independent white signals has a spread of 1/sqrt(N).
        assert abs(ind.i4_norm) < 5 / np.sqrt(n_window)
        assert abs(ind.i3_norm) < 5 / np.sqrt(n_window / 5)  # 10 Hz of 50: fewer degrees of freedom


def test_bounce_coupled_to_roll_raises_i1_and_leaves_the_pitch_indicators_unchanged() -> None:
    rng = np.random.default_rng(11)
    long_window = dataclasses.replace(FAST, window_s=30.0, hop_s=10.0)
    fs, n = FAST.fs_hz, int(90 * FAST.fs_hz)
    roll, pitch = band_noise(n, fs, rng), band_noise(n, fs, rng)
    geometry = BogieGeometry()
    coupled = IndicatorStream(long_window, geometry).process(sensors_from_modal(np.roll(roll, 20), pitch, roll, geometry))
    free = IndicatorStream(long_window, geometry).process(sensors_from_modal(band_noise(n, fs, rng), pitch, roll, geometry))
    assert len(coupled) == len(free) == 7
    assert min(c.i1_norm for c in coupled) > 2.5 * max(f.i1_norm for f in free)
    for c, f in zip(coupled, free, strict=True):  # bounce never enters C_PR
        assert c.raw[1:] == pytest.approx(f.raw[1:], rel=1e-9)
        assert c.normalised[1:] == pytest.approx(f.normalised[1:], rel=1e-9)


def test_window_times_follow_the_hop_from_the_start_time() -> None:
    accel = np.random.default_rng(12).standard_normal((1000, 3))
    out = IndicatorStream(FAST, BogieGeometry(), start_s=100.0).process(accel)
    assert [o.start_s for o in out] == [100.0 + 2.0 * i for i in range(len(out))]
    assert all(o.end_s - o.start_s == pytest.approx(6.0) for o in out)


def test_restart_keeps_windows_off_a_gap() -> None:
    rng = np.random.default_rng(13)
    stream = IndicatorStream(FAST, BogieGeometry())
    before = stream.process(rng.standard_normal((850, 3)))
    stream.restart(500.0)
    after = stream.process(rng.standard_normal((850, 3)))
    assert [o.start_s for o in before] == [0.0, 2.0]
    assert [o.start_s for o in after] == [500.0, 502.0]


def test_a_dead_sensor_leaves_normalised_indicators_undefined() -> None:
    out = IndicatorStream(FAST, BogieGeometry()).process(np.tile(GRAVITY, (700, 1)))
    assert out and all(np.isnan(o.i4_norm) and abs(o.i4) < 1e-15 for o in out)


def test_window_not_a_multiple_of_hop_is_rejected() -> None:
    with pytest.raises(ValueError, match="whole number of hops"):
        IndicatorStream(dataclasses.replace(FAST, hop_s=4.0), BogieGeometry())


# --- ProcessingSettings: what the core cannot run is refused when the settings are built -------


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"fs_hz": 10.0}, r"lowpass_hz \(10 Hz\) must lie between 0 and Nyquist \(fs_hz / 2 = 5 Hz\)"),
        ({"fs_hz": 333.33}, r"window 120 s must be a whole number of hops \(10 s\): at 333.33 Hz that is 40000 samples and hops of 3333"),
        ({"fs_hz": 0.01}, r"fs_hz 0.01 Hz is outside the sample rates the core handles, 1 to 100000 Hz"),
        ({"fs_hz": math.inf}, r"fs_hz must be a finite number, got inf"),
        ({"fs_hz": 1 / 4.9e-324}, r"fs_hz must be a finite number, got inf"),
        ({"window_s": math.inf}, r"window_s must be a finite number, got inf"),
        ({"hop_s": math.nan}, r"hop_s must be a finite number, got nan"),
        ({"fs_hz": "500"}, r"fs_hz must be a finite number, got '500'"),
        ({"hop_s": 0.002}, r"hop_s \(0.002 s\) is 1 sample\(s\) at 500 Hz: a hop needs at least 2 samples"),
        ({"hop_s": -10.0}, r"window_s and hop_s must be positive and max_lag_s not negative"),
        ({"max_lag_s": 120.0}, r"max_lag_s \(120 s, 60000 samples at 500 Hz\) must be shorter than the window \(60000 samples\)"),
        ({"highpass_hz": 0.0}, r"highpass_hz \(0 Hz\) must lie between 0 and Nyquist"),
        ({"highpass_hz": 1e-4}, r"highpass_hz \(0.0001 Hz\) is below fs_hz x 1e-06 = 0.0005 Hz"),
        ({"lowpass_order": 0}, r"lowpass_order must be a whole number from 1 to 32, got 0"),
        ({"highpass_order": 2.5}, r"highpass_order must be a whole number from 1 to 32, got 2.5"),
        ({"hop_s": 0.01, "max_lag_s": 100.0}, r"hold 600\d+ samples of cross-spectra, more than the 4194304 the core allows"),
    ],
    ids=[
        "10hz-lowpass", "333.33hz-hops", "0.01hz", "inf-rate", "rate-of-4.9e-324-step", "inf-window", "nan-hop", "text",
        "one-sample-hop", "negative-hop", "lag-of-a-window", "zero-cutoff", "cutoff-below-precision", "order-0",
        "fractional-order", "memory",
    ],
)  # fmt: skip
def test_settings_the_core_cannot_run_are_refused_with_a_message_naming_the_setting(changes: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        ProcessingSettings(**changes)


@settings(max_examples=150, deadline=None)
@given(
    fs_hz=st.one_of(st.floats(0.5, 2000.0), st.sampled_from([1.0, 20.0, 20.0001, 333.33, 500.0])),
    window_s=st.floats(0.001, 20.0),
    hops=st.integers(1, 12),
    lag_fraction=st.floats(0.0, 1.2),
    highpass_hz=st.floats(1e-7, 20.0),
    lowpass_hz=st.floats(1e-3, 1000.0),
    orders=st.tuples(st.integers(0, 33), st.integers(0, 33)),
)
def test_settings_that_build_always_run_the_core_to_finite_indicators(
    fs_hz, window_s, hops, lag_fraction, highpass_hz, lowpass_hz, orders
) -> None:
    try:
        s = ProcessingSettings(
            fs_hz=fs_hz, window_s=window_s, hop_s=window_s / hops, max_lag_s=lag_fraction * window_s,
            highpass_hz=highpass_hz, highpass_order=orders[0], lowpass_hz=lowpass_hz, lowpass_order=orders[1],
        )  # fmt: skip
    except ValueError:
        return
    assume(s.window_n <= 5000)
    accel = np.random.default_rng(0).standard_normal((s.window_n + s.hop_n, 3)) + GRAVITY
    out = IndicatorStream(s, BogieGeometry()).process(accel)
    assert len(out) == 2
    assert all(np.isfinite([*o.raw, o.rms_bounce_mps2, o.rms_pitch_radps2, o.rms_roll_radps2]).all() for o in out)


@pytest.mark.parametrize("name", ["window_s", "hop_s", "max_lag_s"])
def test_a_duration_of_more_samples_than_a_float_holds_is_a_value_error_not_an_overflow(name: str) -> None:
    with pytest.raises(ValueError, match=rf"{name} \(3.6e\+305 s\) is inf samples at 500 Hz, more than the"):
        ProcessingSettings(**{name: 3.6e305})  # type: ignore[arg-type]  # one float field, named by the parameter
