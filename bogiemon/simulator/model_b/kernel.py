"""Model B's compiled kernel: many scenarios advanced together, one thread per scenario (numba prange).

The arithmetic of bodies.step_reference (elements, bristles, semi-implicit Euler) followed by the
sensor chain of sensors.SensorChain (cross-axis, skew, resonance, anti-alias, decimation), unrolled;
tests run them side by side. Only the decimated samples are stored, and the positions at those
samples when `q_out` has room for them (tests and free-decay checks). Compiled on the first call
and cached like model A's kernel (simulator/kernel.py's _jit: beside the module, under
NUMBA_CACHE_DIR, or not at all on a read-only install).
"""

from __future__ import annotations

import math

import numpy as np

from bogiemon.simulator.kernel import _jit, _speed_mps, numba
from bogiemon.simulator.model_b.bodies import (
    C_CLEARANCE, C_DAMPING, C_FRONT_INNER, C_FRONT_OUTER, C_MU_RATIO, C_PRESLIDING, C_REAR_INNER, C_REAR_OUTER,
    C_RHO, C_V_STRIBECK, N_DOF,
)  # fmt: skip
from bogiemon.simulator.model_b.friction import TAYLOR_BELOW
from bogiemon.simulator.model_b.parameters import WagonParameters
from bogiemon.simulator.model_b.sensors import DELAY_LINE

# Layout of the per-scenario parameter vector `veh`.
(
    V_M_C, V_I_CY, V_I_CX, V_M_F, V_I_FY, V_I_FX, V_M_W, V_I_WX, V_M_T,
    V_HALF_A, V_HALF_L, V_HALF_BP, V_HALF_BC,
    V_K_H, V_C_H, V_K_T, V_C_T,
    V_K_BOWL, V_C_BOWL, V_MU_R_BOWL, V_DELTA_BOWL, V_RHO_BOWL, V_VS_BOWL,
    V_HALF_SB, V_GAP_SB, V_K_SB, V_C_SB,
    V_GRAVITY, V_DS, V_DT, V_CG_OFFSET,
    N_VEH,
) = range(32)  # fmt: skip
_MASK = DELAY_LINE - 1


def pack_vehicle(p: WagonParameters, ds_m: float, dt_s: float) -> np.ndarray:
    """The `veh` vector of one scenario."""
    veh = np.empty(N_VEH)
    veh[V_M_C], veh[V_I_CY], veh[V_I_CX] = p.carbody_mass_kg, p.carbody_pitch_inertia_kg_m2, p.carbody_roll_inertia_kg_m2
    veh[V_M_F], veh[V_I_FY], veh[V_I_FX] = p.frame_mass_kg, p.frame_pitch_inertia_kg_m2, p.frame_roll_inertia_kg_m2
    veh[V_M_W], veh[V_I_WX], veh[V_M_T] = p.wheelset_mass_kg, p.wheelset_roll_inertia_kg_m2, p.track_mass_kg
    veh[V_HALF_A], veh[V_HALF_L] = p.half_bogie_distance_m, p.half_wheelbase_m
    veh[V_HALF_BP], veh[V_HALF_BC] = p.half_box_spacing_m, p.half_contact_spacing_m
    veh[V_K_H], veh[V_C_H] = p.contact_stiffness_n_per_m, p.contact_damping_n_s_per_m
    veh[V_K_T], veh[V_C_T] = p.track_stiffness_n_per_m, p.track_damping_n_s_per_m
    veh[V_K_BOWL], veh[V_C_BOWL] = p.bowl_stiffness_n_per_m, p.bowl_damping_n_s_per_m
    veh[V_MU_R_BOWL] = p.bowl_friction_coefficient * p.bowl_friction_radius_m
    veh[V_DELTA_BOWL], veh[V_RHO_BOWL], veh[V_VS_BOWL] = p.bowl_presliding_rad, p.bowl_kinetic_to_static, p.bowl_stribeck_radps
    veh[V_HALF_SB], veh[V_GAP_SB] = p.half_bearer_spacing_m, p.bearer_clearance_m
    veh[V_K_SB], veh[V_C_SB] = p.bearer_stiffness_n_per_m, p.bearer_damping_n_s_per_m
    veh[V_GRAVITY], veh[V_DS], veh[V_DT] = p.gravity_mps2, ds_m, dt_s
    veh[V_CG_OFFSET] = p.carbody_centre_offset_m
    return veh


@_jit(error_model="numpy")
def _stribeck(speed: float, rho: float, v_s: float) -> float:
    x = speed / v_s
    return rho + (1.0 - rho) / (1.0 + x * x)


@_jit(error_model="numpy")
def _decay(a: float) -> float:
    if a < TAYLOR_BELOW:
        return 1.0 - a * (1.0 - a * (0.5 - a * (1.0 / 6.0 - a * (1.0 / 24.0))))
    return math.exp(-a)


# error_model="numpy": no zero-division checks on every float division of the step.
@_jit(parallel=True, error_model="numpy")
def advance(
    q: np.ndarray,  # (B, 25) positions, updated in place
    v: np.ndarray,  # (B, 25) velocities
    w: np.ndarray,  # (B, 12) friction bristles
    front_m: np.ndarray,  # (B,) first axle's position along the track
    time_s: np.ndarray,  # (B,) simulated time
    n_steps: np.ndarray,  # (B,) steps to take (a multiple of factor, <= factor x out.shape[1])
    veh: np.ndarray,  # (B, N_VEH)
    corner: np.ndarray,  # (B, 8, N_CORNER)
    speed_t: np.ndarray,  # (B, K) speed profile times (s)
    speed_v: np.ndarray,  # (B, K) speeds (m/s)
    n_speed: np.ndarray,  # (B,) points used in each profile
    rail_left: np.ndarray,  # (B, N) rail irregularity every ds (m)
    rail_right: np.ndarray,  # (B, N)
    lateral: np.ndarray,  # (B, C / 3, L) each recorded frame's lateral acceleration at the output rate (m/s^2)
    lateral_t0: np.ndarray,  # (B,) time of its first sample (s)
    lateral_fs: float,  # its sample rate (Hz)
    sensor_xy: np.ndarray,  # (B, 3, 2) sensor positions on each frame (m), the same named corners on both
    cross: np.ndarray,  # (B, C) cross-axis sensitivity per channel
    skew: np.ndarray,  # (B, C) each channel's delay in integration steps (< DELAY_LINE - 1)
    sos: np.ndarray,  # (B, n_sections, 6) resonance and anti-alias sections at the step rate
    zi: np.ndarray,  # (B, n_sections, 2, C) their state (transposed direct form II)
    line: np.ndarray,  # (B, C, DELAY_LINE) the channels' delay lines
    line_pos: np.ndarray,  # (B,) next write position in them
    factor: int,  # keep every factor-th filtered sample
    out: np.ndarray,  # (B, S, C) the sensors' output at the kept samples (m/s^2): C = 3, the leading
    # frame's (a1..a3), or 6, then the trailing frame's (b1..b3)
    q_out: np.ndarray,  # (B, S or 0, 25) positions at the kept samples (when its second axis is not empty)
) -> None:
    n_batch = q.shape[0]
    n_sections = sos.shape[1]
    n_channels = out.shape[2]
    record_q = q_out.shape[1] > 0
    for b in numba.prange(n_batch):
        p = veh[b]
        m_c, i_cy, i_cx = p[V_M_C], p[V_I_CY], p[V_I_CX]
        m_f, i_fy, i_fx = p[V_M_F], p[V_I_FY], p[V_I_FX]
        m_w, i_wx, m_t = p[V_M_W], p[V_I_WX], p[V_M_T]
        a, half_l, half_bp, half_bc = p[V_HALF_A], p[V_HALF_L], p[V_HALF_BP], p[V_HALF_BC]
        k_h, c_h, k_t, c_t = p[V_K_H], p[V_C_H], p[V_K_T], p[V_C_T]
        k_b, c_b, mu_rb, d_b, rho_b, vs_b = p[V_K_BOWL], p[V_C_BOWL], p[V_MU_R_BOWL], p[V_DELTA_BOWL], p[V_RHO_BOWL], p[V_VS_BOWL]
        y_sb, gap, k_sb, c_sb = p[V_HALF_SB], p[V_GAP_SB], p[V_K_SB], p[V_C_SB]
        g, dt = p[V_GRAVITY], p[V_DT]
        inv_ds = 1.0 / p[V_DS]
        n_rail = rail_left.shape[1]
        n_lat = lateral.shape[2]
        # The bogie centres from the carbody's centre of mass (off centre when its ends are loaded unequally).
        x_lead, x_trail = a - p[V_CG_OFFSET], -a - p[V_CG_OFFSET]
        offsets = np.array([0.0, 2.0 * half_l, 2.0 * a, 2.0 * a + 2.0 * half_l])
        mass = np.empty(N_DOF)
        mass[0], mass[1], mass[2] = m_c, i_cy, i_cx
        for base in (3, 6):
            mass[base], mass[base + 1], mass[base + 2] = m_f, i_fy, i_fx
        for j in range(4):
            mass[9 + 2 * j], mass[10 + 2 * j] = m_w, i_wx
        for m in range(8):
            mass[17 + m] = m_t
        inv_mass = 1.0 / mass
        rz = np.empty(8)
        rv = np.empty(8)
        gen = np.empty(N_DOF)
        acc = np.empty(N_DOF)
        # Thread-local copies (no false sharing, no reference counting on shared arrays in the loop).
        qb = q[b].copy()
        vb = v[b].copy()
        wb = w[b].copy()
        cb = corner[b].copy()
        dt_per_delta = np.empty(8)  # dt over each corner's pre-sliding displacement
        for k in range(8):
            dt_per_delta[k] = dt / cb[k, C_PRESLIDING]
        dt_per_delta_bowl = dt / d_b
        xy = sensor_xy[b].copy()
        cr = cross[b].copy()
        sk = skew[b].copy()
        sb = sos[b].copy()
        zb = zi[b].copy()
        lb = line[b].copy()
        pos = line_pos[b]
        st = speed_t[b].copy()
        sv = speed_v[b].copy()
        ns = n_speed[b]
        t0 = time_s[b]
        lat_t0 = lateral_t0[b]
        front = front_m[b]
        for step in range(n_steps[b]):
            t = t0 + step * dt
            speed = _speed_mps(t, st, sv, ns)
            for axle in range(4):
                x = (front - offsets[axle]) * inv_ds
                i = int(x)
                if i > n_rail - 2:  # never reached: run.py sizes the track with a margin
                    i = n_rail - 2
                frac = x - i
                l0 = rail_left[b, i]
                dl = rail_left[b, i + 1] - l0
                r0 = rail_right[b, i]
                dr = rail_right[b, i + 1] - r0
                rz[2 * axle] = l0 + frac * dl
                rz[2 * axle + 1] = r0 + frac * dr
                rv[2 * axle] = speed * dl * inv_ds
                rv[2 * axle + 1] = speed * dr * inv_ds
            for j in range(N_DOF):
                gen[j] = 0.0
            gen[0] = -m_c * g
            gen[3] = -m_f * g
            gen[6] = -m_f * g
            for j in range(4):
                gen[9 + 2 * j] = -m_w * g
            # Wheel-rail contacts and the track under each wheel.
            for axle in range(4):
                iz = 9 + 2 * axle
                zw, pw, wzw, wpw = qb[iz], qb[iz + 1], vb[iz], vb[iz + 1]
                for side in range(2):
                    y = half_bc if side == 0 else -half_bc
                    m = 2 * axle + side
                    zt, wt = qb[17 + m], vb[17 + m]
                    d = zt + rz[m] - (zw + y * pw)
                    dd = wt + rv[m] - (wzw + y * wpw)
                    f = 0.0
                    if d > 0.0:
                        f = k_h * d + c_h * dd
                        if f < 0.0:
                            f = 0.0
                    gen[17 + m] += -k_t * zt - c_t * wt - f
                    gen[iz] += f
                    gen[iz + 1] += y * f
            for bogie in range(2):
                base = 3 + 3 * bogie
                x_c = x_lead if bogie == 0 else x_trail
                zf, tf, pf = qb[base], qb[base + 1], qb[base + 2]
                wz, wtf, wpf = vb[base], vb[base + 1], vb[base + 2]
                # Primary corners: two nests, the Lenoir friction on the rear nest's load, viscous.
                for c in range(4):
                    k = 4 * bogie + c
                    x = half_l if c < 2 else -half_l
                    y = half_bp if c % 2 == 0 else -half_bp
                    iz = 9 + 2 * (2 * bogie + (0 if c < 2 else 1))
                    u = (qb[iz] + y * qb[iz + 1]) - (zf + x * tf + y * pf)
                    du = (vb[iz] + y * vb[iz + 1]) - (wz + x * wtf + y * wpf)
                    outer = max(u, 0.0)
                    inner = max(u - cb[k, C_CLEARANCE], 0.0)
                    front_n = cb[k, C_FRONT_OUTER] * outer + cb[k, C_FRONT_INNER] * inner
                    rear_n = cb[k, C_REAR_OUTER] * outer + cb[k, C_REAR_INNER] * inner
                    lim = cb[k, C_MU_RATIO] * 1.0 * max(rear_n, 0.0)
                    if du != 0.0:
                        sp = abs(du)
                        gs = _stribeck(sp, cb[k, C_RHO], cb[k, C_V_STRIBECK])
                        wss = gs if du > 0.0 else -gs
                        wb[k] = wss + (wb[k] - wss) * _decay(sp * dt_per_delta[k] / gs)
                    f = front_n + rear_n + lim * wb[k] + cb[k, C_DAMPING] * du
                    gen[iz] -= f
                    gen[iz + 1] -= y * f
                    gen[base] += f
                    gen[base + 1] += x * f
                    gen[base + 2] += y * f
                # Centre bowl under the carbody at x_c, and its friction moment against rocking.
                ub = zf - (qb[0] + x_c * qb[1])
                dub = wz - (vb[0] + x_c * vb[1])
                fb = 0.0
                if ub > 0.0:
                    fb = k_b * ub + c_b * dub
                    if fb < 0.0:
                        fb = 0.0
                gen[base] -= fb
                gen[0] += fb
                gen[1] += x_c * fb
                ip = 8 + 2 * bogie
                rp = wtf - vb[1]
                rr = wpf - vb[2]
                sp = math.sqrt(rp * rp + rr * rr)
                if sp != 0.0:
                    gs = _stribeck(sp, rho_b, vs_b)
                    decay = _decay(sp * dt_per_delta_bowl / gs)
                    inv_sp = gs / sp
                    sx = rp * inv_sp
                    sy = rr * inv_sp
                    wb[ip] = sx + (wb[ip] - sx) * decay
                    wb[ip + 1] = sy + (wb[ip + 1] - sy) * decay
                m_lim = mu_rb * fb
                mp = m_lim * wb[ip]
                mr = m_lim * wb[ip + 1]
                gen[base + 1] -= mp
                gen[1] += mp
                gen[base + 2] -= mr
                gen[2] += mr
                # Side bearers with clearance.
                for side in range(2):
                    y = y_sb if side == 0 else -y_sb
                    e = (zf + y * pf) - (qb[0] + x_c * qb[1] + y * qb[2]) - gap
                    de = (wz + y * wpf) - (vb[0] + x_c * vb[1] + y * vb[2])
                    f = 0.0
                    if e > 0.0:
                        f = k_sb * e + c_sb * de
                        if f < 0.0:
                            f = 0.0
                    gen[base] -= f
                    gen[base + 2] -= y * f
                    gen[0] += f
                    gen[1] += x_c * f
                    gen[2] += y * f
            for j in range(N_DOF):
                acc[j] = gen[j] * inv_mass[j]
            # Sensors on the leading frame, then (six channels) on the trailing one.
            keep = step % factor == 0
            xl = (t - lat_t0) * lateral_fs
            il = int(math.floor(xl))
            if il < 0:
                il = 0
            if il > n_lat - 2:
                il = n_lat - 2
            fl = xl - il
            for s in range(n_channels):
                frame = s // 3
                base = 3 + 3 * frame
                ch = s % 3
                lat = lateral[b, frame, il] + fl * (lateral[b, frame, il + 1] - lateral[b, frame, il])
                lb[s, pos & _MASK] = acc[base] + xy[ch, 0] * acc[base + 1] + xy[ch, 1] * acc[base + 2] + g + cr[s] * lat
                i0 = int(sk[s])
                fs_ = sk[s] - i0
                y = (1.0 - fs_) * lb[s, (pos - i0) & _MASK] + fs_ * lb[s, (pos - i0 - 1) & _MASK]
                for sec in range(n_sections):
                    xin = y
                    y = sb[sec, 0] * xin + zb[sec, 0, s]
                    zb[sec, 0, s] = sb[sec, 1] * xin - sb[sec, 4] * y + zb[sec, 1, s]
                    zb[sec, 1, s] = sb[sec, 2] * xin - sb[sec, 5] * y
                if keep:
                    out[b, step // factor, s] = y
            pos += 1
            if keep and record_q:
                for j in range(N_DOF):
                    q_out[b, step // factor, j] = qb[j]
            for j in range(N_DOF):
                vb[j] += dt * acc[j]
                qb[j] += dt * vb[j]
            front += dt * _speed_mps(t + 0.5 * dt, st, sv, ns)
        time_s[b] = t0 + n_steps[b] * dt
        front_m[b] = front
        q[b] = qb
        v[b] = vb
        w[b] = wb
        zi[b] = zb
        line[b] = lb
        line_pos[b] = pos
