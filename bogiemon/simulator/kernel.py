"""The compiled time-stepping kernel: many scenarios advanced together, one thread per scenario.

Arithmetic identical to vehicle.step_reference and vehicle.box_motion_reference, followed by the
anti-aliasing filter and decimation of sensors.Decimator (tests run them side by side), unrolled
for speed; only the decimated samples are stored. The scenario axis is 0 in every array and is run with
numba.prange, so a batch uses every core; a single scenario is a batch of one.

Compilation: numba compiles on the first call (several seconds, see bench/bench_simulator.py)
and caches the machine code (cache=True) beside this file, or under NUMBA_CACHE_DIR if set, or
in the user's cache folder when the package folder is read-only. If none is writable the kernel
is compiled afresh in every process instead of failing.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from bogiemon.simulator.errors import SimulationError

try:
    import numba
except ImportError:  # the `sim` extra: a gateway install leaves the simulator out
    raise SimulationError("the simulator needs numba: install bogiemon with its 'sim' extra (pip install 'bogiemon[sim]')") from None

# Layout of the per-scenario parameter vector `veh`.
(
    V_MASS_C, V_PITCH_C, V_ROLL_C, V_MASS_F, V_PITCH_F, V_ROLL_F,
    V_HALF_CENTRES, V_HALF_WHEELBASE, V_HALF_BOXES, V_BOX_LEVER,
    V_K_BOWL, V_C_BOWL, V_HALF_SB, V_K_SB, V_C_SB, V_GRAVITY, V_DS, V_DT, V_CG_OFFSET,
    N_VEH,
) = range(20)  # fmt: skip
# Layout of a corner's row in `corner` (suspension.CornerSuspension.as_row).
C_K_OUTER, C_K_INNER, C_CLEARANCE, C_FS, C_K_STICK, C_DAMPING = range(6)


def _jit(**options: Any) -> Callable[[Callable[..., Any]], Any]:
    """numba.njit with an on-disk cache when some cache location is writable, without otherwise."""

    def wrap(func: Callable[..., Any]) -> Any:
        try:
            return numba.njit(cache=True, **options)(func)
        except RuntimeError:  # "cannot cache function ...: no locator available": read-only install
            return numba.njit(cache=False, **options)(func)

    return wrap


@_jit()
def _speed_mps(t_s: float, times_s: np.ndarray, speeds_mps: np.ndarray, n: int) -> float:
    """Piecewise-linear speed, held constant before the first and after the last point."""
    if t_s <= times_s[0]:
        return speeds_mps[0]
    if t_s >= times_s[n - 1]:
        return speeds_mps[n - 1]
    i = 0
    while times_s[i + 1] < t_s:
        i += 1
    frac = (t_s - times_s[i]) / (times_s[i + 1] - times_s[i])
    return speeds_mps[i] + frac * (speeds_mps[i + 1] - speeds_mps[i])


@_jit(parallel=True)
def advance(
    q: np.ndarray,  # (B, 9) positions, updated in place
    v: np.ndarray,  # (B, 9) velocities
    slider: np.ndarray,  # (B, 8) friction sliders
    front_m: np.ndarray,  # (B,) first axle's position along the track
    time_s: np.ndarray,  # (B,) simulated time
    n_steps: np.ndarray,  # (B,) steps to take (<= out.shape[1])
    veh: np.ndarray,  # (B, N_VEH)
    corner: np.ndarray,  # (B, 8, 6)
    speed_t: np.ndarray,  # (B, K) speed profile times (s)
    speed_v: np.ndarray,  # (B, K) speeds (m/s)
    n_speed: np.ndarray,  # (B,) points used in each profile
    rail_left: np.ndarray,  # (B, N) rail heights every ds (m)
    rail_right: np.ndarray,  # (B, N)
    sensor_xy: np.ndarray,  # (B, 3, 2) sensor positions on each frame (m), the same named corners on both
    sos: np.ndarray,  # (n_sections, 6) anti-aliasing low-pass at the step rate (sensors.anti_alias_sos)
    zi: np.ndarray,  # (B, n_sections, 2, C) its state (transposed direct form II, as scipy's sosfilt)
    factor: int,  # keep every factor-th filtered sample (n_steps must be a multiple of it)
    out: np.ndarray,  # (B, S, C) specific force at the sensors (m/s^2), one row per kept sample:
    # C = 3, the leading frame's (a1..a3), or 6, then the trailing frame's (b1..b3)
) -> None:
    n_batch = q.shape[0]
    n_sections = sos.shape[0]
    n_channels = out.shape[2]
    for b in numba.prange(n_batch):
        p = veh[b]
        m_c, i_cy, i_cx = p[V_MASS_C], p[V_PITCH_C], p[V_ROLL_C]
        m_f, i_fy, i_fx = p[V_MASS_F], p[V_PITCH_F], p[V_ROLL_F]
        a, half_l, half_b, lever = p[V_HALF_CENTRES], p[V_HALF_WHEELBASE], p[V_HALF_BOXES], p[V_BOX_LEVER]
        k_bowl, c_bowl, y_sb, k_sb, c_sb = p[V_K_BOWL], p[V_C_BOWL], p[V_HALF_SB], p[V_K_SB], p[V_C_SB]
        g, dt = p[V_GRAVITY], p[V_DT]
        # The bogie centres from the carbody's centre of mass (off centre when its ends are loaded unequally).
        x_lead, x_trail = a - p[V_CG_OFFSET], -a - p[V_CG_OFFSET]
        inv_ds = 1.0 / p[V_DS]
        n_rail = rail_left.shape[1]
        offsets = np.array([0.0, 2.0 * half_l, 2.0 * a, 2.0 * a + 2.0 * half_l])
        box_z = np.empty(8)
        box_v = np.empty(8)
        gen = np.empty(9)
        acc = np.empty(9)
        # Thread-local copies: scenarios next to each other share cache lines, and two threads
        # writing them in place would slow each other down (false sharing).
        qb = q[b].copy()
        vb = v[b].copy()
        sb = slider[b].copy()
        zb = zi[b].copy()
        cb = corner[b].copy()
        xy = sensor_xy[b].copy()
        # Views of shared arrays inside the loop would update the shared array's reference count
        # atomically from both threads at every step: copies, or plain 2-D indexing, instead.
        st = speed_t[b].copy()
        sv = speed_v[b].copy()
        ns = n_speed[b]
        t0 = time_s[b]
        front = front_m[b]
        for step in range(n_steps[b]):
            t = t0 + step * dt
            speed = _speed_mps(t, st, sv, ns)
            # Axle boxes: each axle reads the rails at its own position.
            for axle in range(4):
                x = (front - offsets[axle]) * inv_ds
                i = int(x)
                if i > n_rail - 2:  # never reached: scenario.py sizes the track with a margin
                    i = n_rail - 2
                frac = x - i
                l0 = rail_left[b, i]
                dl = rail_left[b, i + 1] - l0
                r0 = rail_right[b, i]
                dr = rail_right[b, i + 1] - r0
                zl = l0 + frac * dl
                zr = r0 + frac * dr
                vl = speed * dl * inv_ds
                vr = speed * dr * inv_ds
                k = 4 * (axle // 2) + 2 * (axle % 2)
                box_z[k] = 0.5 * (zl + zr) + lever * 0.5 * (zl - zr)
                box_z[k + 1] = 0.5 * (zl + zr) - lever * 0.5 * (zl - zr)
                box_v[k] = 0.5 * (vl + vr) + lever * 0.5 * (vl - vr)
                box_v[k + 1] = 0.5 * (vl + vr) - lever * 0.5 * (vl - vr)
            for j in range(9):
                gen[j] = 0.0
            gen[0] = -m_c * g
            for bogie in range(2):
                base = 3 + 3 * bogie
                x_c = x_lead if bogie == 0 else x_trail
                zf, tf, pf = qb[base], qb[base + 1], qb[base + 2]
                wz, wt, wp = vb[base], vb[base + 1], vb[base + 2]
                fz = -m_f * g
                ft = 0.0
                fp = 0.0
                for c in range(4):
                    k = 4 * bogie + c
                    x = half_l if c < 2 else -half_l
                    y = half_b if c % 2 == 0 else -half_b
                    u = box_z[k] - (zf + x * tf + y * pf)
                    du = box_v[k] - (wz + x * wt + y * wp)
                    f = cb[k, C_K_OUTER] * max(u, 0.0) + cb[k, C_K_INNER] * max(u - cb[k, C_CLEARANCE], 0.0)
                    fs = cb[k, C_FS]
                    k_stick = cb[k, C_K_STICK]
                    trial = k_stick * (u - sb[k])
                    if trial > fs:
                        sb[k] = u - fs / k_stick
                        trial = fs
                    elif trial < -fs:
                        sb[k] = u + fs / k_stick
                        trial = -fs
                    f += trial + cb[k, C_DAMPING] * du
                    fz += f
                    ft += x * f
                    fp += y * f
                # Centre bowl: frame centre against the carbody at x_c.
                u = zf - (qb[0] + x_c * qb[1])
                du = wz - (vb[0] + x_c * vb[1])
                f = k_bowl * u + c_bowl * du
                fz -= f
                gen[0] += f
                gen[1] += x_c * f
                # Side bearers at +/- y_sb.
                for side in range(2):
                    y = y_sb if side == 0 else -y_sb
                    u = zf + y * pf - (qb[0] + x_c * qb[1] + y * qb[2])
                    du = wz + y * wp - (vb[0] + x_c * vb[1] + y * vb[2])
                    f = k_sb * u + c_sb * du
                    fz -= f
                    fp -= y * f
                    gen[0] += f
                    gen[1] += x_c * f
                    gen[2] += y * f
                gen[base] += fz
                gen[base + 1] += ft
                gen[base + 2] += fp
            acc[0] = gen[0] / m_c
            acc[1] = gen[1] / i_cy
            acc[2] = gen[2] / i_cx
            for bogie in range(2):
                base = 3 + 3 * bogie
                acc[base] = gen[base] / m_f
                acc[base + 1] = gen[base + 1] / i_fy
                acc[base + 2] = gen[base + 2] / i_fx
            keep = step % factor == 0
            for s in range(n_channels):
                base = 3 + 3 * (s // 3)
                ch = s % 3
                y = acc[base] + xy[ch, 0] * acc[base + 1] + xy[ch, 1] * acc[base + 2] + g
                for sec in range(n_sections):
                    x = y
                    y = sos[sec, 0] * x + zb[sec, 0, s]
                    zb[sec, 0, s] = sos[sec, 1] * x - sos[sec, 4] * y + zb[sec, 1, s]
                    zb[sec, 1, s] = sos[sec, 2] * x - sos[sec, 5] * y
                if keep:
                    out[b, step // factor, s] = y
            for j in range(9):
                vb[j] += dt * acc[j]
                qb[j] += dt * vb[j]
            front += dt * _speed_mps(t + 0.5 * dt, st, sv, ns)
        time_s[b] = t0 + n_steps[b] * dt
        front_m[b] = front
        q[b] = qb
        v[b] = vb
        slider[b] = sb
        zi[b] = zb


def pack_vehicle(params: Any, ds_m: float, dt_s: float) -> np.ndarray:
    """The `veh` vector of one scenario from its VehicleParameters."""
    veh = np.empty(N_VEH)
    veh[V_MASS_C] = params.carbody_mass_kg
    veh[V_PITCH_C] = params.carbody_pitch_inertia_kg_m2
    veh[V_ROLL_C] = params.carbody_roll_inertia_kg_m2
    veh[V_MASS_F] = params.frame_mass_kg
    veh[V_PITCH_F] = params.frame_pitch_inertia_kg_m2
    veh[V_ROLL_F] = params.frame_roll_inertia_kg_m2
    veh[V_HALF_CENTRES] = params.bogie_centre_distance_m / 2
    veh[V_HALF_WHEELBASE] = params.wheelbase_m / 2
    veh[V_HALF_BOXES] = params.axle_box_spacing_m / 2
    veh[V_BOX_LEVER] = params.axle_box_spacing_m / params.contact_spacing_m
    veh[V_K_BOWL] = params.bowl_stiffness_n_per_m
    veh[V_C_BOWL] = params.bowl_damping_n_s_per_m
    veh[V_HALF_SB] = params.side_bearer_spacing_m / 2
    veh[V_K_SB] = params.side_bearer_stiffness_n_per_m
    veh[V_C_SB] = params.side_bearer_damping_n_s_per_m
    veh[V_GRAVITY] = params.gravity_mps2
    veh[V_DS] = ds_m
    veh[V_DT] = dt_s
    veh[V_CG_OFFSET] = params.carbody_centre_offset_m
    return veh


IDENTITY_SOS = np.array([[1.0, 0.0, 0.0, 1.0, 0.0, 0.0]])  # no filter: with factor 1, every step's value

