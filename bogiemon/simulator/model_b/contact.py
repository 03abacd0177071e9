"""Model B's wheel-rail contact and track: flexible wheelsets on a moving-mass track.

Each of the 8 wheels carries a linearised Hertzian contact spring (tangent stiffness at the load's
static wheel load, parameters.hertz_stiffness_n_per_m) with a little damping between the wheel's
contact point and the rail head, and under the rail head a moving track mass (rail and sleeper share)
on the pad-and-ballast spring and damper to the ground:

    delta = z_track + r(x) - z_contact             compression of the contact (m), r the irregularity
    F_contact = max(k_H delta + c_H d(delta)/dt, 0) if delta > 0, else 0   (unilateral: a wheel can lift)
    m_t z_track'' = -k_t z_track - c_t z_track' - F_contact

Model A prescribes the axle boxes' heights from the rails (rigid wheelsets, no track): here the
unsprung mass and the contact and track flexibility filter the rail input, with the P2 resonance
(wheelset and track mass on the track spring) near 50 Hz and the P1 (track mass against the wheel
on the Hertz spring) near 500 Hz, and the short waves and dips the rails carry reach the frame
through them. The track mass has no gravity term: its rest position (z = 0) already carries its
own weight on the ballast.
"""

from __future__ import annotations


def contact_force_n(compression_m: float, rate_mps: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> float:
    """Unilateral linearised Hertz: pushes only, and only while the wheel touches the rail."""
    if compression_m <= 0.0:
        return 0.0
    return max(stiffness_n_per_m * compression_m + damping_n_s_per_m * rate_mps, 0.0)


def unilateral_spring_n(closure_m: float, rate_mps: float, stiffness_n_per_m: float, damping_n_s_per_m: float) -> float:
    """A spring-damper that only pushes once its gap has closed (bowl, side bearers)."""
    return contact_force_n(closure_m, rate_mps, stiffness_n_per_m, damping_n_s_per_m)
