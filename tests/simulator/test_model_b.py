"""Model B, the independently built wagon: its kernel against its numpy reference, its physics, its interface."""

import copy
import json
from typing import Any
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import signal

from bogiemon.cli.main import main
from bogiemon.detection import BogieGeometry, Corner, IndicatorStream, ProcessingSettings
from bogiemon.simulator import vehicle as model_a
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import friction, kernel, sensors
from bogiemon.simulator.model_b.bodies import (
    N_DOF, N_FRICTION, State, WagonModel, build_model, build_models, forces_reference, natural_frequencies,
    nominal_corner_values, static_equilibrium, step_reference,
)  # fmt: skip
from bogiemon.simulator.model_b.parameters import default_parameter_set, wagon_parameters, with_ideal_sensor
from bogiemon.simulator.model_b.run import integrate, run_group
from bogiemon.simulator.model_b.track import event_positions_m, generate_track, track_model
from bogiemon.simulator.params import default_parameter_set as model_a_parameter_set
from bogiemon.simulator.run import rerun_sidecar, simulate, simulate_batch, write_recording
from bogiemon.simulator.scenario import Scenario, SpeedProfile, read_sidecar
from bogiemon.simulator.suspension import parse_fault
from bogiemon.simulator.track import TrackProfile

PARAMS = default_parameter_set()
IDEAL = with_ideal_sensor(PARAMS)
DT_S = 2.5e-4
BROKEN_LL = (parse_fault("type_a:rear_outer:0.0@leading-left"),)


def _no_friction(parameters: dict) -> dict:
    out = copy.deepcopy(parameters)
    out["vehicle"]["primary"]["lenoir"]["calibration_fs_full_n"] = 0.0
    out["vehicle"]["centre_bowl"]["friction_coefficient"] = 0.0
    return out


def _random_state(model, rng: np.random.Generator) -> State:
    """Off rest and moving, bristles anywhere in their range (the bowl's inside the unit disc)."""
    rest = static_equilibrium(model)
    scale = np.r_[[1e-3, 1e-4, 1e-4], [1e-3, 1e-3, 1e-3] * 2, [1e-4, 1e-4] * 4, [5e-5] * 8]
    w = rng.uniform(-1.0, 1.0, N_FRICTION)
    for i in (8, 10):
        w[i : i + 2] *= rng.uniform(0, 1) / max(np.hypot(*w[i : i + 2]), 1.0)
    return State(q=rest.q + scale * rng.standard_normal(N_DOF), v=0.03 * rng.standard_normal(N_DOF), w=w)


def _rails_at(track: TrackProfile, front_m: float, offsets, speed_mps: float):
    """The irregularity and its rate under each wheel, as the kernel interpolates them."""
    z, rate = np.empty(8), np.empty(8)
    for axle, offset in enumerate(offsets):
        x = (front_m - offset) * (1.0 / track.ds_m)
        i = int(x)
        frac = x - i
        for side, rail in enumerate((track.left_m, track.right_m)):
            z[2 * axle + side] = rail[i] + frac * (rail[i + 1] - rail[i])
            rate[2 * axle + side] = speed_mps * (rail[i + 1] - rail[i]) / track.ds_m
    return z, rate


def _kernel_run(model, state, track, speed_mps, n_steps, sensor_p, geometry, lateral, factor=1, sensor_2=None, lateral_2=None):
    """model B's kernel on one scenario from `state`: (outputs (n_steps // factor, 3 or 6), final
    state); with sensor_2 and lateral_2, the trailing frame's three channels too."""
    rate_hz = 1.0 / DT_S
    parts = (sensor_p,) if sensor_2 is None else (sensor_p, sensor_2)
    laterals = np.array([lateral] if sensor_2 is None else [lateral, lateral_2])
    n_channels = 3 * len(parts)
    q, v, w = state.q[None].copy(), state.v[None].copy(), state.w[None].copy()
    sos = sensors.chain_sos(sensor_p, rate_hz, rate_hz / factor)[None]
    g = model.params.gravity_mps2
    zi = (signal.sosfilt_zi(sos[0])[:, :, None] * np.full(n_channels, g))[None].copy()
    out = np.empty((1, n_steps // factor, n_channels))
    kernel.advance(
        q, v, w, np.array([model.params.axle_offsets_m[-1] + 5.0123]), np.zeros(1), np.array([n_steps]),
        kernel.pack_vehicle(model.params, track.ds_m, DT_S)[None], model.corner_table()[None],
        np.zeros((1, 1)), np.full((1, 1), speed_mps), np.ones(1, dtype=np.int64), track.left_m[None], track.right_m[None],
        laterals[None], np.zeros(1), rate_hz, geometry.positions_m()[None], np.concatenate([p.cross_axis for p in parts])[None],
        np.concatenate([sensors.skew_steps(p, DT_S) for p in parts])[None], sos, zi, np.full((1, n_channels, sensors.DELAY_LINE), g),
        np.zeros(1, dtype=np.int64), factor, out, np.empty((1, 0, N_DOF)),
    )  # fmt: skip
    return out[0], State(q=q[0], v=v[0], w=w[0])


# --- the compiled kernel against the numpy reference ------------------------------------------------


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), load=st.sampled_from(["full", "tare"]))
def test_one_kernel_step_is_the_reference_step_on_random_states(seed: int, load: str) -> None:
    rng = np.random.default_rng(seed)
    model = build_model(PARAMS, load, (parse_fault("type_a:front_inner:0.5@leading-right"), parse_fault("type_b::1.5@trailing-bogie:trailing-left")))
    state = _random_state(model, rng)
    track = TrackProfile(0.05, 2e-3 * rng.standard_normal(1000), 2e-3 * rng.standard_normal(1000))
    speed = rng.uniform(0.0, 33.0)
    p = model.params
    out, after = _kernel_run(model, state, track, speed, 1, p.sensor, BogieGeometry(), np.zeros(4))
    rail_z, rail_v = _rails_at(track, p.axle_offsets_m[-1] + 5.0123, p.axle_offsets_m, speed)
    ref, accel = step_reference(model, state, rail_z, rail_v, DT_S)
    np.testing.assert_allclose(after.w, ref.w, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(after.v, ref.v, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(after.q, ref.q, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("load", ["full", "tare"])
def test_the_kernel_follows_the_reference_for_800_steps_sensor_chain_included(load: str) -> None:
    rng = np.random.default_rng(7)
    model = build_model(PARAMS, load, BROKEN_LL)
    state = _random_state(model, rng)
    track = generate_track(PARAMS, "erri-high", 200.0, rng)
    speed = 25.0
    n = 800
    lateral = 0.5 * rng.standard_normal(n + 2)
    geometry = BogieGeometry(corners=(Corner.TRAILING_RIGHT, Corner.LEADING_LEFT, Corner.LEADING_RIGHT))
    p = model.params
    out, after = _kernel_run(model, state, track, speed, n, p.sensor, geometry, lateral, factor=4)

    xy = geometry.positions_m()
    vertical = np.empty((n, 3))
    ref, front = state, p.axle_offsets_m[-1] + 5.0123
    for step in range(n):
        rail_z, rail_v = _rails_at(track, front, p.axle_offsets_m, speed)
        ref, accel = step_reference(model, ref, rail_z, rail_v, DT_S)
        vertical[step] = accel[3] + xy[:, 0] * accel[4] + xy[:, 1] * accel[5] + p.gravity_mps2
        front += DT_S * speed
    np.testing.assert_allclose(after.q, ref.q, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(after.w, ref.w, rtol=1e-7, atol=1e-9)
    chain = sensors.SensorChain(p.sensor, 1.0 / DT_S, 1.0 / (4 * DT_S), 4, p.gravity_mps2)
    np.testing.assert_allclose(out, chain.process(vertical, lateral[:n]), rtol=1e-9, atol=1e-7)


# --- rest and modes -----------------------------------------------------------------------------------


@pytest.mark.parametrize("load", ["full", "tare"])
def test_at_rest_the_springs_carry_the_sprung_weight_and_the_contacts_all_of_it(load: str) -> None:
    model = build_model(PARAMS, load)
    rest = static_equilibrium(model)
    forces, _, element = forces_reference(model, rest.q, rest.v, rest.w, np.zeros(8), np.zeros(8), DT_S)
    p = model.params
    assert np.sum(element.primary_n) == pytest.approx(p.sprung_mass_kg * p.gravity_mps2, rel=1e-9)
    assert np.sum(element.contact_n) == pytest.approx(p.total_mass_kg * p.gravity_mps2, rel=1e-9)
    assert np.sum(element.bowl_n) == pytest.approx(p.carbody_mass_kg * p.gravity_mps2, rel=1e-9)
    assert np.all(element.bearer_n == 0.0)  # the healthy wagon rests inside the side bearers' clearance
    assert np.max(np.abs(forces)) < 1e-3  # N, out of 9e5


def test_on_a_perfect_track_the_wagon_stays_at_rest_and_the_sensors_read_gravity() -> None:
    result = simulate(Scenario(model="b", track="perfect", duration_s=3.0, parameters=IDEAL, faults=BROKEN_LL))
    assert isinstance(result.model, WagonModel)
    rest = static_equilibrium(result.model)
    np.testing.assert_allclose(result.final_state.q, rest.q, atol=1e-12)
    np.testing.assert_allclose(result.accel_mps2, 9.81, atol=1e-9)


# Natural frequencies (Hz) of model B linearised about rest, friction sliding (left out) or stuck
# (pre-sliding stiffness F_lim / delta: 33 MN/m per corner loaded, 5.6 MN/m empty). The ranges,
# from simple estimates +/- about 20 %:
#   carbody bounce sqrt(8 Kz / (m_c + 2 m_f)) / 2 pi: 2.86 Hz loaded (Kz 3.4 MN/m), 4.3 Hz empty
#   (1.3 MN/m); loaded freight wagons are quoted at 2-5 Hz. Stuck: the corner is Kz + k_stick in
#   series with the track (1e8 N/m), 7-8 Hz loaded;
#   carbody pitch: the same with 2 a^2 (a = 7.1 m) and the pitch inertia;
#   carbody roll, sliding: 0 Hz, nothing holds it inside the side bearers' clearance; stuck: the
#   bowls' rocking stiffness, about 1-2 Hz;
#   frame pitch sqrt(4 Kz l^2 / I) / 2 pi: 13 Hz loaded, 8 Hz empty (plus the bowl when stuck);
#   wheelset bounce (P2: wheelset and track mass on the track spring) sqrt(k_t / (m_w / 2 + m_t)) / 2 pi
#   = 52 Hz; track (P1: the track mass against the wheel on the Hertz spring) 400-500 Hz.
FREQUENCY_RANGES_HZ = {
    ("full", False): {"carbody bounce": (2.3, 3.4), "carbody pitch": (3.0, 4.5), "frame pitch": (10, 16),
                      "frame roll": (11, 18), "wheelset bounce": (40, 65), "frame bounce": (90, 140), "track": (400, 600)},
    ("tare", False): {"carbody bounce": (3.5, 5.2), "carbody pitch": (4.0, 6.2), "frame pitch": (6.5, 10),
                      "frame roll": (7.5, 11.5), "wheelset bounce": (40, 65), "frame bounce": (100, 160), "track": (300, 480)},
    ("full", True): {"carbody bounce": (6.0, 9.0), "carbody roll": (0.8, 2.0), "frame pitch": (27, 42),
                     "wheelset bounce": (45, 75), "track": (400, 600)},
    ("tare", True): {"carbody bounce": (7.5, 11.5), "carbody roll": (1.0, 2.5), "frame pitch": (14, 23),
                     "wheelset bounce": (40, 65), "track": (300, 480)},
}  # fmt: skip


@pytest.mark.parametrize(("load", "stuck"), list(FREQUENCY_RANGES_HZ))
def test_natural_frequencies_fall_in_the_stated_ranges(load: str, stuck: bool) -> None:
    found = natural_frequencies(build_model(PARAMS, load), stuck=stuck)
    for name, (low, high) in FREQUENCY_RANGES_HZ[(load, stuck)].items():
        assert low <= found[name] <= high, (name, found[name])
    if not stuck:
        assert found["carbody roll"] < 1e-3  # free inside the clearance


def test_carbody_bounce_and_the_p2_mode_differ_from_model_a_by_more_than_ten_percent() -> None:
    b = natural_frequencies(build_model(PARAMS, "full"), stuck=False)
    a = model_a.natural_frequencies(model_a.build_model(model_a_parameter_set(), "full"), stick=False)
    assert abs(b["carbody bounce"] / a["carbody bounce"] - 1.0) > 0.10
    # Model A has no wheelset on a contact; its stiffest vertical mode is the frame on the centre bowl.
    assert abs(b["wheelset bounce"] / a["frame bounce"] - 1.0) > 0.10


# --- symmetry ------------------------------------------------------------------------------------------


def test_a_healthy_wagon_on_identical_rails_does_not_roll() -> None:
    track = generate_track(IDEAL, "erri-high", 400.0, np.random.default_rng(3), fade_start_m=17.0, fade_length_m=25.0)
    same = TrackProfile(track.ds_m, track.left_m, track.left_m.copy())
    (result,) = run_group([Scenario(model="b", duration_s=8.0, parameters=IDEAL)], lambda _: None, [same])
    a = result.accel_mps2
    assert a[:, 0].std() > 1.0  # it does shake
    np.testing.assert_allclose(a[:, 0], a[:, 1], atol=1e-9)  # left and right sensors of the leading axle
    assert np.max(np.abs(result.final_state.q[[2, 5, 8, 10, 12, 14, 16]])) < 1e-12  # every roll


def test_a_fault_mirrored_from_left_to_right_mirrors_the_response() -> None:
    track = generate_track(IDEAL, "erri-high", 400.0, np.random.default_rng(4), fade_start_m=17.0, fade_length_m=25.0)
    mirrored = TrackProfile(track.ds_m, track.right_m, track.left_m)
    left = Scenario(model="b", duration_s=8.0, parameters=IDEAL, faults=BROKEN_LL)
    right = Scenario(
        model="b", duration_s=8.0, parameters=IDEAL, faults=(parse_fault("type_a:rear_outer:0.0@leading-right"),),
        geometry=BogieGeometry(corners=(Corner.LEADING_RIGHT, Corner.LEADING_LEFT, Corner.TRAILING_RIGHT)),
    )  # fmt: skip
    (a,) = run_group([left], lambda _: None, [track])
    (b,) = run_group([right], lambda _: None, [mirrored])
    np.testing.assert_allclose(b.accel_mps2, a.accel_mps2, atol=1e-8)
    # and on the same sensors the leading axle's two channels swap
    (c,) = run_group([Scenario(**{**right.__dict__, "geometry": BogieGeometry()})], lambda _: None, [mirrored])
    np.testing.assert_allclose(c.accel_mps2[:, [1, 0]], a.accel_mps2[:, :2], atol=1e-8)


# --- friction ----------------------------------------------------------------------------------------------


def test_friction_makes_a_free_decay_die_out_faster() -> None:
    amplitudes = []
    for parameters in (PARAMS, _no_friction(PARAMS)):
        model = build_model(parameters, "full")
        rest = static_equilibrium(model)
        lifted = rest.q.copy()
        lifted[0] += 0.015  # carbody 15 mm up
        _, q, _ = integrate(model, State(q=lifted, v=rest.v, w=rest.w), 3.0)
        late = q[int(2.0 / (8 * DT_S)) :, 0] - rest.q[0]
        amplitudes.append(np.max(np.abs(late)))
    with_friction, without = amplitudes
    assert without > 1e-3  # m: the structural damping alone leaves it ringing
    assert with_friction < 0.2 * without


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), dt_s=st.floats(1e-5, 2e-3))
def test_the_friction_force_never_exceeds_its_normal_load_law(seed: int, dt_s: float) -> None:
    rng = np.random.default_rng(seed)
    model = build_model(PARAMS, str(rng.choice(["full", "tare"])), BROKEN_LL)
    state = _random_state(model, rng)
    state = State(q=state.q + 0.02 * rng.standard_normal(N_DOF) * (np.arange(N_DOF) < 17), v=5 * state.v, w=state.w)
    _, w, element = forces_reference(model, state.q, state.v, state.w, np.zeros(8), np.zeros(8), dt_s)
    limit = np.array([c.mu_ratio for c in model.corners]) * np.maximum(
        [c.nest_forces_n(u)[1] for c, u in zip(model.corners, model.corner_rows() @ state.q, strict=True)], 0.0
    )
    np.testing.assert_allclose(element.friction_limit_n, limit)
    assert np.all(np.abs(element.friction_n) <= limit * (1 + 1e-12))
    assert np.all(np.hypot(w[8::2], w[9::2]) <= 1 + 1e-12)
    p = model.params
    assert np.all(np.abs(element.bowl_moment_n_m) <= p.bowl_friction_coefficient * p.bowl_friction_radius_m * np.repeat(element.bowl_n, 2) * (1 + 1e-12))


def test_in_steady_sliding_the_bristle_settles_at_the_kinetic_share_and_at_rest_it_does_not_creep() -> None:
    w = 0.0
    for _ in range(2000):
        w = friction.bristle_update(w, 0.2, 2.5e-4, 5e-4, 0.9, 0.01)
    assert w == pytest.approx(friction.stribeck(0.2, 0.9, 0.01), abs=1e-12) and w == pytest.approx(0.9, abs=1e-3)
    assert friction.bristle_update(0.37, 0.0, 2.5e-4, 5e-4, 0.9, 0.01) == 0.37
    # a slow stroke the other way (40 pre-sliding lengths) overshoots nothing: it settles at the static limit
    path = [w := friction.bristle_update(w, -1e-4, 1e-2, 5e-4, 0.9, 0.01) for _ in range(20000)]
    assert min(path) >= -1.0 and np.all(np.diff(path) <= 0)
    assert path[-1] == pytest.approx(-friction.stribeck(1e-4, 0.9, 0.01), abs=1e-12)


def test_the_lenoir_force_follows_the_rear_nest_so_coil_faults_move_fs_as_the_papers_table_1() -> None:
    def fs(spec: str) -> float:
        model = build_model(PARAMS, "full", (parse_fault(spec),))
        u = model.corner_rows() @ static_equilibrium(model).q
        return model.corners[0].breakaway_n(float(u[0]))

    kz, healthy = nominal_corner_values(wagon_parameters(PARAMS, "full"))
    assert healthy == pytest.approx(16510.0)  # the calibration
    assert fs("type_a:rear_outer:0.0@leading-left") < 0.8 * healthy  # the link's nest lost a coil
    assert fs("type_a:front_outer:0.0@leading-left") > 1.2 * healthy  # the link's nest carries more
    assert fs("type_b::0.5@leading-left") == pytest.approx(0.5 * healthy, rel=1e-3)  # the coefficient
    custom = build_model(PARAMS, "full", (parse_fault("custom:2.0e6:9000@leading-left"),))
    u = float((custom.corner_rows() @ static_equilibrium(custom).q)[0])
    assert custom.corners[0].tangent_stiffness_n_per_m(u) == pytest.approx(2.0e6)
    assert custom.corners[0].breakaway_n(u) == pytest.approx(9000.0)


def test_the_onset_keeps_the_standing_corners_friction() -> None:
    standing = (parse_fault("custom:3.2e6:15000@trailing-right"),)
    before, after = build_models(PARAMS, "full", standing, BROKEN_LL)
    assert before.corners[3] == after.corners[3] and before.corners[0] != after.corners[0]


# --- the paper's effect, determinism, interface -----------------------------------------------------------


def _c_pr0(result) -> float:
    settings_ = ProcessingSettings(fs_hz=result.scenario.fs_hz, window_s=60.0)
    values = [
        corr.lagged[1][settings_.max_lag_n] / (ind.rms_pitch_radps2 * ind.rms_roll_radps2)
        for ind, corr in IndicatorStream(settings_, result.scenario.geometry).process_with_correlations(result.accel_mps2)
    ]
    return float(np.mean(values))


@pytest.mark.slow
def test_a_broken_outer_coil_changes_the_frames_pitch_roll_coupling_clearly() -> None:
    seeds = (0, 1)
    runs = simulate_batch([Scenario(model="b", seed=s, duration_s=120.0, faults=f) for f in ((), BROKEN_LL) for s in seeds])
    healthy, broken = np.array([_c_pr0(r) for r in runs[:2]]), np.array([_c_pr0(r) for r in runs[2:]])
    assert np.all(np.abs(healthy) < 0.03)
    # Model B: the corner loses both coil and friction stiffness, C_PR(0) turns negative (A: positive).
    assert np.all(broken - healthy < -0.03)


@pytest.mark.slow
def test_ten_minutes_at_120_kmh_on_high_level_track_stay_bounded_at_both_loads() -> None:
    runs = simulate_batch(
        [Scenario(model="b", load=load, track="erri-high", speed=SpeedProfile.constant(120.0), duration_s=600.0, faults=BROKEN_LL)
         for load in ("full", "tare")]
    )  # fmt: skip
    for result in runs:
        a = result.accel_mps2
        assert np.isfinite(a).all()
        assert np.all((a.std(axis=0) > 1.0) & (a.std(axis=0) < 20.0))
        assert np.max(np.abs(a - 9.81)) < 150.0  # inside the converter's +/-16 g
        first, last = a[:30000].std(axis=0), a[-30000:].std(axis=0)
        assert np.all(last < 1.3 * first) and np.all(first < 1.3 * last)
        assert isinstance(result.model, WagonModel)
        rest = static_equilibrium(result.model)
        assert np.max(np.abs(result.final_state.q - rest.q)[[0, 3, 6]]) < 0.02  # m


def test_a_seed_gives_the_same_samples_and_a_mixed_batch_what_each_gives_alone() -> None:
    scenarios = [
        Scenario(model="b", duration_s=4.0, seed=5, faults=BROKEN_LL),
        Scenario(duration_s=3.0, seed=5),
        Scenario(model="b", duration_s=3.0, seed=6, load="tare", track="fra-4", speed=SpeedProfile.parse("0:50,3:70")),
    ]
    batch = simulate_batch(scenarios)
    for scenario, result in zip(scenarios, batch, strict=True):
        assert result.scenario == scenario
        np.testing.assert_array_equal(result.accel_mps2, simulate(scenario).accel_mps2)
    assert batch[1].derived.get("model") is None and batch[0].derived["model"] == "b"
    assert not np.array_equal(batch[0].accel_mps2, simulate(Scenario(model="b", duration_s=4.0, seed=6, faults=BROKEN_LL)).accel_mps2)


def test_a_fault_onset_on_model_b_changes_the_run_only_from_then() -> None:
    base: dict[str, Any] = dict(model="b", duration_s=6.0, seed=2, fs_hz=200.0)
    healthy = simulate(Scenario(**base)).accel_mps2
    late = simulate(Scenario(**base, faults=BROKEN_LL, fault_onset_s=3.0)).accel_mps2
    np.testing.assert_array_equal(late[:600], healthy[:600])
    assert np.max(np.abs(late[600:] - healthy[600:])) > 0.1


def test_a_sidecar_of_model_b_reproduces_the_recording(tmp_path: Path) -> None:
    scenario = Scenario(model="b", load="tare", duration_s=3.0, seed=9, track="fra-5", faults=BROKEN_LL)
    result = simulate(scenario)
    sidecar = write_recording(result, tmp_path / "b.csv")
    document = json.loads(sidecar.read_text())
    assert document["scenario"]["model"] == "b" and document["derived"]["track_class"] == "B4"
    assert read_sidecar(sidecar) == scenario
    np.testing.assert_array_equal(rerun_sidecar(sidecar).accel_mps2, result.accel_mps2)


def test_a_sidecar_without_a_model_is_model_a() -> None:
    data = Scenario(duration_s=2.0).to_dict()
    assert data.pop("model") == "a"
    assert Scenario.from_dict(data) == Scenario(duration_s=2.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"model": "c"}, "unknown model 'c': use 'a' or 'b'"),
        ({"model": "b", "parameters": model_a_parameter_set()}, "model b cannot run model A's parameter set"),
        ({"model": "a", "parameters": default_parameter_set()}, "model a cannot run model B's parameter set"),
    ],
)
def test_a_bad_model_is_one_clear_error(kwargs, message: str) -> None:
    with pytest.raises(SimulationError, match=message):
        Scenario(**kwargs)


def test_a_step_too_long_for_model_b_is_a_clear_error() -> None:
    with pytest.raises(SimulationError, match="sensor resonance at 1600 Hz needs an integration step below"):
        simulate(Scenario(model="b", duration_s=1.0, max_step_s=1e-3))


def test_simulate_command_runs_model_b(tmp_path: Path, capsys) -> None:
    assert main(["simulate", "-o", str(tmp_path / "b.csv"), "--model", "b", "--duration-s", "2", "--track", "fra-6"]) == 0
    assert capsys.readouterr().out.rstrip().endswith(f"healthy, model b; scenario in {tmp_path / 'b.json'}")
    assert read_sidecar(tmp_path / "b.json").model == "b"


# --- track and sensors --------------------------------------------------------------------------------------


def _without_events(parameters: dict) -> dict:
    out = copy.deepcopy(parameters)
    for c in out["vehicle"]["irregularity"]["classes"].values():
        c["events"] = "none"
    return out


@pytest.mark.parametrize("name", ["erri-low", "fra-4"])
def test_each_rail_has_the_target_psd_and_the_rails_the_target_coherence(name: str) -> None:
    params = _without_events(PARAMS)
    track = generate_track(params, name, 20000.0, np.random.default_rng(11))
    model = track_model(params, name)
    fs = 1.0 / track.ds_m
    n, psd = signal.welch(track.left_m, fs=fs, nperseg=4096)
    _, coh = signal.coherence(track.left_m, track.right_m, fs=fs, nperseg=4096)
    for wavelength in (64, 32, 16, 8, 4, 2, 1, 0.5):
        band = (n > 0.8 / wavelength) & (n < 1.25 / wavelength)
        assert np.mean(psd[band]) == pytest.approx(np.mean(model.rail_psd(n[band])), rel=0.15), wavelength
    for wavelength in (50, 5, 1.5):
        band = (n > 0.8 / wavelength) & (n < 1.25 / wavelength)
        assert np.mean(coh[band]) == pytest.approx(np.mean(model.coherence(n[band]) ** 2), abs=0.08), wavelength


def test_jointed_track_has_staggered_joints_every_rail_length_and_welded_track_random_welds() -> None:
    rng = np.random.default_rng(2)
    jointed = track_model(PARAMS, "fra-4").track_class
    assert jointed is not None
    left, right = event_positions_m(jointed, 1000.0, rng)
    assert np.allclose(np.diff(left), 25.0, atol=1.1) and np.allclose(np.diff(right), 25.0, atol=1.1)
    assert np.min(np.abs(right[:, None] - left[None, :])) > 10.0  # staggered by about half a rail
    welded = track_model(PARAMS, "erri-low").track_class
    assert welded is not None
    gaps = np.diff(event_positions_m(welded, 200000.0, rng)[0])
    assert gaps.mean() == pytest.approx(60.0, rel=0.05) and gaps.min() >= 15.0 and gaps.std() > 20.0


def test_the_converter_quantises_to_its_step_and_clips_at_its_range() -> None:
    p = wagon_parameters(with_ideal_sensor(PARAMS), "full").sensor
    twelve_bits = type(p)(**{**p.__dict__, "bits": 12, "range_g": 8.0})
    x = np.linspace(-100.0, 100.0, 3001)[:, None] * np.ones(3)
    y = sensors.convert(x, twelve_bits, 500.0, np.random.default_rng(0))
    lsb = 16 * 9.80665 / 4096
    np.testing.assert_allclose(y / lsb, np.round(y / lsb), atol=1e-9)
    assert y.max() == pytest.approx(8 * 9.80665 - lsb) and y.min() == pytest.approx(-8 * 9.80665)
    assert np.max(np.abs(y - x)[np.abs(x[:, 0]) < 70]) <= lsb / 2 + 1e-12


def test_the_sensor_noise_has_its_density_in_the_passband() -> None:
    p = wagon_parameters(with_ideal_sensor(PARAMS), "full").sensor
    noisy = type(p)(**{**p.__dict__, "noise_density_mps2_per_sqrt_hz": 1e-3})
    y = sensors.convert(np.zeros((200000, 3)), noisy, 500.0, np.random.default_rng(1))
    f, psd = signal.welch(y[:, 0], fs=500.0, nperseg=4096)
    assert np.mean(psd[(f > 5) & (f < 50)]) == pytest.approx(1e-6, rel=0.1)  # (m/s^2)^2 / Hz, one-sided
    assert np.mean(psd[f > 200]) < 0.05 * 1e-6  # the anti-alias response at 0.25 fs shapes it


def test_the_kernels_six_channels_are_both_frames_through_their_own_sensor_chains() -> None:
    """Channels 4-6: the trailing frame at the same named corners, through bogie 2's own parts
    (cross-axis, skew) and its own lateral acceleration, the same chain of filters."""
    rng = np.random.default_rng(11)
    model = build_model(PARAMS, "full", (parse_fault("type_a:rear_outer:0.0@2:leading-left"),))
    state = _random_state(model, rng)
    track = generate_track(PARAMS, "erri-high", 200.0, rng)
    n, speed = 800, 25.0
    lateral, lateral_2 = 0.5 * rng.standard_normal(n + 2), 0.5 * rng.standard_normal(n + 2)
    p = model.params
    part_2 = sensors.other_part(p.sensor, np.random.default_rng(5))
    geometry = BogieGeometry(corners=(Corner.TRAILING_RIGHT, Corner.LEADING_LEFT, Corner.LEADING_RIGHT))
    out, _ = _kernel_run(model, state, track, speed, n, p.sensor, geometry, lateral, 4, part_2, lateral_2)
    alone, _ = _kernel_run(model, state, track, speed, n, p.sensor, geometry, lateral, 4)
    np.testing.assert_array_equal(out[:, :3], alone)  # bogie 1's channels as a one-bogie run's

    xy = geometry.positions_m()
    vertical = np.empty((n, 3))
    ref, front = state, p.axle_offsets_m[-1] + 5.0123
    for step in range(n):
        rail_z, rail_v = _rails_at(track, front, p.axle_offsets_m, speed)
        ref, accel = step_reference(model, ref, rail_z, rail_v, DT_S)
        vertical[step] = accel[6] + xy[:, 0] * accel[7] + xy[:, 1] * accel[8] + p.gravity_mps2
        front += DT_S * speed
    chain = sensors.SensorChain(part_2, 1.0 / DT_S, 1.0 / (4 * DT_S), 4, p.gravity_mps2)
    np.testing.assert_allclose(out[:, 3:], chain.process(vertical, lateral_2[:n]), rtol=1e-9, atol=1e-7)
