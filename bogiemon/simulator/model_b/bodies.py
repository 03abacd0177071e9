"""Model B's bodies and equations of motion: layout, faults, a plain numpy reference step, rest, modes.

Degrees of freedom (25; small motions from the free-length configuration, z up, SI units; a point
(x, y) of a body moves by z + x theta + y phi, detection/kinematics.py's signs):
   0..2   carbody bounce, pitch (leading end up), roll (left up)
   3..5   leading bogie frame (the monitored one) bounce, pitch, roll;  6..8 the trailing frame
   9..16  wheelsets 1..4 (leading bogie's leading axle first): bounce and roll each
  17..24  the track mass under each wheel: axle 1 left, axle 1 right, axle 2 left, ...
Friction states (12, dimensionless bristles, friction.py): the 8 Lenoir dampers (corner order of
simulator/suspension.py, leading bogie first), then each bogie's centre bowl in pitch and roll.

Elements, each a row G of the state (its deformation e = G q, compressive force f, generalised
force -G^T f): the primary corners between axle box (on the wheelset, at y = +/- half box spacing)
and frame corner (x = +/- half wheelbase): two two-stage nests, the Lenoir friction on the rear
nest's load, a small viscous term; the centre bowls, unilateral vertical springs under the carbody
at x = +/- half the bogie distance, with a friction moment against the frame's rocking; the side
bearers with a clearance, unilateral; the wheel-rail contacts and the track (contact.py); gravity
on carbody, frames and wheelsets. The mass matrix is diagonal (coordinates at the centres of mass).

Time step (the kernel does the same arithmetic): the friction bristles are advanced exactly over
the step with the step's relative velocities (friction.py), the forces use them, then
semi-implicit Euler, v += dt a, q += dt v.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import contact, friction
from bogiemon.simulator.model_b.parameters import WagonParameters, wagon_parameters
from bogiemon.simulator.suspension import BOGIES, CORNER_ORDER, HEALTHY_SEVERITY, Fault

FloatArray = NDArray[np.float64]

N_DOF = 25
N_FRICTION = 12
CARBODY = 0
FRAME = (3, 6)  # first DOF of each bogie's frame
WHEELSET = 9  # axle j: 9 + 2 j (bounce), 10 + 2 j (roll)
TRACK = 17  # wheel (axle j, side s = 0 left / 1 right): 17 + 2 j + s
BOWL_FRICTION = 8  # bogie i: 8 + 2 i (pitch), 9 + 2 i (roll)
N_WHEELS = 8

# A corner's row in the kernel's table.
(
    C_FRONT_OUTER, C_FRONT_INNER, C_REAR_OUTER, C_REAR_INNER, C_CLEARANCE,
    C_MU_RATIO, C_PRESLIDING, C_RHO, C_V_STRIBECK, C_DAMPING, N_CORNER,
) = range(11)  # fmt: skip


@dataclass(frozen=True)
class Corner:
    """One axle box's primary suspension in model B. N/m, m, N s/m; mu_ratio = mu_s x link ratio."""

    front_outer_n_per_m: float
    front_inner_n_per_m: float
    rear_outer_n_per_m: float
    rear_inner_n_per_m: float
    inner_clearance_m: float
    mu_ratio: float
    presliding_m: float
    kinetic_to_static: float
    stribeck_velocity_mps: float
    damping_n_s_per_m: float

    def nest_forces_n(self, compression_m: float) -> tuple[float, float]:
        return friction.nest_forces_n(
            compression_m, self.front_outer_n_per_m, self.front_inner_n_per_m,
            self.rear_outer_n_per_m, self.rear_inner_n_per_m, self.inner_clearance_m,
        )  # fmt: skip

    def tangent_stiffness_n_per_m(self, compression_m: float) -> float:
        """Kz: the nests' stiffness at a compression (the paper's corner stiffness at its load)."""
        k = self.front_outer_n_per_m + self.rear_outer_n_per_m if compression_m > 0.0 else 0.0
        if compression_m > self.inner_clearance_m:
            k += self.front_inner_n_per_m + self.rear_inner_n_per_m
        return k

    def breakaway_n(self, compression_m: float) -> float:
        """Fs at a compression: mu_s x link ratio x the rear nest's force."""
        return self.mu_ratio * max(self.nest_forces_n(compression_m)[1], 0.0)

    def as_row(self) -> list[float]:
        return [
            self.front_outer_n_per_m, self.front_inner_n_per_m, self.rear_outer_n_per_m, self.rear_inner_n_per_m,
            self.inner_clearance_m, self.mu_ratio, self.presliding_m, self.kinetic_to_static,
            self.stribeck_velocity_mps, self.damping_n_s_per_m,
        ]  # fmt: skip


def healthy_corner(p: WagonParameters) -> Corner:
    return Corner(
        front_outer_n_per_m=p.outer_coil_n_per_m,
        front_inner_n_per_m=p.inner_coil_n_per_m,
        rear_outer_n_per_m=p.outer_coil_n_per_m,
        rear_inner_n_per_m=p.inner_coil_n_per_m,
        inner_clearance_m=p.inner_clearance_m,
        mu_ratio=p.mu_static * p.link_ratio,
        presliding_m=p.presliding_m,
        kinetic_to_static=p.kinetic_to_static,
        stribeck_velocity_mps=p.stribeck_velocity_mps,
        damping_n_s_per_m=p.primary_damping_n_s_per_m,
    )


def nominal_corner(parameter_set: dict[str, Any], load: str) -> tuple[float, float]:
    """(Kz N/m, Fs N) of model B's healthy corner at a load: the base of a wagon's tolerances
    (custom faults), as the paper's healthy Kz and Fs are model A's."""
    return nominal_corner_values(wagon_parameters(parameter_set, load))


def nominal_corner_values(p: WagonParameters) -> tuple[float, float]:
    """(Kz N/m, Fs N) of model B's healthy corner at its load's static compression."""
    c = healthy_corner(p)
    u = _nest_compression(c, p.static_corner_load_n)
    return c.tangent_stiffness_n_per_m(u), c.breakaway_n(u)


def _nest_compression(c: Corner, load_n: float) -> float:
    outer = c.front_outer_n_per_m + c.rear_outer_n_per_m
    inner = c.front_inner_n_per_m + c.rear_inner_n_per_m
    if outer > 0 and load_n <= outer * c.inner_clearance_m:
        return load_n / outer
    return (load_n + inner * c.inner_clearance_m) / (outer + inner)


@dataclass(frozen=True, eq=False)
class WagonModel:
    """A model-B wagon ready to simulate: one load's parameters and the 8 corners (leading bogie first)."""

    params: WagonParameters
    corners: tuple[Corner, ...]

    @property
    def mass_diag(self) -> FloatArray:
        p = self.params
        m = np.empty(N_DOF)
        m[0:3] = (p.carbody_mass_kg, p.carbody_pitch_inertia_kg_m2, p.carbody_roll_inertia_kg_m2)
        for base in FRAME:
            m[base : base + 3] = (p.frame_mass_kg, p.frame_pitch_inertia_kg_m2, p.frame_roll_inertia_kg_m2)
        for j in range(4):
            m[WHEELSET + 2 * j : WHEELSET + 2 * j + 2] = (p.wheelset_mass_kg, p.wheelset_roll_inertia_kg_m2)
        m[TRACK:] = p.track_mass_kg
        return m

    def gravity_force(self) -> FloatArray:
        p = self.params
        out = np.zeros(N_DOF)
        out[CARBODY] = -p.carbody_mass_kg * p.gravity_mps2
        for base in FRAME:
            out[base] = -p.frame_mass_kg * p.gravity_mps2
        for j in range(4):
            out[WHEELSET + 2 * j] = -p.wheelset_mass_kg * p.gravity_mps2
        return out

    def corner_table(self) -> FloatArray:
        return np.array([c.as_row() for c in self.corners])

    # Element rows ---------------------------------------------------------------------------

    def corner_rows(self) -> FloatArray:
        """(8, 25): compression of each primary corner, axle box up minus frame corner up."""
        p = self.params
        rows = np.zeros((8, N_DOF))
        for bogie in range(2):
            for c, corner in enumerate(CORNER_ORDER):
                k = 4 * bogie + c
                axle = 2 * bogie + (0 if corner.x_sign > 0 else 1)
                y = corner.y_sign * p.half_box_spacing_m
                rows[k, WHEELSET + 2 * axle] = 1.0
                rows[k, WHEELSET + 2 * axle + 1] = y
                base = FRAME[bogie]
                rows[k, base] = -1.0
                rows[k, base + 1] = -corner.x_sign * p.half_wheelbase_m
                rows[k, base + 2] = -y
        return rows

    def contact_rows(self) -> FloatArray:
        """(8, 25): each wheel's contact compression without the irregularity (track mass minus contact point)."""
        b = self.params.half_contact_spacing_m
        rows = np.zeros((N_WHEELS, N_DOF))
        for axle in range(4):
            for side, y in enumerate((b, -b)):
                m = 2 * axle + side
                rows[m, TRACK + m] = 1.0
                rows[m, WHEELSET + 2 * axle] = -1.0
                rows[m, WHEELSET + 2 * axle + 1] = -y
        return rows

    def track_rows(self) -> FloatArray:
        """(8, 25): compression of each track spring (the track mass moving down)."""
        rows = np.zeros((N_WHEELS, N_DOF))
        for m in range(N_WHEELS):
            rows[m, TRACK + m] = -1.0
        return rows

    def bowl_rows(self) -> FloatArray:
        """(2, 25): each centre bowl's compression, frame centre up minus carbody up at the bowl."""
        rows = np.zeros((2, N_DOF))
        for bogie, x in enumerate(self.params.bogie_centres_x_m):
            rows[bogie, FRAME[bogie]] = 1.0
            rows[bogie, 0] = -1.0
            rows[bogie, 1] = -x
        return rows

    def rocking_rows(self) -> FloatArray:
        """(4, 25): each frame's pitch and roll relative to the carbody (bogie 0 pitch, roll, bogie 1 ...)."""
        rows = np.zeros((4, N_DOF))
        for bogie in range(2):
            for axis in range(2):  # pitch, roll
                rows[2 * bogie + axis, FRAME[bogie] + 1 + axis] = 1.0
                rows[2 * bogie + axis, 1 + axis] = -1.0
        return rows

    def bearer_rows(self) -> FloatArray:
        """(4, 25): each side bearer's closure (bogie 0 left, right, bogie 1 ...), before the clearance."""
        p = self.params
        y_sb = p.half_bearer_spacing_m
        rows = np.zeros((4, N_DOF))
        for bogie, x in enumerate(p.bogie_centres_x_m):
            for side, y in enumerate((y_sb, -y_sb)):
                r = rows[2 * bogie + side]
                r[FRAME[bogie]] = 1.0
                r[FRAME[bogie] + 2] = y
                r[0] = -1.0
                r[1] = -x
                r[2] = -y
        return rows


@dataclass(frozen=True)
class State:
    """Positions q (25,), velocities v (25,) and friction bristles w (12,) of one model-B wagon."""

    q: FloatArray
    v: FloatArray
    w: FloatArray


@dataclass(frozen=True)
class ElementForces:
    """The forces of one evaluation (N, N m), for checks."""

    primary_n: FloatArray  # (8,) each corner's total upward force on the frame
    friction_n: FloatArray  # (8,) its Lenoir part
    friction_limit_n: FloatArray  # (8,) mu_s x link ratio x the rear nest's force
    contact_n: FloatArray  # (8,) wheel-rail
    bowl_n: FloatArray  # (2,)
    bowl_moment_n_m: FloatArray  # (4,) on the frame's rocking, pitch and roll per bogie
    bearer_n: FloatArray  # (4,)


def forces_reference(
    model: WagonModel,
    q: FloatArray,
    v: FloatArray,
    w: FloatArray,
    rail_z_m: FloatArray,
    rail_v_mps: FloatArray,
    dt_s: float,
    friction_on: bool = True,
) -> tuple[FloatArray, FloatArray, ElementForces]:
    """Generalised forces (25,), the bristles after the step (12,), and the element forces.

    rail_z_m / rail_v_mps: the irregularity under each wheel (axle-major, left first) and its rate.
    """
    p = model.params
    w_new = np.array(w, dtype=np.float64)
    # Primary corners.
    rows = model.corner_rows()
    u, du = rows @ q, rows @ v
    primary = np.empty(8)
    fric = np.zeros(8)
    limit = np.empty(8)
    for k, c in enumerate(model.corners):
        front_n, rear_n = c.nest_forces_n(u[k])
        limit[k] = friction.lenoir_limit_n(rear_n, c.mu_ratio, 1.0)
        if friction_on:
            w_new[k] = friction.bristle_update(w[k], du[k], dt_s, c.presliding_m, c.kinetic_to_static, c.stribeck_velocity_mps)
            fric[k] = limit[k] * w_new[k]
        primary[k] = front_n + rear_n + fric[k] + c.damping_n_s_per_m * du[k]
    generalised = -rows.T @ primary
    # Wheel-rail contacts and the track.
    rows = model.contact_rows()
    delta, ddelta = rows @ q + rail_z_m, rows @ v + rail_v_mps
    contact_n = np.array(
        [contact.contact_force_n(delta[m], ddelta[m], p.contact_stiffness_n_per_m, p.contact_damping_n_s_per_m) for m in range(N_WHEELS)]
    )
    generalised -= rows.T @ contact_n
    rows = model.track_rows()
    track_n = p.track_stiffness_n_per_m * (rows @ q) + p.track_damping_n_s_per_m * (rows @ v)
    generalised -= rows.T @ track_n
    # Centre bowls and their friction moment.
    rows = model.bowl_rows()
    ub, dub = rows @ q, rows @ v
    bowl_n = np.array([contact.unilateral_spring_n(ub[i], dub[i], p.bowl_stiffness_n_per_m, p.bowl_damping_n_s_per_m) for i in range(2)])
    generalised -= rows.T @ bowl_n
    rows = model.rocking_rows()
    rate = rows @ v
    moment = np.zeros(4)
    if friction_on:
        for bogie in range(2):
            i = BOWL_FRICTION + 2 * bogie
            w_new[i], w_new[i + 1] = friction.bristle_update_2d(
                w[i], w[i + 1], rate[2 * bogie], rate[2 * bogie + 1], dt_s,
                p.bowl_presliding_rad, p.bowl_kinetic_to_static, p.bowl_stribeck_radps,
            )  # fmt: skip
            m_lim = p.bowl_friction_coefficient * p.bowl_friction_radius_m * bowl_n[bogie]
            moment[2 * bogie] = m_lim * w_new[i]
            moment[2 * bogie + 1] = m_lim * w_new[i + 1]
    generalised -= rows.T @ moment
    # Side bearers.
    rows = model.bearer_rows()
    closure, dclosure = rows @ q - p.bearer_clearance_m, rows @ v
    bearer_n = np.array(
        [contact.unilateral_spring_n(closure[i], dclosure[i], p.bearer_stiffness_n_per_m, p.bearer_damping_n_s_per_m) for i in range(4)]
    )
    generalised -= rows.T @ bearer_n
    generalised += model.gravity_force()
    return generalised, w_new, ElementForces(primary, fric, limit, contact_n, bowl_n, moment, bearer_n)


def step_reference(
    model: WagonModel, state: State, rail_z_m: FloatArray, rail_v_mps: FloatArray, dt_s: float
) -> tuple[State, FloatArray]:
    """One step: bristles, forces, semi-implicit Euler. Returns the new state and the accelerations."""
    forces, w, _ = forces_reference(model, state.q, state.v, state.w, rail_z_m, rail_v_mps, dt_s)
    accel = forces / model.mass_diag
    v = state.v + dt_s * accel
    return State(q=state.q + dt_s * v, v=v, w=w), accel


# Rest and linearisation ---------------------------------------------------------------------------


def stiffness_matrix(model: WagonModel, q: FloatArray, stuck: bool, closed: bool = False) -> FloatArray:
    """Tangent stiffness (25, 25) at q, v = 0: every element at its current stage.

    stuck=True adds the friction elements' pre-sliding stiffness (F_lim / delta at the current
    normal force): the small-amplitude limit; stuck=False leaves friction out (gross sliding).
    closed=True takes the contacts, bowls and outer coils as touching whatever q (Newton's start).
    """
    p = model.params
    k = np.zeros((N_DOF, N_DOF))

    def add(rows: FloatArray, stiffness: FloatArray) -> None:
        nonlocal k
        k += rows.T @ (stiffness[:, None] * rows)

    rows = model.corner_rows()
    u = rows @ q
    add(rows, np.array([c.tangent_stiffness_n_per_m(max(float(x), 1e-12) if closed else float(x)) for c, x in zip(model.corners, u, strict=True)]))
    if stuck:
        add(rows, np.array([c.breakaway_n(float(x)) / c.presliding_m for c, x in zip(model.corners, u, strict=True)]))
    rows = model.contact_rows()
    add(rows, np.where((rows @ q > 0.0) | closed, p.contact_stiffness_n_per_m, 0.0))
    add(model.track_rows(), np.full(N_WHEELS, p.track_stiffness_n_per_m))
    rows = model.bowl_rows()
    ub = rows @ q
    add(rows, np.where((ub > 0.0) | closed, p.bowl_stiffness_n_per_m, 0.0))
    if stuck:
        n_bowl = p.bowl_stiffness_n_per_m * np.maximum(ub, 0.0)
        k_rock = p.bowl_friction_coefficient * p.bowl_friction_radius_m * n_bowl / p.bowl_presliding_rad
        add(model.rocking_rows(), np.repeat(k_rock, 2))
    rows = model.bearer_rows()
    add(rows, np.where(rows @ q - p.bearer_clearance_m > 0.0, p.bearer_stiffness_n_per_m, 0.0))
    return k


def static_equilibrium(model: WagonModel, tol_n: float = 1e-6) -> State:
    """Rest on a level track with the friction unloaded (bristles at zero): the springs carry the weight.

    Newton on the piecewise-linear elements. Within the side bearers' clearance nothing holds the
    carbody's roll at rest (its rest roll is any angle inside the gap), so the step is the least-
    squares one: it leaves that free direction where it started (level).
    """
    zero = np.zeros(N_DOF)
    rail = np.zeros(N_WHEELS)
    q = np.zeros(N_DOF)
    for iteration in range(60):
        forces, _, _ = forces_reference(model, q, zero, np.zeros(N_FRICTION), rail, rail, 1.0, friction_on=False)
        if np.max(np.abs(forces)) < tol_n:
            break
        k = stiffness_matrix(model, q, stuck=False, closed=iteration == 0)
        q = q + np.linalg.lstsq(k, forces, rcond=1e-12)[0]
    else:  # pragma: no cover - piecewise-linear Newton converges in a few steps
        raise RuntimeError("model B's static equilibrium did not converge")
    return State(q=q, v=np.zeros(N_DOF), w=np.zeros(N_FRICTION))


_GROUPS = (
    ("carbody bounce", [0]), ("carbody pitch", [1]), ("carbody roll", [2]),
    ("frame bounce", [3, 6]), ("frame pitch", [4, 7]), ("frame roll", [5, 8]),
    ("wheelset bounce", [9, 11, 13, 15]), ("wheelset roll", [10, 12, 14, 16]),
    ("track", list(range(TRACK, N_DOF))),
)  # fmt: skip


@dataclass(frozen=True)
class Mode:
    frequency_hz: float
    name: str  # the group of coordinates holding the largest share of the mode's kinetic energy
    energy_share: float


def normal_modes(model: WagonModel, stuck: bool) -> list[Mode]:
    """Undamped modes of model B linearised about its rest, lowest first (stuck or sliding friction)."""
    rest = static_equilibrium(model)
    k = stiffness_matrix(model, rest.q, stuck=stuck)
    scale = 1.0 / np.sqrt(model.mass_diag)
    omega2, vectors = np.linalg.eigh(scale[:, None] * k * scale[None, :])
    modes = []
    for w2, vec in zip(omega2, vectors.T, strict=True):
        share = vec**2
        grouped = np.array([share[idx].sum() for _, idx in _GROUPS])
        i = int(np.argmax(grouped))
        modes.append(Mode(float(math.sqrt(max(w2, 0.0)) / (2 * math.pi)), _GROUPS[i][0], float(grouped[i])))
    return modes


def natural_frequencies(model: WagonModel, stuck: bool) -> dict[str, float]:
    """The lowest frequency (Hz) of the modes each group of coordinates dominates."""
    out: dict[str, float] = {}
    for mode in normal_modes(model, stuck):
        out.setdefault(mode.name, mode.frequency_hz)
    return out


# Faults -------------------------------------------------------------------------------------------


def _faulty(healthy: Corner, fault: Fault, kz_nominal: float) -> Corner:
    """A corner under one fault, model B's reading of the paper's vocabulary (custom's Fs set later)."""
    if fault.kind == "custom":
        assert fault.kz_n_per_m is not None
        scale = fault.kz_n_per_m / kz_nominal
        return replace(
            healthy,
            front_outer_n_per_m=healthy.front_outer_n_per_m * scale,
            front_inner_n_per_m=healthy.front_inner_n_per_m * scale,
            rear_outer_n_per_m=healthy.rear_outer_n_per_m * scale,
            rear_inner_n_per_m=healthy.rear_inner_n_per_m * scale,
        )
    assert fault.severity is not None
    if fault.severity == HEALTHY_SEVERITY:
        return healthy
    if fault.kind == "type_b":
        # The damper's friction coefficient (a worn or seized shoe); Fs follows at every load.
        return replace(healthy, mu_ratio=healthy.mu_ratio * fault.severity)
    field = {
        "front_outer": "front_outer_n_per_m",
        "front_inner": "front_inner_n_per_m",
        "rear_outer": "rear_outer_n_per_m",
        "rear_inner": "rear_inner_n_per_m",
    }[fault.position or ""]
    # One coil at severity x its stiffness; the friction follows the rear nest's load by itself.
    return replace(healthy, **{field: getattr(healthy, field) * fault.severity})


def _apply(
    corners: list[Corner], faults: tuple[Fault, ...], kz_nominal: float
) -> tuple[list[Corner], list[tuple[int, float]]]:
    out = list(corners)
    custom_fs: list[tuple[int, float]] = []
    for fault in faults:
        k = BOGIES.index(fault.bogie) * 4 + CORNER_ORDER.index(fault.corner)
        out[k] = _faulty(out[k], fault, kz_nominal)
        if fault.kind == "custom":
            assert fault.fs_n is not None
            custom_fs.append((k, fault.fs_n))
    return out, custom_fs


def _calibrate_custom_friction(model: WagonModel, custom_fs: list[tuple[int, float]]) -> WagonModel:
    """Set each custom corner's friction so that it breaks away at its Fs at this wagon's rest."""
    if not custom_fs:
        return model
    rest = static_equilibrium(model)
    u = model.corner_rows() @ rest.q
    corners = list(model.corners)
    for k, fs_n in custom_fs:
        rear_n = corners[k].nest_forces_n(float(u[k]))[1]
        corners[k] = replace(corners[k], mu_ratio=fs_n / rear_n if rear_n > 0.0 else 0.0)
    return WagonModel(model.params, tuple(corners))


def build_models(
    parameter_set: dict[str, Any], load: str, standing: tuple[Fault, ...] = (), faults: tuple[Fault, ...] = ()
) -> tuple[WagonModel, WagonModel]:
    """(before the fault onset, after it): the standing faults alone, then with `faults` as well.

    Custom faults' Kz scale the corner's four coils to that tangent stiffness at the load (model
    B's own nominal Kz as the base); their Fs sets the corner's friction so that it breaks away at
    Fs at the wagon's rest, the standing ones on the wagon before the onset.
    """
    p = wagon_parameters(parameter_set, load)
    seen: set[tuple[str, Any]] = set()
    for fault in standing + faults:
        key = (fault.bogie, fault.corner)
        if key in seen:
            raise SimulationError(f"two faults at {fault.where}: give at most one fault per corner (custom for a combination)")
        seen.add(key)
    kz_nominal, _ = nominal_corner_values(p)
    corners, custom = _apply([healthy_corner(p)] * 8, standing, kz_nominal)
    before = _calibrate_custom_friction(WagonModel(p, tuple(corners)), custom)
    if not faults:
        return before, before
    corners, custom = _apply(list(before.corners), faults, kz_nominal)
    return before, _calibrate_custom_friction(WagonModel(p, tuple(corners)), custom)


def build_model(parameter_set: dict[str, Any], load: str, faults: tuple[Fault, ...] = ()) -> WagonModel:
    """The wagon with `faults` from the start."""
    return build_models(parameter_set, load, faults, ())[0]
