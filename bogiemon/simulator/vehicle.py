"""The wagon's vertical equations of motion: geometry, a plain numpy reference, equilibrium, modes.

Degrees of freedom (9; small motions about the free-length configuration, z up, SI units):
  0..2  carbody bounce z_c (m), pitch theta_c (rad, leading end up), roll phi_c (rad, left up)
  3..5  leading bogie frame bounce, pitch, roll (the monitored bogie)
  6..8  trailing bogie frame bounce, pitch, roll
A point (x, y) of a body moves by z + x theta + y phi (detection/kinematics.py's convention).
The carbody's x runs from its centre of mass towards the leading bogie (at x = +a, the bogies
at +/-a; at a - e and -a - e when the ends are loaded unequally, VehicleParameters'
carbody_centre_offset_m = e), each frame's from its centre towards its leading axle (at x = +l);
y towards the left rail.

Forces (generalised force Q = sum of G^T F over the elements, with G the element's row):
  - primary suspension at each of the 8 axle boxes (suspension.py), between the axle box, whose
    height the rails prescribe, and the frame corner (x = +/-l, y = +/-b_p);
  - the centre bowl of each bogie: a stiff vertical spring-damper between the frame centre and
    the carbody at (x = +/-a, 0), free in pitch and roll (a pivot);
  - two constant-contact side bearers per bogie at y = +/-b_sb, spring-dampers between frame and
    carbody that carry the carbody's roll;
  - gravity on the carbody and the frames.
The mass matrix is diagonal: every body's coordinates are at its centre of mass.

The time step (the kernel does exactly the same arithmetic, see kernel.py): accelerations at
t_n from positions q_n, velocities v_n and the friction sliders, then semi-implicit (symplectic)
Euler, v_{n+1} = v_n + dt a_n, q_{n+1} = q_n + dt v_{n+1}: second-order accurate positions for
the undamped part, no numerical damping of the carbody modes, stable for dt below 2 / omega_max.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.simulator.params import VehicleParameters, vehicle_parameters
from bogiemon.simulator.suspension import CORNER_ORDER, CornerSuspension, Fault, corner_suspensions, friction_step
from bogiemon.simulator.track import TrackProfile

FloatArray = NDArray[np.float64]
N_DOF = 9
DOF_NAMES = (
    "carbody bounce", "carbody pitch", "carbody roll",
    "leading frame bounce", "leading frame pitch", "leading frame roll",
    "trailing frame bounce", "trailing frame pitch", "trailing frame roll",
)  # fmt: skip


@dataclass(frozen=True)
class VehicleModel:
    """A wagon ready to simulate: parameters for one load and the 8 corners' suspensions."""

    params: VehicleParameters
    corners: tuple[CornerSuspension, ...]  # leading bogie then trailing, each in CORNER_ORDER

    @property
    def mass_diag(self) -> FloatArray:
        p = self.params
        body = [p.carbody_mass_kg, p.carbody_pitch_inertia_kg_m2, p.carbody_roll_inertia_kg_m2]
        frame = [p.frame_mass_kg, p.frame_pitch_inertia_kg_m2, p.frame_roll_inertia_kg_m2]
        return np.array(body + frame + frame)

    def gravity_force(self) -> FloatArray:
        q = np.zeros(N_DOF)
        g = self.params.gravity_mps2
        q[0] = -self.params.carbody_mass_kg * g
        q[3] = q[6] = -self.params.frame_mass_kg * g
        return q

    def corner_rows(self) -> FloatArray:
        """(8, 9): row k maps q to the vertical displacement of frame corner k."""
        p = self.params
        rows = np.zeros((8, N_DOF))
        for bogie in range(2):
            for c, corner in enumerate(CORNER_ORDER):
                k = 4 * bogie + c
                base = 3 + 3 * bogie
                rows[k, base] = 1.0
                rows[k, base + 1] = corner.x_sign * p.wheelbase_m / 2
                rows[k, base + 2] = corner.y_sign * p.axle_box_spacing_m / 2
        return rows

    def bowl_rows(self) -> FloatArray:
        """(2, 9): row j maps q to the compression of bogie j's centre bowl (frame up minus carbody)."""
        rows = np.zeros((2, N_DOF))
        for bogie, x in enumerate(self.params.bogie_centres_x_m):
            rows[bogie, 3 + 3 * bogie] = 1.0
            rows[bogie, 0] = -1.0
            rows[bogie, 1] = -x
        return rows

    def side_bearer_rows(self) -> FloatArray:
        """(4, 9): bogie j's left (2j) and right (2j + 1) side bearers' compressions."""
        y_sb = self.params.side_bearer_spacing_m / 2
        rows = np.zeros((4, N_DOF))
        for bogie, x in enumerate(self.params.bogie_centres_x_m):
            for side, y in enumerate((y_sb, -y_sb)):
                r = rows[2 * bogie + side]
                r[3 + 3 * bogie] = 1.0
                r[5 + 3 * bogie] = y
                r[0] = -1.0
                r[1] = -x
                r[2] = -y
        return rows

    def corner_table(self) -> FloatArray:
        """(8, 6) per-corner parameters in the kernel's order (CornerSuspension.as_row)."""
        return np.array([c.as_row() for c in self.corners])


def box_motion_reference(
    params: VehicleParameters, track: TrackProfile, front_axle_m: float, speed_mps: float
) -> tuple[FloatArray, FloatArray]:
    """Heights (m) and vertical velocities (m/s) of the 8 axle boxes, in corner order.

    front_axle_m is the first axle's position along the track; each axle sees the rails at its
    own position, linearly interpolated, and a rigid wheelset rolls with the rails' cross-level.
    """
    offsets = np.asarray(params.axle_offsets_m)
    pos = front_axle_m - offsets
    s = np.arange(track.left_m.shape[0]) * track.ds_m
    z_left = np.interp(pos, s, track.left_m)
    z_right = np.interp(pos, s, track.right_m)
    seg = np.floor(pos / track.ds_m).astype(int)
    v_left = speed_mps * (track.left_m[seg + 1] - track.left_m[seg]) / track.ds_m
    v_right = speed_mps * (track.right_m[seg + 1] - track.right_m[seg]) / track.ds_m
    lever = params.axle_box_spacing_m / params.contact_spacing_m
    heights = np.empty(8)
    velocities = np.empty(8)
    for axle in range(4):
        bogie, trailing = divmod(axle, 2)
        for side, sign in ((0, 1.0), (1, -1.0)):  # left, right
            k = 4 * bogie + 2 * trailing + side
            heights[k] = 0.5 * (z_left[axle] + z_right[axle]) + sign * lever * 0.5 * (z_left[axle] - z_right[axle])
            velocities[k] = 0.5 * (v_left[axle] + v_right[axle]) + sign * lever * 0.5 * (v_left[axle] - v_right[axle])
    return heights, velocities


def forces_reference(
    model: VehicleModel,
    q: FloatArray,
    v: FloatArray,
    box_z: FloatArray,
    box_v: FloatArray,
    slider: FloatArray,
    friction: bool = True,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Generalised forces (9,), the updated friction sliders (8,) and the primary forces (8,) in N."""
    p = model.params
    corner_rows, bowl_rows, bearer_rows = model.corner_rows(), model.bowl_rows(), model.side_bearer_rows()
    compression = box_z - corner_rows @ q
    rate = box_v - corner_rows @ v
    primary = np.empty(8)
    new_slider = slider.copy()
    for k, corner in enumerate(model.corners):
        f_friction = 0.0
        if friction:
            f_friction, new_slider[k] = friction_step(
                compression[k], slider[k], corner.stick_stiffness_n_per_m, corner.fs_n
            )
        primary[k] = float(corner.spring_force_n(compression[k])) + f_friction + corner.damping_n_s_per_m * rate[k]
    bowl = p.bowl_stiffness_n_per_m * (bowl_rows @ q) + p.bowl_damping_n_s_per_m * (bowl_rows @ v)
    bearer = p.side_bearer_stiffness_n_per_m * (bearer_rows @ q) + p.side_bearer_damping_n_s_per_m * (bearer_rows @ v)
    generalised = corner_rows.T @ primary - bowl_rows.T @ bowl - bearer_rows.T @ bearer + model.gravity_force()
    return generalised, new_slider, primary


@dataclass(frozen=True)
class State:
    """Positions q (9,), velocities v (9,) and friction sliders (8,) of one wagon."""

    q: FloatArray
    v: FloatArray
    slider: FloatArray


def step_reference(
    model: VehicleModel, state: State, box_z: FloatArray, box_v: FloatArray, dt_s: float
) -> tuple[State, FloatArray]:
    """One semi-implicit Euler step; returns the new state and the accelerations at the old time."""
    forces, slider, _ = forces_reference(model, state.q, state.v, box_z, box_v, state.slider)
    accel = forces / model.mass_diag
    v = state.v + dt_s * accel
    return State(q=state.q + dt_s * v, v=v, slider=slider), accel


def static_equilibrium(model: VehicleModel, box_z: FloatArray | None = None, tol_n: float = 1e-6) -> State:
    """Rest position with the friction elements unloaded (sliders at the compressions): springs carry the weight.

    Newton's method on the piecewise-linear spring forces, from the linear solution.
    """
    box = np.zeros(8) if box_z is None else np.asarray(box_z, dtype=np.float64)
    zero = np.zeros(N_DOF)
    q = np.zeros(N_DOF)
    for _ in range(50):
        forces, _, _ = forces_reference(model, q, zero, box, np.zeros(8), np.zeros(8), friction=False)
        if np.max(np.abs(forces)) < tol_n:
            break
        q = q + np.linalg.solve(stiffness_matrix(model, q, box, stick=False), forces)
    else:  # pragma: no cover - piecewise-linear Newton converges in a few steps
        raise RuntimeError("static equilibrium did not converge")
    compression = box - model.corner_rows() @ q
    return State(q=q, v=np.zeros(N_DOF), slider=compression.copy())


def stiffness_matrix(model: VehicleModel, q: FloatArray, box_z: FloatArray, stick: bool) -> FloatArray:
    """Tangent stiffness (9, 9) at q: coil nests at their current stage, plus k_stick if stuck."""
    p = model.params
    corner_rows = model.corner_rows()
    compression = box_z - corner_rows @ q
    k_corner = np.array(
        [
            c.tangent_stiffness_n_per_m(float(u)) + (c.stick_stiffness_n_per_m if stick else 0.0)
            for c, u in zip(model.corners, compression, strict=True)
        ]
    )
    bowl, bearer = model.bowl_rows(), model.side_bearer_rows()
    return (
        corner_rows.T @ (k_corner[:, None] * corner_rows)
        + p.bowl_stiffness_n_per_m * bowl.T @ bowl
        + p.side_bearer_stiffness_n_per_m * bearer.T @ bearer
    )


_MODE_NAMES = ("carbody bounce", "carbody pitch", "carbody roll", "frame bounce", "frame pitch", "frame roll")


@dataclass(frozen=True)
class Mode:
    frequency_hz: float
    name: str  # the body motion holding the largest share of the mode's kinetic energy (frames together)
    energy_share: float


def normal_modes(model: VehicleModel, stick: bool) -> list[Mode]:
    """Undamped modes of the model linearised about its static equilibrium, lowest first.

    stick=False: friction sliding (it adds no stiffness), the large-amplitude limit;
    stick=True: every damper stuck (k_stick in parallel with Kz), the small-amplitude limit.
    """
    rest = static_equilibrium(model)
    k = stiffness_matrix(model, rest.q, np.zeros(8), stick=stick)
    m = model.mass_diag
    scale = 1.0 / np.sqrt(m)
    omega2, vectors = np.linalg.eigh(scale[:, None] * k * scale[None, :])
    modes = []
    for w2, vec in zip(omega2, vectors.T, strict=True):
        share = vec**2  # mass-normalised coordinates: the kinetic energy distribution over the DOFs
        # Group the two frames: their modes pair up in and out of phase with equal shares.
        grouped = np.concatenate([share[:3], share[3:6] + share[6:9]])
        i = int(np.argmax(grouped))
        frequency_hz = float(np.sqrt(max(w2, 0.0)) / (2 * np.pi))
        modes.append(Mode(frequency_hz=frequency_hz, name=_MODE_NAMES[i], energy_share=float(grouped[i])))
    return modes


def natural_frequencies(model: VehicleModel, stick: bool) -> dict[str, float]:
    """Frequency (Hz) of the mode dominated by each body motion ("carbody bounce", "leading frame pitch", ...).

    Keys: "carbody bounce|pitch|roll", "frame bounce|pitch|roll". The two frames' modes pair up
    (in and out of phase, nearly the same frequency); the lower of each pair is given.
    """
    out: dict[str, float] = {}
    for mode in normal_modes(model, stick):
        out.setdefault(mode.name, mode.frequency_hz)
    return out


def build_model(parameter_set: dict[str, Any], load: str, faults: tuple[Fault, ...] = ()) -> VehicleModel:
    """The wagon of a parameter set (params.default_parameter_set()) at a load, with faults."""
    params = vehicle_parameters(parameter_set, load)
    return VehicleModel(params=params, corners=corner_suspensions(params, parameter_set["fault_cases"], faults))
