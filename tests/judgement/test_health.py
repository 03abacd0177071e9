"""Sensor health and gating: sensor faults and standstill are told apart from the suspension."""

import dataclasses

import numpy as np
import pytest

from bogiemon.daemon.config import ConfigError, parse_config
from bogiemon.judgement.events import EventKind, SensorFaultDetails
from bogiemon.judgement.gating import Gate
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.health import SensorProblem, assess_window, coherence_noisy_channel, same_rail_pair
from bogiemon.judgement.sensor_tracker import HealthTracker
from bogiemon.judgement.settings import LAYOUT_CHECKS
from bogiemon.judgement.structure import LayoutFit, layout_fit, learn_structure, merge_structures
from bogiemon.detection import BogieGeometry, Corner, WindowIndicators
from bogiemon.detection.channel_stats import NOT_MEASURED, ChannelStats
from bogiemon.detection.spectra import BANDS_HZ, N_BANDS, WindowSpectra
from bogiemon.drivers.base import SensorStatus
from tests.judgement.event_examples import details_as

SETTINGS = HealthSettings()
OK = SensorStatus.OK
GEOMETRY = BogieGeometry()  # a1 leading-left, a2 leading-right, a3 trailing-left: a1 and a3 on the left rail


def window(
    rms=(1.0, 1.1, 0.9), repeat=(0.0, 0.0, 0.0), clipped=(0.0, 0.0, 0.0), t=0.0, run_s=(0.002, 0.002, 0.002),
    hop_min=NOT_MEASURED, hop_max=NOT_MEASURED, matrix=None,
) -> WindowIndicators:  # fmt: skip
    stats = ChannelStats((9.81,) * 3, (10.0,) * 3, tuple(repeat), tuple(run_s), tuple(clipped), tuple(hop_min), tuple(hop_max))
    return WindowIndicators(
        start_s=t, end_s=t + 60, i1=0, i2=0, i3=0, i4=0, i1_norm=0, i2_norm=0, i3_norm=0, i4_norm=0,
        rms_mps2=tuple(rms), rms_bounce_mps2=1, rms_pitch_radps2=1, rms_roll_radps2=1, channels=stats,
        spectra=None if matrix is None else WindowSpectra(BANDS_HZ, matrix),
    )  # fmt: skip


def frame_matrix(noise=(0.0, 0.0, 0.0), phase_rad=0.3, independent_rails=False) -> np.ndarray:
    """Band cross-spectra of a frame on two rails, (m/s^2)^2 per band: a1 and a3 on the left rail,
    a3 meeting each wave phase_rad after a1 at 0.5-1 Hz, a2 on the right rail, which moves with the
    left one in part; plus white noise of the given power per channel in the lowest band. With
    independent_rails, a3's rail has nothing in common with a1's."""
    out = np.zeros((N_BANDS, 3, 3), dtype=np.complex128)
    for b in range(N_BANDS):
        s = 1e-3 * 4.0**b  # the frame's acceleration grows with frequency
        delay = np.exp(-1j * phase_rad * 2.0**b)
        left, right, third = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0])
        a1 = left
        a3 = third if independent_rails else delay * left
        a2 = 0.6 * left + 0.8 * right
        h = np.array([a1, a2, a3])  # (channels, inputs)
        out[b] = s * h @ h.conj().T + np.diag([1e-7, 1e-7, 1e-7])  # the sensors' own small noise
    out[0] += np.diag(noise)
    return out


def test_a_running_healthy_bogie_is_judgeable() -> None:
    health = assess_window(window(), SETTINGS)
    assert health.judgeable and health.gate is None and health.problems == {}


@pytest.mark.parametrize(
    ("kwargs", "status", "gaps", "expected"),
    [
        ({"rms": (0.001, 1.0, 1.0)}, (OK, OK, OK), 0, {"a1": (SensorProblem.FLAT,)}),
        ({"repeat": (0.0, 0.9, 0.0)}, (OK, OK, OK), 0, {"a2": (SensorProblem.STUCK,)}),
        ({"run_s": (0.002, 0.002, 1.5)}, (OK, OK, OK), 0, {"a3": (SensorProblem.STUCK,)}),
        ({"clipped": (0.0, 0.0, 0.01)}, (OK, OK, OK), 0, {"a3": (SensorProblem.CLIPPING,)}),
        ({"rms": (1.0, 9.0, 1.0)}, (OK, OK, OK), 0, {"a2": (SensorProblem.NOISY,)}),
        ({"rms": (60.0, 60.0, 60.0)}, (OK, OK, OK), 0, {c: (SensorProblem.NOISY,) for c in ("a1", "a2", "a3")}),
        ({}, (OK, SensorStatus.SENSOR_FAULT, OK), 0, {"a2": (SensorProblem.SENSOR_FAULT_BIT,)}),
        ({}, (SensorStatus.OVER_RANGE, OK, OK), 0, {"a1": (SensorProblem.OVER_RANGE,)}),
        ({}, (OK, OK, OK), 7, {"source": (SensorProblem.DROPOUTS,)}),
    ],
    ids=["flat", "stuck", "stuck-just-now", "clipping", "noisy-ratio", "noisy-absolute", "fault-bit", "over-range-bit", "dropouts"],
)
def test_each_sensor_problem_is_named_on_its_channel(kwargs, status, gaps, expected) -> None:
    health = assess_window(window(**kwargs), SETTINGS, status, gaps)
    assert health.problems == expected
    assert not health.judgeable


def test_all_channels_quiet_is_standstill_not_a_sensor_fault() -> None:
    health = assess_window(window(rms=(0.01, 0.01, 0.01), repeat=(0.5, 0.5, 0.5)), SETTINGS)
    assert health.gate is Gate.STANDSTILL and health.sensors_ok and not health.judgeable


def test_moving_gently_is_weak_excitation() -> None:
    health = assess_window(window(rms=(0.1, 0.1, 0.1)), SETTINGS)
    assert health.gate is Gate.WEAK_EXCITATION and health.sensors_ok


def test_tracker_reports_a_fault_once_and_clears_after_healthy_moving_windows() -> None:
    tracker = HealthTracker("cfg", clear_after_windows=2)
    bad, good, still = window(rms=(0.001, 1, 1)), window(), window(rms=(0.01, 0.01, 0.01))
    kinds = []
    for w in (bad, bad, good, still, still, good, good, good):
        kinds.append([e.kind for e in tracker.update(w, assess_window(w, SETTINGS))])
    assert kinds == [[EventKind.SENSOR_FAULT], [], [], [], [], [EventKind.SENSOR_CLEARED], [], []]


def test_tracker_reports_again_when_a_new_problem_appears() -> None:
    tracker = HealthTracker("cfg")
    first = tracker.update(window(rms=(0.001, 1, 1)), assess_window(window(rms=(0.001, 1, 1)), SETTINGS))
    w = window(rms=(0.001, 1, 1), repeat=(0, 0.9, 0))
    second = tracker.update(w, assess_window(w, SETTINGS))
    assert details_as(first[0], SensorFaultDetails).problems == {"a1": ("flat",)}
    assert details_as(second[0], SensorFaultDetails).problems == {"a1": ("flat",), "a2": ("stuck",)}
    assert details_as(second[0], SensorFaultDetails).reported == {"a1": ("flat",), "a2": ("stuck",)}


def test_a_problem_that_comes_and_goes_while_the_fault_lasts_is_reported_once() -> None:
    tracker = HealthTracker("cfg")
    flat, flat_and_stuck = window(rms=(0.001, 1, 1)), window(rms=(0.001, 1, 1), repeat=(0.9, 0, 0))
    events = []
    for w in (flat, flat_and_stuck, flat, flat_and_stuck, flat):
        events += tracker.update(w, assess_window(w, SETTINGS))
    assert [details_as(e, SensorFaultDetails).problems for e in events] == [{"a1": ("flat",)}, {"a1": ("flat", "stuck")}]


def test_a_window_with_a_standing_hop_is_non_stationary_not_judged() -> None:
    health = assess_window(window(hop_min=(0.01, 0.01, 0.012), hop_max=(1.2, 1.3, 1.2)), SETTINGS)
    assert health.gate is Gate.NON_STATIONARY and health.sensors_ok and not health.judgeable


def test_a_window_whose_quietest_hop_has_a_fifth_of_the_loudest_is_non_stationary() -> None:
    health = assess_window(window(hop_min=(0.2, 0.2, 0.2), hop_max=(1.0, 1.0, 1.0)), SETTINGS)
    assert health.gate is Gate.NON_STATIONARY


def test_hops_within_half_of_each_other_are_steady_running() -> None:
    health = assess_window(window(hop_min=(0.5, 0.5, 0.5), hop_max=(1.0, 1.0, 1.0)), SETTINGS)
    assert health.gate is None and health.judgeable


def test_one_channel_s_own_hops_do_not_make_the_window_non_stationary() -> None:
    # a2 dead (its hops read nothing) and a3 noisy in one hop: the median channel runs steadily.
    health = assess_window(window(hop_min=(0.8, 0.0, 0.8), hop_max=(1.1, 0.0, 9.0)), SETTINGS)
    assert health.gate is None


def test_a_converter_s_repeats_while_the_wagon_stood_in_the_window_are_not_stuck() -> None:
    standing = assess_window(window(repeat=(0.3, 0.3, 0.3), hop_min=(0.01,) * 3, hop_max=(1.0,) * 3), SETTINGS)
    running = assess_window(window(repeat=(0.3, 0.0, 0.0), hop_min=(0.8,) * 3, hop_max=(1.0,) * 3), SETTINGS)
    assert standing.problems == {}
    assert running.problems == {"a1": (SensorProblem.STUCK,)}


def test_a_sensor_fault_clears_only_on_windows_that_every_check_saw() -> None:
    tracker = HealthTracker("cfg", clear_after_windows=2)
    bad, good = window(rms=(0.001, 1, 1)), window()
    weak, stop = window(rms=(0.1, 0.1, 0.1)), window(hop_min=(0.01,) * 3, hop_max=(1.0,) * 3)
    kinds = [[e.kind for e in tracker.update(w, assess_window(w, SETTINGS))] for w in (bad, weak, stop, weak, stop, good, good)]
    assert kinds == [[EventKind.SENSOR_FAULT], [], [], [], [], [], [EventKind.SENSOR_CLEARED]]


def test_the_two_sensors_on_one_rail_are_found_from_the_corners() -> None:
    assert same_rail_pair(GEOMETRY) == (0, 2, 1)
    other = BogieGeometry(corners=(Corner.TRAILING_RIGHT, Corner.LEADING_LEFT, Corner.LEADING_RIGHT))
    assert same_rail_pair(other) == (0, 2, 1)
    assert same_rail_pair(BogieGeometry(corners=(Corner.LEADING_LEFT, Corner.TRAILING_LEFT, Corner.TRAILING_RIGHT))) == (0, 1, 2)


@pytest.mark.parametrize("channel", [0, 2], ids=["a1", "a3"])
def test_white_noise_on_a_sensor_of_the_rail_pair_is_named_from_the_coherence(channel: int) -> None:
    # Noise as strong as the frame's motion at 0.5-1 Hz (SNR 1): far below the RMS check.
    noise = [0.0, 0.0, 0.0]
    noise[channel] = 1e-3
    health = assess_window(window(matrix=frame_matrix(tuple(noise))), SETTINGS, geometry=GEOMETRY)
    assert health.problems == {f"a{channel + 1}": (SensorProblem.NOISY,)}


def test_a_healthy_frame_is_not_noisy_and_a_third_of_its_motion_in_noise_is_still_tolerated() -> None:
    assert coherence_noisy_channel(frame_matrix(), GEOMETRY, SETTINGS) is None
    assert coherence_noisy_channel(frame_matrix((0.25e-3, 0.0, 0.0)), GEOMETRY, SETTINGS) is None  # SNR 4: above the bound
    assert coherence_noisy_channel(frame_matrix((0.5e-3, 0.0, 0.0)), GEOMETRY, SETTINGS) == 0  # SNR 2: below it


def test_the_lone_sensor_s_noise_is_not_blamed_on_the_rail_pair() -> None:
    assert coherence_noisy_channel(frame_matrix((0.0, 1e-3, 0.0)), GEOMETRY, SETTINGS) is None


def test_waves_too_short_for_the_premise_say_nothing_about_noise() -> None:
    # Walking pace: the rail pair's cross-spectrum is 1.2 rad out of phase at 0.5-1 Hz.
    assert coherence_noisy_channel(frame_matrix((1e-3, 0.0, 0.0), phase_rad=1.2), GEOMETRY, SETTINGS) is None


def test_a_coherence_lost_without_extra_power_names_no_one() -> None:
    # The two rail sensors disagree with equal power (a swap, or a frame that does not follow
    # the rail): not the signature of white noise on one of them.
    assert coherence_noisy_channel(frame_matrix(independent_rails=True), GEOMETRY, SETTINGS) is None


def test_without_the_frame_s_structure_checks_no_coherence_noise_is_judged() -> None:
    off = dataclasses.replace(SETTINGS, structure_checks=False)
    assert assess_window(window(matrix=frame_matrix((1e-3, 0.0, 0.0))), off, geometry=GEOMETRY).problems == {}


def test_a_window_gated_for_weak_excitation_is_not_judged_for_noise() -> None:
    health = assess_window(window(rms=(0.1, 0.1, 0.1), matrix=frame_matrix((1e-3, 0.0, 0.0))), SETTINGS, geometry=GEOMETRY)
    assert health.gate is Gate.WEAK_EXCITATION and health.problems == {}


def test_an_uncommissioned_wagon_has_no_layout_check_in_force() -> None:
    inverted = frame_matrix() * np.array([1.0, 1.0, -1.0])[None, :, None] * np.array([1.0, 1.0, -1.0])[None, None, :]
    assert SETTINGS.layout_checks == ()
    assert layout_fit(inverted, GEOMETRY, SETTINGS) is None
    assert layout_fit(inverted, GEOMETRY, dataclasses.replace(SETTINGS, layout_checks=("low",))) == LayoutFit((0, 1, 2), (1.0, 1.0, -1.0))


def test_learn_structure_without_windows_puts_no_check_in_force() -> None:
    fit = learn_structure([], GEOMETRY)
    assert fit.checks == () and fit.windows == 0 and fit.health_fields() == {"layout_checks": []}


def test_a_learned_structure_reads_back_from_the_config_as_the_same_settings() -> None:
    windows = [window(matrix=frame_matrix(phase_rad=0.2 + 0.05 * k)) for k in range(4)]
    fit = learn_structure(windows, GEOMETRY)
    assert fit.windows == 4 and "low" in fit.checks
    assert fit.thresholds["low"] == pytest.approx(fit.smallest["low"] / 2)
    lines = [f"{name} = {value!r}".replace("'", '"') for name, value in fit.health_fields().items()]
    config = parse_config("[health]\n" + "\n".join(lines) + "\n", "calibration.toml")
    assert config.health_settings() == fit.applied_to(HealthSettings())
    assert config.health_settings().layout_checks == fit.checks


def test_unknown_or_repeated_layout_checks_are_refused() -> None:
    with pytest.raises(ValueError, match="unknown layout checks"):
        HealthSettings(layout_checks=("low", "sideways"))
    with pytest.raises(ConfigError, match="layout_checks"):
        parse_config('[health]\nlayout_checks = ["low", "low"]\n', "site.toml")
    assert set(LAYOUT_CHECKS) == {"low", "diagonal", "other", "quadrature"}


def test_merged_commissioning_structures_are_the_structure_of_their_windows_together() -> None:
    # Each load is commissioned on its own recordings; the checks in force are those of all of
    # them at once (a check that fails in one load is not in force).
    first = [window(matrix=frame_matrix(phase_rad=0.2 + 0.05 * k)) for k in range(3)]
    second = [window(matrix=frame_matrix(phase_rad=1.2 + 0.3 * k)) for k in range(3)]
    merged = merge_structures([learn_structure(first, GEOMETRY), learn_structure(second, GEOMETRY), learn_structure([], GEOMETRY)])
    together = learn_structure(first + second, GEOMETRY)
    assert merged == together
    assert merge_structures([]).checks == ()


def test_the_low_band_noise_check_speaks_only_while_the_wagon_runs_steadily() -> None:
    # Braking to a stop pitches the frame at 0.5-1 Hz: one healthy channel's power there rose 3.35
    # times the median in a simulated stop (model B), past noise_low_band_ratio.
    matrix = frame_matrix(independent_rails=True)
    matrix[0] = np.diag([1e-3, 3.4e-3, 1e-3]).astype(np.complex128)
    running = assess_window(window(matrix=matrix), SETTINGS)
    stopping = assess_window(window(matrix=matrix, hop_min=(0.028,) * 3, hop_max=(0.2,) * 3), SETTINGS)
    assert running.gate is None and running.problems == {"a2": (SensorProblem.NOISY,)}
    assert stopping.gate is Gate.NON_STATIONARY and stopping.problems == {}
