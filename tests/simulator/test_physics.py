"""Physics of the wagon model: equilibrium, natural frequencies, free decay, boundedness, the paper's effect."""

import numpy as np
import pytest
from scipy import signal

from bogiemon.detection import IndicatorStream, ProcessingSettings
from bogiemon.simulator import kernel
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.run import simulate, simulate_batch
from bogiemon.simulator.scenario import Scenario, SpeedProfile
from bogiemon.simulator.suspension import CORNER_ORDER, parse_fault
from bogiemon.simulator.vehicle import State, VehicleModel, build_model, forces_reference, natural_frequencies, static_equilibrium

PARAMS = default_parameter_set()


@pytest.mark.parametrize("load", ["full", "tare"])
@pytest.mark.parametrize("faults", [(), ("type_a:rear_outer:0.0@leading-left", "type_b::0.5@trailing-bogie:leading-right")])
def test_on_a_perfect_track_the_wagon_rests_with_the_springs_carrying_the_weight(load, faults) -> None:
    scenario = Scenario(load=load, track="perfect", duration_s=5.0, faults=tuple(parse_fault(f) for f in faults))
    result = simulate(scenario)
    model = result.model
    assert isinstance(model, VehicleModel)
    rest = static_equilibrium(model)
    weight_n = model.params.sprung_mass_kg * model.params.gravity_mps2
    zero8 = np.zeros(8)
    for state in (rest, result.final_state):
        forces, _, primary = forces_reference(model, state.q, state.v, zero8, zero8, state.slider)
        assert np.sum(primary) == pytest.approx(weight_n, rel=1e-9)
        assert np.max(np.abs(forces)) < 1e-3  # N, out of 8e5
    np.testing.assert_allclose(result.final_state.q, rest.q, atol=1e-12)
    np.testing.assert_allclose(result.accel_mps2, model.params.gravity_mps2, atol=1e-9)  # at rest: +g


# Natural frequencies (Hz) of the model linearised about rest, two limits of the friction:
# sliding (no friction stiffness: large amplitudes) and stuck (k_stick in parallel with Kz).
# Where the ranges come from, sliding: carbody bounce f = sqrt(8 Kz / (m_carbody + 2 m_frame)) / 2 pi
# (2.48 Hz full, 4.3 Hz tare: loaded freight wagons are quoted at 2-3 Hz); carbody pitch the same
# with the pitch inertia and the bogie spacing; carbody roll from the side bearers in series with
# the primary roll stiffness (about 1 Hz loaded: a soft, tall load); frame pitch
# sqrt(4 Kz l^2 / I_pitch) / 2 pi (12.7 Hz full, 7.9 Hz tare) and frame roll likewise plus the
# side bearers; frame bounce is the frame on the stiff centre bowl (80-100 Hz). Each range is the
# estimate +/- about 20 % for the simplifications (point bowl, rigid frame, no track flexibility).
FREQUENCY_RANGES_HZ = {
    ("full", False): {
        "carbody bounce": (2.0, 3.0), "carbody pitch": (2.4, 3.6), "carbody roll": (0.6, 1.5),
        "frame bounce": (60, 120), "frame pitch": (10, 16), "frame roll": (11, 17),
    },
    ("tare", False): {
        "carbody bounce": (3.5, 5.5), "carbody pitch": (4.0, 6.0), "carbody roll": (2.5, 4.0),
        "frame bounce": (60, 130), "frame pitch": (6.0, 10.0), "frame roll": (7.0, 12.0),
    },
    # Stuck: every corner k_stick + Kz; the same formulas give 6.9 / 8.3 Hz for the loaded carbody
    # and 38 Hz for the frame, whatever the load (k_stick >> Kz).
    ("full", True): {
        "carbody bounce": (5.5, 8.5), "carbody pitch": (6.5, 10.0), "carbody roll": (0.6, 1.5),
        "frame bounce": (60, 120), "frame pitch": (30, 46), "frame roll": (30, 46),
    },
    ("tare", True): {
        "carbody bounce": (15, 23), "carbody pitch": (17, 27), "carbody roll": (2.5, 4.5),
        "frame bounce": (60, 130), "frame pitch": (30, 46), "frame roll": (30, 46),
    },
}  # fmt: skip


@pytest.mark.parametrize(("load", "stick"), list(FREQUENCY_RANGES_HZ))
def test_natural_frequencies_fall_in_the_stated_ranges(load: str, stick: bool) -> None:
    found = natural_frequencies(build_model(PARAMS, load), stick=stick)
    ranges = FREQUENCY_RANGES_HZ[(load, stick)]
    assert set(found) == set(ranges)
    for mode, (low, high) in ranges.items():
        assert low <= found[mode] <= high, (mode, found[mode])


def test_carbody_bounce_is_softer_in_full_load_than_in_tare() -> None:
    full = natural_frequencies(build_model(PARAMS, "full"), stick=False)
    tare = natural_frequencies(build_model(PARAMS, "tare"), stick=False)
    assert full["carbody bounce"] < 0.7 * tare["carbody bounce"]


def _free_decay(model, initial: State, duration_s: float, dt_s: float = 2.5e-4) -> np.ndarray:
    """Kernel run from `initial` on a perfect track at standstill; (n, 3) leading-frame sensors."""
    n = int(duration_s / dt_s)
    out = np.empty((1, n, 3))
    sensors = np.array([[[0.9, 1.0], [0.9, -1.0], [-0.9, 1.0]]])
    kernel.advance(
        initial.q[None].copy(), initial.v[None].copy(), initial.slider[None].copy(), np.array([20.0]),
        np.array([0.0]), np.array([n]), kernel.pack_vehicle(model.params, 0.05, dt_s)[None],
        model.corner_table()[None], np.zeros((1, 1)), np.zeros((1, 1)), np.array([1]),
        np.zeros((1, 1000)), np.zeros((1, 1000)), sensors, kernel.IDENTITY_SOS, np.zeros((1, 1, 2, 3)), 1, out,
    )  # fmt: skip
    return out[0]


def _peak_hz(x: np.ndarray, fs_hz: float, lo_hz: float, hi_hz: float) -> float:
    f, p = signal.periodogram(x - x.mean(), fs=fs_hz, nfft=1 << 20)
    band = (f > lo_hz) & (f < hi_hz)
    return float(f[band][np.argmax(p[band])])


@pytest.mark.parametrize("load", ["full", "tare"])
def test_free_decay_without_friction_rings_at_the_linearised_frequencies(load: str) -> None:
    """Fs = 0 at every corner (custom faults): the model is linear and its free decay shows the eigenvalues."""
    healthy_kz = PARAMS["fault_cases"]["healthy"][load]["Kz"]
    faults = tuple(
        parse_fault(f"custom:{healthy_kz}:0@{bogie}{corner.value}")
        for bogie in ("", "trailing-bogie:")
        for corner in CORNER_ORDER
    )
    model = build_model(PARAMS, load, faults)
    expected = natural_frequencies(model, stick=False)
    rest = static_equilibrium(model)
    kick = np.zeros(9)
    kick[[0, 3, 6]] = 0.005  # carbody and frames 5 mm up: bounce
    kick[[4, 5]] = 0.002  # leading frame pitched and rolled
    accel = _free_decay(model, State(q=rest.q + kick, v=rest.v, slider=rest.slider), 20.0)
    fs_hz = 4000.0
    bounce = 0.5 * (accel[:, 1] + accel[:, 2])
    pitch = (accel[:, 0] - accel[:, 2]) / 1.8
    carbody_hz = expected["carbody bounce"]
    assert _peak_hz(bounce, fs_hz, 0.5 * carbody_hz, 1.5 * carbody_hz) == pytest.approx(carbody_hz, rel=0.01)
    pitch_hz = expected["frame pitch"]
    assert _peak_hz(pitch, fs_hz, 0.7 * pitch_hz, 1.3 * pitch_hz) == pytest.approx(pitch_hz, rel=0.01)


def test_with_friction_a_free_decay_slides_then_sticks_and_rings_at_the_stuck_frequency() -> None:
    """Coulomb-like decay while sliding; once every damper sticks, the wagon rings on Kz + k_stick."""
    model = build_model(PARAMS, "full")
    rest = static_equilibrium(model)
    kick = np.zeros(9)
    kick[[0, 3, 6]] = 0.01  # 10 mm up: the dampers slide
    accel = _free_decay(model, State(q=rest.q + kick, v=rest.v, slider=rest.slider), 10.0)
    bounce = accel.mean(axis=1) - model.params.gravity_mps2
    first, last = np.abs(bounce[:4000]).max(), np.abs(bounce[-8000:]).max()
    assert first > 2.0 and last < 0.1 * first
    stuck_hz = natural_frequencies(model, stick=True)["carbody bounce"]
    assert _peak_hz(bounce[-16000:], 4000.0, 0.5 * stuck_hz, 1.5 * stuck_hz) == pytest.approx(stuck_hz, rel=0.02)


@pytest.mark.parametrize("load", ["full", "tare"])
def test_ten_minutes_at_120_kmh_on_high_level_track_stay_bounded(load: str) -> None:
    scenario = Scenario(
        load=load,
        track="erri-high",
        speed=SpeedProfile.constant(120.0),
        duration_s=600.0,
        faults=(parse_fault("type_a:rear_outer:0.0@leading-left"),),
    )
    result = simulate(scenario)
    accel = result.accel_mps2
    assert np.isfinite(accel).all()
    rms = np.sqrt(np.mean((accel - accel.mean(axis=0)) ** 2, axis=0))
    assert np.all((rms > 0.3) & (rms < 15.0)), rms
    assert np.max(np.abs(accel - 9.81)) < 100.0
    # Neither the first nor the last minute grows: same RMS within a factor 1.5.
    first, last = accel[:30000].std(axis=0), accel[-30000:].std(axis=0)
    assert np.all(last < 1.5 * first) and np.all(first < 1.5 * last)
    assert isinstance(result.model, VehicleModel)
    rest = static_equilibrium(result.model)
    assert np.max(np.abs(result.final_state.q - rest.q)[[0, 3, 6]]) < 0.05  # m


def _zero_lag_coefficients(results) -> np.ndarray:
    """Per result: mean over 60 s windows of C_BR(0) and C_PR(0) normalised, and of I2 and I4."""
    out = []
    for r in results:
        settings = ProcessingSettings(fs_hz=r.scenario.fs_hz)
        stream = IndicatorStream(settings, r.scenario.geometry)
        rows = []
        for ind, corr in stream.process_with_correlations(r.accel_mps2):
            c_br0, c_pr0 = corr.lagged[0][settings.max_lag_n], corr.lagged[1][settings.max_lag_n]
            rows.append(
                [
                    c_br0 / (ind.rms_bounce_mps2 * ind.rms_roll_radps2),
                    c_pr0 / (ind.rms_pitch_radps2 * ind.rms_roll_radps2),
                    ind.i2,
                    ind.i4,
                ]
            )
        out.append(np.mean(rows, axis=0))
    return np.array(out)


def test_a_broken_spring_at_full_load_couples_pitch_and_roll_while_a_healthy_wagon_does_not() -> None:
    """The paper's main effect: C_PR(0) (and C_BR(0)) ~0 for a healthy wagon, clearly not with a broken spring."""
    seeds = range(6)
    broken = (parse_fault("type_a:rear_outer:0.0@leading-left"),)
    scenarios = [Scenario(seed=s, duration_s=120.0) for s in seeds]
    scenarios += [Scenario(seed=s, duration_s=120.0, faults=broken) for s in seeds]
    values = _zero_lag_coefficients(simulate_batch(scenarios))
    healthy, faulty = values[:6], values[6:]
    sem = healthy.std(axis=0, ddof=1) / np.sqrt(len(seeds))
    # Healthy: both coefficients average to zero within 3 standard errors, and are small.
    assert np.all(np.abs(healthy.mean(axis=0)[:2]) < 3 * sem[:2] + 1e-3)
    assert np.all(np.abs(healthy[:, :2]) < 0.08)
    # Broken rear outer coil at the leading-left corner: C_PR(0) strongly positive in every run,
    # C_BR(0) clearly positive, I2 and I4 above every healthy run.
    assert np.all(faulty[:, 1] > 0.3)
    assert faulty[:, 1].min() > healthy[:, 1].max() + 10 * healthy[:, 1].std()
    assert faulty[:, 0].min() > 3 * np.abs(healthy[:, 0]).max()
    assert faulty[:, 2].min() > healthy[:, 2].max()
    assert faulty[:, 3].min() > np.abs(healthy[:, 3]).max()
