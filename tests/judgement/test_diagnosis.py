"""The diagnosis from the geometry: the diagonal pair from the signs of the coupling shift, or "unknown"."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bogiemon.judgement.vocabulary import LoadState, Method
from bogiemon.judgement.decision import Decider, DecisionSettings
from bogiemon.judgement.diagnosis import (
    MIN_SCORE,
    NO_EVIDENCE,
    PAIR_CONFIDENCE_MAX,
    Diagnosis,
    SIGN_BANDS,
    diagnose,
    diagonal_of,
    healthy_covariance,
    judge_signs,
    raw_shift,
    sign_evidence,
)
from bogiemon.judgement.events import ConfirmedDetails, EventKind
from bogiemon.judgement.models import UNKNOWN, Baseline, Levels, whitening_of
from bogiemon.detection import BogieGeometry, Corner, WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats
from bogiemon.detection.features import BOUNCE, COUPLING_FEATURES, PITCH, ROLL
from bogiemon.detection.spectra import BANDS_HZ, WindowSpectra

N = len(COUPLING_FEATURES)
SD = 0.05  # the healthy spread of every coupling in these tests
LEVELS = Levels(warning=20.0, alarm=40.0, trend_warning=2.0, trend_alarm=4.0)  # the trend's spread: 1/10 of a window's variance


def covariance(rho: float = 0.3) -> np.ndarray:
    """SD in every coupling, bands of one coupling correlated by rho, the two couplings not."""
    c = np.zeros((N, N))
    for a, (_, ia, _, _) in enumerate(COUPLING_FEATURES):
        for b, (_, ib, _, _) in enumerate(COUPLING_FEATURES):
            c[a, b] = SD**2 * (1.0 if a == b else rho if ia == ib else 0.0)
    return c


def baseline(cov: np.ndarray | None = None, center: np.ndarray | None = None) -> Baseline:
    cov = covariance() if cov is None else cov
    center = np.linspace(-0.1, 0.1, N) if center is None else center
    return Baseline("calibrated", center, whitening_of(cov), LEVELS, trend_tau_s=1800.0)


def shift_of(corner: Corner, load: str, amplitude_sd: float, softer: bool = True) -> np.ndarray:
    """A raw coupling shift of amplitude_sd healthy spreads in the load's sign bands, with the signs
    a softer (or stiffer) corner gives: x y for pitch-roll, y for bounce-roll."""
    sign = 1.0 if softer else -1.0
    out = np.zeros(N)
    for k, (_, mode, _, band) in enumerate(COUPLING_FEATURES):
        if band in SIGN_BANDS[load]:
            out[k] = sign * amplitude_sd * SD * (corner.x_sign * corner.y_sign if mode == PITCH else corner.y_sign)
    return out


def windows_of(shift: np.ndarray, b: Baseline, n: int = 3) -> list[list[float]]:
    """n confirming windows' whitened shifts, all of this raw shift."""
    return [list(b.whitening @ shift)] * n


def across_the_track(corner: Corner) -> Corner:
    return next(c for c in Corner if c.x_sign == corner.x_sign and c.y_sign != corner.y_sign)


def pair(corner: Corner) -> tuple[Corner, Corner]:
    return (corner, diagonal_of(corner))


def test_the_diagonal_of_a_corner_is_across_the_frames_centre() -> None:
    assert [(c.value, diagonal_of(c).value) for c in Corner] == [
        ("leading-left", "trailing-right"), ("leading-right", "trailing-left"), ("trailing-left", "leading-right"), ("trailing-right", "leading-left"),
    ]  # fmt: skip


@pytest.mark.parametrize("load", ["full", "tare"])
@pytest.mark.parametrize("corner", list(Corner))
def test_a_softer_corner_is_named_with_its_diagonal_from_the_signs_of_its_shift(corner: Corner, load: str) -> None:
    b = baseline()
    d = diagnose(windows_of(shift_of(corner, load, 6.0), b), b, load)
    assert (d.corners, d.kind, d.windows) == (pair(corner), UNKNOWN, 3)
    assert d.corner == f"{corner.value} or {diagonal_of(corner).value}"
    assert d.corner_confidence == PAIR_CONFIDENCE_MAX < 1.0 and d.cosine == pytest.approx(1.0)  # never a certainty


@pytest.mark.parametrize("load", ["full", "tare"])
@pytest.mark.parametrize("corner", list(Corner))
def test_a_stiffer_corner_reads_as_its_neighbour_across_the_track_softening(corner: Corner, load: str) -> None:
    # The mirror y -> -y flips both couplings: the first-order ambiguity the docstring states.
    b = baseline()
    d = diagnose(windows_of(shift_of(corner, load, 6.0, softer=False), b), b, load)
    assert d.corners == pair(across_the_track(corner))
    assert d.kind == UNKNOWN


@pytest.mark.parametrize("corner", list(Corner))
def test_a_front_coil_that_reads_as_the_rear_coil_of_the_diagonal_corner_is_in_the_pair(corner: Corner) -> None:
    # A broken front coil: its damper grips more, the bounce-roll sign turns round while the
    # pitch-roll sign keeps x y (module docstring): the signs of a softer diagonal corner.
    b = baseline()
    shift = shift_of(corner, "full", 6.0)
    shift[[k for k, (_, mode, _, _) in enumerate(COUPLING_FEATURES) if mode == BOUNCE]] *= -1.0
    d = diagnose(windows_of(shift, b), b, "full")
    assert corner in d.corners and d.corners == pair(diagonal_of(corner))
    assert d.best_match.endswith(f"({diagonal_of(corner).value} if softer)")


def test_bands_that_disagree_in_sign_give_unknown() -> None:
    # Read in two bands (SIGN_BANDS reads one, the rule any number): a band against the sum's sign.
    b = baseline()
    low, high = 3, 5
    shift = np.zeros(N)
    for k, (_, mode, _, band) in enumerate(COUPLING_FEATURES):
        if band == low:
            shift[k] = 6.0 * SD  # leading-left softer: both couplings positive at 4-8 Hz ...
        elif band == high and mode == PITCH:
            shift[k] = -2.0 * SD  # ... but pitch-roll -2 sd at 16-32 Hz
    healthy = healthy_covariance(b)
    d = judge_signs(sign_evidence(shift, healthy, healthy, (low, high)), 3)
    assert d.corner == UNKNOWN and d.corners == ()
    assert d.best_match.endswith(": a band contradicts the pitch-roll sign, no pair named") and d.cosine < 1.0
    assert not any(c.value in d.best_match for c in Corner)  # an unknown corner names no pair


def test_a_shift_within_its_noise_gives_unknown() -> None:
    b = baseline()
    d = diagnose(windows_of(shift_of(Corner.TRAILING_RIGHT, "full", 1.5), b), b, "full")
    assert d.corner == UNKNOWN
    assert d.best_match.endswith(": the pitch-roll sign is within the noise (under 2.5 sd), no pair named")
    assert not any(c.value in d.best_match for c in Corner)  # an unknown corner names no pair


def test_the_pair_needs_the_pitch_roll_sign_alone() -> None:
    b = baseline()
    shift = shift_of(Corner.LEADING_RIGHT, "tare", 8.0)
    shift[[k for k, (_, mode, _, _) in enumerate(COUPLING_FEATURES) if mode == BOUNCE]] *= 0.1  # bounce-roll 0.8 sd
    assert diagnose(windows_of(shift, b), b, "tare").corners == pair(Corner.LEADING_RIGHT)
    shift = shift_of(Corner.LEADING_RIGHT, "tare", 8.0)
    shift[[k for k, (_, mode, _, _) in enumerate(COUPLING_FEATURES) if mode == PITCH]] *= 0.1  # pitch-roll 0.8 sd
    assert diagnose(windows_of(shift, b), b, "tare").corner == UNKNOWN


def test_windows_that_scatter_widely_about_a_clear_mean_give_unknown() -> None:
    b = baseline()
    mean = shift_of(Corner.TRAILING_LEFT, "full", 4.0)
    assert diagnose(windows_of(mean, b, 4), b, "full").corners == pair(Corner.TRAILING_LEFT)
    spread = np.zeros(N)
    spread[:] = 12.0 * SD
    scattered = [list(b.whitening @ (mean + s * spread)) for s in (1.0, -1.0, 1.0, -1.0)]
    assert diagnose(scattered, b, "full").corner == UNKNOWN


def test_the_trend_is_read_against_its_smaller_spread() -> None:
    b = baseline()
    mean = windows_of(shift_of(Corner.LEADING_LEFT, "full", 2.0), b, 1)
    assert diagnose(mean, b, "full").corner == UNKNOWN  # 2 sd of a window's spread: within the noise
    # The trend's spread is sqrt(4 / 40) of a window's: the same mean is 6.3 of its sd.
    assert diagnose(mean, b, "full", trend=True).corners == pair(Corner.LEADING_LEFT)


def test_uncorrelated_bands_score_the_sum_of_their_standard_scores_over_root_n() -> None:
    b = baseline(covariance(rho=0.0))
    rng = np.random.default_rng(3)
    shift = rng.normal(0.0, SD, N)
    e = sign_evidence(shift, healthy_covariance(b), healthy_covariance(b), (2, 4, 6))
    pr = [shift[k] / SD for k, (_, mode, _, band) in enumerate(COUPLING_FEATURES) if mode == PITCH and band in (2, 4, 6)]
    br = [shift[k] / SD for k, (_, mode, _, band) in enumerate(COUPLING_FEATURES) if mode == BOUNCE and band in (2, 4, 6)]
    assert e.score_pr == pytest.approx(sum(pr) / np.sqrt(3)) and e.score_br == pytest.approx(sum(br) / np.sqrt(3))
    np.testing.assert_allclose(e.band_scores_pr, pr)


def test_the_raw_shift_is_recovered_from_the_whitened_one() -> None:
    b = baseline()
    x = np.linspace(0.3, -0.2, N)
    np.testing.assert_allclose(raw_shift(b, b.whiten(x)), x - b.center, atol=1e-12)
    np.testing.assert_allclose(healthy_covariance(b), covariance(), atol=1e-15)


def test_no_shifts_or_a_load_state_without_sign_bands_give_no_evidence() -> None:
    b = baseline()
    assert diagnose([], b, "full") == NO_EVIDENCE
    assert diagnose(windows_of(shift_of(Corner.LEADING_LEFT, "full", 6.0), b), b, "half") == NO_EVIDENCE
    assert NO_EVIDENCE.stated() == NO_EVIDENCE


def test_a_diagnosis_as_an_event_states_it_has_its_confidences_and_cosine_to_three_decimals() -> None:
    d = Diagnosis(pair(Corner.LEADING_LEFT), UNKNOWN, 0.94649, 0.00049, "words", -0.12351, 3)
    assert d.stated() == Diagnosis(pair(Corner.LEADING_LEFT), UNKNOWN, 0.946, 0.0, "words", -0.124, 3)


@settings(max_examples=40, deadline=None)
@given(
    corner=st.sampled_from(list(Corner)),
    load=st.sampled_from(["full", "tare"]),
    seed=st.integers(0, 2**31 - 1),
)
def test_the_corner_follows_the_signs_whatever_the_healthy_spread_and_center(corner: Corner, load: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 1.0, (N, N))
    cov = SD**2 * (a @ a.T / N + 0.2 * np.eye(N))
    b = baseline(cov, rng.normal(0.0, 0.1, N))
    sd = np.sqrt(np.diag(cov))
    shift = np.sign(shift_of(corner, load, 1.0)) * 1.2 * MIN_SCORE * sd  # every read band beyond MIN_SCORE: the sum is too
    d = diagnose(windows_of(shift, b), b, load)
    assert d.corners == pair(corner) and d.corner_confidence <= PAIR_CONFIDENCE_MAX


# --------------------------------------------------------------------------------------------
# The geometry: the configured corners change the modal matrix, not the physical answer

QUIET = ChannelStats((9.81,) * 3, (12.0,) * 3, (0.0,) * 3, (0.002,) * 3, (0.0,) * 3)
LAYOUTS = [
    (Corner.LEADING_LEFT, Corner.LEADING_RIGHT, Corner.TRAILING_LEFT),
    (Corner.TRAILING_RIGHT, Corner.TRAILING_LEFT, Corner.LEADING_RIGHT),
    (Corner.LEADING_RIGHT, Corner.TRAILING_RIGHT, Corner.LEADING_LEFT),
    (Corner.TRAILING_LEFT, Corner.LEADING_LEFT, Corner.TRAILING_RIGHT),
]


def sensor_spectra(modal_coupling: np.ndarray, geometry: BogieGeometry) -> WindowSpectra:
    """The channels' band spectra of a frame whose modal accelerations have unit power and these
    couplings (COUPLING_FEATURES order), seen by sensors at the geometry's corners."""
    modal = np.tile(np.eye(3, dtype=np.complex128), (len(BANDS_HZ) - 1, 1, 1))
    for value, (_, i, j, band) in zip(modal_coupling, COUPLING_FEATURES, strict=True):
        modal[band, i, j] = modal[band, j, i] = value
    s = geometry.sensor_matrix()
    return WindowSpectra(BANDS_HZ, np.einsum("ai,bij,cj->bac", s, modal, s))


def window(spectra: WindowSpectra, t_s: float) -> WindowIndicators:
    return WindowIndicators(
        start_s=t_s, end_s=t_s + 120.0, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=0,
        rms_mps2=(1.0, 1.0, 1.0), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=QUIET, spectra=spectra,
    )  # fmt: skip


@pytest.mark.parametrize("layout", LAYOUTS, ids=lambda c: "+".join(x.value for x in c))
def test_the_decider_names_the_physical_corner_whatever_corners_the_sensors_are_on(layout: tuple[Corner, Corner, Corner]) -> None:
    geometry = BogieGeometry(corners=layout)
    b = Baseline("calibrated", np.zeros(N), whitening_of(covariance()), LEVELS, trend_tau_s=1800.0)
    decider = Decider(DecisionSettings({}, confirm_k=3, confirm_n=5, method=Method.FUSED, baselines={LoadState.FULL: b}), "cfg", geometry=geometry, hop_s=10.0)
    physical = shift_of(Corner.TRAILING_RIGHT, "full", 8.0)  # a softer trailing-right corner, in every band read
    spectra = sensor_spectra(physical, geometry)
    events = [e for i in range(3) for e in decider.update(window(spectra, 10.0 * i), LoadState.FULL)[1]]
    (confirmed,) = [e for e in events if e.kind is EventKind.CONFIRMED]
    assert isinstance(confirmed.details, ConfirmedDetails) and confirmed.details.diagnosis is not None
    assert confirmed.details.diagnosis.corners == (Corner.TRAILING_RIGHT, Corner.LEADING_LEFT)
    # The channels themselves differ from the paper's layout's: only the modal map undoes them.
    paper = sensor_spectra(physical, BogieGeometry())
    assert layout == LAYOUTS[0] or not np.allclose(spectra.matrix, paper.matrix)


def test_roll_is_read_with_the_sign_of_the_left_rail_whatever_the_layout() -> None:
    # The frame rolling left up: the left sensors read more, whichever two of them there are.
    for layout in LAYOUTS:
        rows = BogieGeometry(corners=layout).sensor_matrix()
        left = [i for i, c in enumerate(layout) if c.y_sign > 0]
        right = [i for i, c in enumerate(layout) if c.y_sign < 0]
        assert all(rows[i, ROLL] > 0 for i in left) and all(rows[i, ROLL] < 0 for i in right)


# --------------------------------------------------------------------------------------------
# A simulated broken spring on model A


@pytest.fixture(scope="module")
def commissioned():
    """The default config commissioned at full load on four healthy 450 s runs of the nominal wagon."""
    from bogiemon.daemon.calibrate import calibrate_windows, fragment
    from bogiemon.daemon.config import BogiemonConfig
    from bogiemon.detection import IndicatorStream
    from bogiemon.lab.robust.judge import with_fragment
    from bogiemon.simulator import Scenario, SpeedProfile, simulate_batch

    config = BogiemonConfig()
    tracks = [("erri-low", 70.0), ("fra-5", 90.0), ("erri-high", 80.0), ("fra-6", 100.0)]
    runs = simulate_batch([Scenario(load="full", track=t, speed=SpeedProfile.constant(v), duration_s=450.0, seed=s)
                           for s, (t, v) in enumerate(tracks)])  # fmt: skip
    windows, numbers = [], []
    for k, r in enumerate(runs):
        run_windows = IndicatorStream(config.processing_settings(), config.bogie_geometry()).process(r.accel_mps2)
        windows += run_windows
        numbers += [k] * len(run_windows)
    return with_fragment(config, fragment(calibrate_windows(windows, config, "full", runs=numbers)))


@pytest.mark.slow
def test_a_simulated_broken_rear_coil_is_named_at_its_corner_or_unknown(commissioned) -> None:
    from bogiemon.judgement.verdict import WindowJudge
    from bogiemon.detection import IndicatorStream
    from bogiemon.simulator import Fault, Scenario, SpeedProfile, simulate_batch

    corners = list(Corner)
    # A broken rear outer coil at full load: Kz and the Lenoir damper's grip both fall, softer in every sense.
    faults = [Fault(kind="type_a", corner=c, position="rear_outer", severity=0.0) for c in corners]
    runs = simulate_batch(
        [Scenario(load="full", track="erri-high", speed=SpeedProfile.constant(80.0), duration_s=330.0, seed=40 + k, faults=(f,), fault_onset_s=90.0)
         for k, f in enumerate(faults)]
    )  # fmt: skip
    settings = commissioned.monitor_settings()
    named = []
    for corner, run in zip(corners, runs, strict=True):
        judge = WindowJudge(settings)
        events = [e for w in IndicatorStream(settings.processing, settings.geometry).process(run.accel_mps2) for e in judge.judge(w).events]
        confirmed = [e for e in events if e.kind is EventKind.CONFIRMED]
        assert confirmed, (corner, [e.kind for e in events])
        assert confirmed[0].time_s > 90.0
        assert isinstance(confirmed[0].details, ConfirmedDetails) and confirmed[0].details.diagnosis is not None
        named.append(tuple(c.value for c in confirmed[0].details.diagnosis.corners))
    # Never a pair without the broken coil's corner. Named only where the three confirming
    # windows' 4-8 Hz pitch-roll coupling is clear: they confirm 50-60 s after the break, so the
    # oldest of them holds little of the fault.
    assert all(not n or c.value in n for n, c in zip(named, corners, strict=True)), named
    assert sum(bool(n) for n in named) >= 2, named
