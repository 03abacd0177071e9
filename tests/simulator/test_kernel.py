"""The compiled kernel against the plain numpy reference of the equations of motion, step by step."""

import numpy as np
import pytest
from scipy import signal

from bogiemon.detection import BogieGeometry, Corner
from bogiemon.simulator import kernel
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.scenario import SpeedProfile
from bogiemon.simulator.sensors import Decimator, anti_alias_sos
from bogiemon.simulator.suspension import parse_fault
from bogiemon.simulator.track import generate_track
from bogiemon.simulator.vehicle import State, box_motion_reference, build_model, static_equilibrium, step_reference

DT_S = 2.5e-4


def _setup(load: str, seed: int):
    faults = (parse_fault("type_a:rear_outer:0.0@leading-left"), parse_fault("type_b::1.5@trailing-bogie:trailing-right"))
    model = build_model(default_parameter_set(), load, faults)
    rng = np.random.default_rng(seed)
    track = generate_track("erri-high", 400.0, rng, ds_m=0.05)
    rest = static_equilibrium(model)
    # Off equilibrium and moving, sliders anywhere: every branch of the friction element is used.
    state = State(
        q=rest.q + 2e-4 * rng.standard_normal(9) * np.array([1, 0.1, 0.1] * 3),
        v=0.02 * rng.standard_normal(9),
        slider=rest.slider + 1e-3 * rng.standard_normal(8),
    )
    speed = SpeedProfile(((0.0, 60.0), (0.2, 90.0), (0.3, 70.0)))
    geometry = BogieGeometry(corners=(Corner.TRAILING_RIGHT, Corner.LEADING_LEFT, Corner.LEADING_RIGHT))
    return model, track, state, speed, geometry


@pytest.mark.parametrize(("load", "seed"), [("full", 0), ("tare", 1)])
def test_kernel_steps_exactly_like_the_reference(load: str, seed: int) -> None:
    model, track, state, speed, geometry = _setup(load, seed)
    n_steps, front0, t0 = 1600, 30.0123, -0.02  # off the 5 cm grid: at a node the slope is either side's
    sensors = geometry.positions_m()
    g = model.params.gravity_mps2

    # Reference: one plain numpy step at a time.
    ref_out = np.empty((n_steps, 3))
    ref_state, front = state, front0
    for n in range(n_steps):
        t = t0 + n * DT_S
        box_z, box_v = box_motion_reference(model.params, track, front, speed.speed_mps(t))
        ref_state, accel = step_reference(model, ref_state, box_z, box_v, DT_S)
        ref_out[n] = accel[3] + sensors[:, 0] * accel[4] + sensors[:, 1] * accel[5] + g
        front += DT_S * speed.speed_mps(t + 0.5 * DT_S)

    # Kernel, twice in a batch of two (the scenario axis), in two calls each: once unfiltered
    # (identity filter, every step kept), once through the anti-aliasing filter, decimated by 8.
    times, speeds = speed.arrays_mps()
    factor = 8
    aa_sos = anti_alias_sos(1 / DT_S, 1 / (DT_S * factor))
    for sos, keep in ((kernel.IDENTITY_SOS, 1), (aa_sos, factor)):
        q = np.array([state.q, state.q])
        v = np.array([state.v, state.v])
        slider = np.array([state.slider, state.slider])
        front_m = np.array([front0, front0])
        time_s = np.array([t0, t0])
        zi = np.zeros((2, sos.shape[0], 2, 3))
        out = np.empty((2, n_steps // keep, 3))
        half = n_steps // 2
        for start in (0, half):
            chunk = np.empty((2, half // keep, 3))
            kernel.advance(
                q, v, slider, front_m, time_s, np.array([half, half]),
                np.array([kernel.pack_vehicle(model.params, track.ds_m, DT_S)] * 2),
                np.array([model.corner_table()] * 2),
                np.array([times] * 2), np.array([speeds] * 2), np.array([times.size] * 2),
                np.array([track.left_m] * 2), np.array([track.right_m] * 2),
                np.array([sensors] * 2), sos, zi, keep, chunk,
            )  # fmt: skip
            out[:, start // keep : (start + half) // keep] = chunk
        expected = ref_out if keep == 1 else signal.sosfilt(sos, ref_out, axis=0)[::keep]
        for b in range(2):
            np.testing.assert_allclose(out[b], expected, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(q[b], ref_state.q, rtol=1e-9, atol=1e-13)
            np.testing.assert_allclose(v[b], ref_state.v, rtol=1e-9, atol=1e-11)
            np.testing.assert_allclose(slider[b], ref_state.slider, rtol=1e-9, atol=1e-13)
            assert front_m[b] == pytest.approx(front, rel=1e-12)
            assert time_s[b] == pytest.approx(t0 + n_steps * DT_S, rel=1e-12)
    # The run moved the friction sliders (slip happened) and the accelerations are not trivial.
    assert np.max(np.abs(ref_state.slider - state.slider)) > 1e-4
    assert np.std(ref_out) > 0.1


def test_the_kernels_filter_is_the_decimator() -> None:
    """sensors.Decimator (scipy's sosfilt, steady-state start) is what the kernel's filter reproduces."""
    fs_in, factor = 4000.0, 8
    x = 9.81 + np.random.default_rng(0).standard_normal((4000, 3))
    x[0] = 9.81
    sos = anti_alias_sos(fs_in, fs_in / factor)
    zi = signal.sosfilt_zi(sos)[:, :, None] * x[0][None, None, :]
    expected = signal.sosfilt(sos, x, axis=0, zi=zi)[0][::factor]
    np.testing.assert_allclose(Decimator(fs_in, factor, 3).process(x), expected, rtol=1e-12)


def test_the_cache_falls_back_to_no_cache_when_no_location_is_writable(monkeypatch) -> None:
    calls = []

    def njit(cache: bool, **options):
        calls.append(cache)
        if cache:
            raise RuntimeError("cannot cache function 'f': no locator available for file '/ro/kernel.py'")
        return lambda func: func

    monkeypatch.setattr(kernel.numba, "njit", njit)

    def func() -> int:
        return 1

    assert kernel._jit()(func)() == 1
    assert calls == [True, False]


@pytest.mark.parametrize("offset_m", [0.0, 1.4])
def test_six_channels_read_both_frames_like_the_reference_an_off_centre_carbody_too(offset_m: float) -> None:
    """Channels 4-6 are the trailing frame's at the same named corners; a carbody whose centre of
    mass lies off centre (ends loaded unequally) moves the bowls in the kernel as in the reference."""
    params = default_parameter_set()
    params = {**params, "vehicle": {**params["vehicle"], "carbody": {**params["vehicle"]["carbody"], "centre_of_mass_offset_m": offset_m}}}
    faults = (parse_fault("type_a:rear_outer:0.0@2:leading-left"),)
    model = build_model(params, "full", faults)
    assert model.params.carbody_centre_offset_m == offset_m
    rng = np.random.default_rng(3)
    track = generate_track("erri-high", 400.0, rng, ds_m=0.05)
    state = static_equilibrium(model)
    speed = SpeedProfile.constant(80.0)
    geometry = BogieGeometry(corners=(Corner.TRAILING_RIGHT, Corner.LEADING_LEFT, Corner.LEADING_RIGHT))
    sensors, g = geometry.positions_m(), model.params.gravity_mps2
    n_steps, front0 = 800, 30.0123
    ref_out = np.empty((n_steps, 6))
    ref_state, front = state, front0
    for n in range(n_steps):
        box_z, box_v = box_motion_reference(model.params, track, front, speed.speed_mps(n * DT_S))
        ref_state, accel = step_reference(model, ref_state, box_z, box_v, DT_S)
        for frame in range(2):
            base = 3 + 3 * frame
            ref_out[n, 3 * frame : 3 * frame + 3] = accel[base] + sensors[:, 0] * accel[base + 1] + sensors[:, 1] * accel[base + 2] + g
        front += DT_S * speed.speed_mps(0.0)
    times, speeds = speed.arrays_mps()
    out = np.empty((1, n_steps, 6))
    kernel.advance(
        state.q[None].copy(), state.v[None].copy(), state.slider[None].copy(), np.array([front0]), np.zeros(1), np.array([n_steps]),
        kernel.pack_vehicle(model.params, track.ds_m, DT_S)[None], model.corner_table()[None], times[None], speeds[None],
        np.array([times.size]), track.left_m[None], track.right_m[None], sensors[None], kernel.IDENTITY_SOS,
        np.zeros((1, 1, 2, 6)), 1, out,
    )  # fmt: skip
    np.testing.assert_allclose(out[0], ref_out, rtol=1e-9, atol=1e-9)
    # The trailing frame (broken spring) moves otherwise than the leading one.
    assert np.std(out[0, :, 3:] - out[0, :, :3]) > 0.1
