"""Model B's dry friction: a load-proportional Lenoir damper and the centre bowl, as LuGre/Dahl bristles.

Both friction elements of model B are the same law, a LuGre bristle model without bristle damping,
written for a friction limit that follows its normal force N(t):

    F = F_lim(t) * w,   F_lim = mu_s * ratio * N(t),
    dw/dt = v / delta - |v| w / (delta * g(v)),   g(v) = rho + (1 - rho) / (1 + (v / v_s)^2)

with w the dimensionless bristle deflection (|w| <= 1), v the relative sliding velocity, delta the
pre-sliding displacement, rho = mu_k / mu_s the Stribeck drop and v_s its velocity (a rational
Stribeck curve: one division where the Gaussian form costs an exponential, twelve times a step).
For the Lenoir damper N is the rear nest's force (the link hangs on it) and ratio the link ratio;
for the centre bowl N is the bowl's load, ratio its friction radius, v the frame's rocking rate
relative to the carbody in pitch and roll together (a 2-vector: the seat's friction is isotropic).

Why this law (model A uses an elasto-plastic Jenkins element with a constant Fs):
  - the Lenoir link makes the real damper's normal force, hence its sliding force, proportional to
    the instantaneous spring load: the damper grips harder on compression than on rebound, and a
    corner whose nest is unloaded dynamically loses its friction;
  - stiffness proportional to the normal load (a constant pre-sliding length, Dahl's observation
    for metallic contacts) instead of a constant stick stiffness;
  - a smooth pre-sliding branch and a Stribeck drop instead of the ideal parallelogram; under an
    oscillating load below breakaway the bristle creeps (a LuGre property, real dampers drift too).
Integration: over one step the velocity and N are frozen and the bristle equation is linear in w,
so it is integrated exactly, w_{n+1} = w_ss + (w_n - w_ss) exp(-|v| dt / (delta g)), with
w_ss = g v / |v| (the exponential by its Taylor series below 1e-3, exact to rounding and cheaper:
the argument is that small at almost every step). The update is unconditionally stable, does not
chatter at velocity reversals (the exponential never overshoots w_ss, and v = 0 leaves w unchanged:
true sticking, no drift under a constant load), and keeps |w| <= 1, so |F| <= F_lim at every step,
whatever N does.
Bristle damping (LuGre's sigma_1) is left out: with a varying normal force it is not dissipative;
the nest's viscous term in parallel damps the stuck oscillations instead.
"""

from __future__ import annotations

import math

# Below this argument exp(-a) is its Taylor series to a^4 (the error a^5 / 120 < 1e-17).
TAYLOR_BELOW = 1e-3


def stribeck(speed: float, rho: float, v_s: float) -> float:
    """g(|v|): 1 at rest, rho = mu_k / mu_s in gross sliding."""
    x = speed / v_s
    return rho + (1.0 - rho) / (1.0 + x * x)


def decay(a: float) -> float:
    """exp(-a) for a >= 0, by its Taylor series where that is exact to rounding (the kernel's arithmetic)."""
    if a < TAYLOR_BELOW:
        return 1.0 - a * (1.0 - a * (0.5 - a * (1.0 / 6.0 - a * (1.0 / 24.0))))
    return math.exp(-a)


def bristle_update(w: float, v: float, dt_s: float, delta: float, rho: float, v_s: float) -> float:
    """One exact step of the bristle deflection w (dimensionless) under the relative velocity v."""
    if v == 0.0:
        return w
    speed = abs(v)
    g = stribeck(speed, rho, v_s)
    w_ss = g if v > 0.0 else -g
    return w_ss + (w - w_ss) * decay(speed * (dt_s / delta) / g)


def bristle_update_2d(
    wx: float, wy: float, vx: float, vy: float, dt_s: float, delta: float, rho: float, v_s: float
) -> tuple[float, float]:
    """The isotropic 2-D bristle: the same law along the direction of the relative velocity vector."""
    speed = math.sqrt(vx * vx + vy * vy)
    if speed == 0.0:
        return wx, wy
    g = stribeck(speed, rho, v_s)
    factor = decay(speed * (dt_s / delta) / g)
    scale = g / speed
    sx, sy = vx * scale, vy * scale
    return sx + (wx - sx) * factor, sy + (wy - sy) * factor


def lenoir_limit_n(rear_nest_n: float, mu_static: float, link_ratio: float) -> float:
    """The Lenoir damper's breakaway force: mu_s x link ratio x the rear nest's force (never < 0)."""
    return mu_static * link_ratio * max(rear_nest_n, 0.0)


def nest_forces_n(
    compression_m: float, front_outer: float, front_inner: float, rear_outer: float, rear_inner: float, clearance_m: float
) -> tuple[float, float]:
    """(front nest, rear nest) forces of one axle box: outer coils from free length, inner from the clearance."""
    outer = max(compression_m, 0.0)
    inner = max(compression_m - clearance_m, 0.0)
    return front_outer * outer + front_inner * inner, rear_outer * outer + rear_inner * inner
