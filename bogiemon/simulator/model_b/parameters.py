"""Model B's parameters: config/y25_wagon_b.toml as a plain dict (for the sidecar) and typed per load.

A model-B parameter set is {"model": "b", "vehicle": <the parsed TOML>}; a scenario keeps it whole
so that its sidecar reproduces the run even if the shipped file changes. `wagon_parameters()` turns
it into the frozen WagonParameters of one load, with the two quantities B derives rather than reads:
the Lenoir link ratio (calibrated on the paper's healthy full-load Fs) and the linearised Hertzian
contact stiffness at the load's static wheel load.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any

from bogiemon.simulator.errors import SimulationError

MODEL_TAG = "b"
PARAMETER_FILE = "y25_wagon_b.toml"
LOADS = ("full", "tare")
# Sensor skew is a delay line inside the kernel of this many integration steps.
MAX_SKEW_STEPS = 7
# The kernel runs every scenario of a batch through as many filter sections (sensors.N_SECTIONS):
# the resonance and up to two of the anti-alias Butterworth.
MAX_ANTIALIAS_ORDER = 4


def default_parameter_set() -> dict[str, Any]:
    """{'model': 'b', 'vehicle': <y25_wagon_b.toml>} as parsed from the shipped file."""
    try:
        text = resources.files("bogiemon.config").joinpath(PARAMETER_FILE).read_text(encoding="utf-8")
    except (OSError, ValueError):
        raise SimulationError(f"{PARAMETER_FILE}: no such vehicle parameter file in bogiemon's config folder") from None
    return {"model": MODEL_TAG, "vehicle": tomllib.loads(text)}


def is_parameter_set(parameters: Any) -> bool:
    """True for a model-B parameter set (a model-A set has no 'model' tag)."""
    return isinstance(parameters, dict) and parameters.get("model") == MODEL_TAG


def with_ideal_sensor(parameters: dict[str, Any]) -> dict[str, Any]:
    """A copy of a parameter set whose sensors are exact, bogie 2's too: no resonance error, noise,
    bias, drift, cross-axis, skew or quantisation (the anti-alias filter stays: it is how the rate
    is reduced)."""
    out = {"model": parameters["model"], "vehicle": {**parameters["vehicle"]}}
    sensor = dict(out["vehicle"]["sensor"])
    sensor.update(
        resonance_hz=0.0,
        noise_density_mps2_per_sqrt_hz=0.0,
        bias_mps2=[0.0, 0.0, 0.0],
        bias_instability_mps2=0.0,
        bias_random_walk_mps2_per_sqrt_s=0.0,
        gain=[1.0, 1.0, 1.0],
        cross_axis=[0.0, 0.0, 0.0],
        skew_s=[0.0, 0.0, 0.0],
        bits=0,
    )
    out["vehicle"]["sensor"] = sensor
    # Bogie 2's parts (a run of two bogies) exact too, not drawn (sensors.other_part).
    out["vehicle"]["sensor_bogie_2"] = {"gain": [1.0, 1.0, 1.0], "bias_mps2": [0.0, 0.0, 0.0], "cross_axis": [0.0, 0.0, 0.0], "skew_s": [0.0, 0.0, 0.0]}
    return out


@dataclass(frozen=True)
class SensorParameters:
    """The MEMS accelerometers of model B (sensors.py). resonance_hz 0: no resonance; bits 0: no converter."""

    resonance_hz: float
    resonance_damping_ratio: float
    antialias_fraction_of_fs: float
    noise_density_mps2_per_sqrt_hz: float
    bias_mps2: tuple[float, float, float]
    bias_instability_mps2: float
    bias_random_walk_mps2_per_sqrt_s: float
    gain: tuple[float, float, float]
    cross_axis: tuple[float, float, float]
    skew_s: tuple[float, float, float]
    bits: int
    range_g: float
    hunting_wavelength_m: float
    hunting_bandwidth_fraction: float
    hunting_rms_mps2_at_100_kmh: float
    random_lateral_rms_mps2_at_100_kmh: float
    # Extra white noise of each channel's sensing element (a failing one), a density like the
    # sensor's own and shaped by its anti-alias filter whatever noise_inside says: inside the sensor.
    element_noise_density_mps2_per_sqrt_hz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    antialias_order: int = 4  # of the anti-alias Butterworth (1 to MAX_ANTIALIAS_ORDER)
    # The sensor's white noise enters before its anti-alias filter (True: the MEMS element feeds
    # it) or after it (the converter's or the cable's, white up to Nyquist).
    noise_inside: bool = True


@dataclass(frozen=True)
class WagonParameters:
    """Everything model B's equations need for one load. SI units; half-distances are from the centre."""

    load: str
    gravity_mps2: float
    carbody_mass_kg: float
    carbody_pitch_inertia_kg_m2: float
    carbody_roll_inertia_kg_m2: float
    half_bogie_distance_m: float
    frame_mass_kg: float
    frame_pitch_inertia_kg_m2: float
    frame_roll_inertia_kg_m2: float
    half_wheelbase_m: float
    half_box_spacing_m: float
    wheelset_mass_kg: float
    wheelset_roll_inertia_kg_m2: float
    half_contact_spacing_m: float
    wheel_radius_m: float
    contact_stiffness_n_per_m: float  # linearised Hertz at this load's static wheel load
    contact_damping_n_s_per_m: float
    track_mass_kg: float
    track_stiffness_n_per_m: float
    track_damping_n_s_per_m: float
    outer_coil_n_per_m: float
    inner_coil_n_per_m: float
    inner_clearance_m: float
    primary_damping_n_s_per_m: float
    mu_static: float
    link_ratio: float  # calibrated: mu_static x link_ratio x F_rear_nest = Fs
    kinetic_to_static: float
    stribeck_velocity_mps: float
    presliding_m: float
    bowl_stiffness_n_per_m: float
    bowl_damping_n_s_per_m: float
    bowl_friction_coefficient: float
    bowl_friction_radius_m: float
    bowl_presliding_rad: float
    bowl_kinetic_to_static: float
    bowl_stribeck_radps: float
    half_bearer_spacing_m: float
    bearer_clearance_m: float
    bearer_stiffness_n_per_m: float
    bearer_damping_n_s_per_m: float
    sensor: SensorParameters
    # The carbody's centre of mass this far from mid-way between the bogie centres, towards the
    # leading bogie (a wagon whose ends are loaded unequally); its inertias are about that point.
    carbody_centre_offset_m: float = 0.0

    @property
    def bogie_centres_x_m(self) -> tuple[float, float]:
        """The leading and the trailing bogie centre's x from the carbody's centre of mass."""
        a = self.half_bogie_distance_m
        return (a - self.carbody_centre_offset_m, -a - self.carbody_centre_offset_m)

    @property
    def axle_offsets_m(self) -> tuple[float, float, float, float]:
        """Distance of each axle behind the first: axles 1, 2 (leading bogie), 3, 4."""
        wb, bc = 2.0 * self.half_wheelbase_m, 2.0 * self.half_bogie_distance_m
        return (0.0, wb, bc, bc + wb)

    @property
    def sprung_mass_kg(self) -> float:
        """Mass on the primary springs: the carbody and both frames."""
        return self.carbody_mass_kg + 2.0 * self.frame_mass_kg

    @property
    def total_mass_kg(self) -> float:
        return self.sprung_mass_kg + 4.0 * self.wheelset_mass_kg

    @property
    def static_corner_load_n(self) -> float:
        """Load on one axle box's nests of the symmetric, healthy wagon at rest."""
        return (self.carbody_mass_kg / 8.0 + self.frame_mass_kg / 4.0) * self.gravity_mps2


def nest_compression_m(load_n: float, outer_n_per_m: float, inner_n_per_m: float, clearance_m: float) -> float:
    """Compression of a two-stage nest (outer coils from 0, inner from the clearance) under a load."""
    if load_n <= outer_n_per_m * clearance_m or inner_n_per_m == 0.0:
        return load_n / outer_n_per_m
    return (load_n + inner_n_per_m * clearance_m) / (outer_n_per_m + inner_n_per_m)


def hertz_stiffness_n_per_m(wheel_load_n: float, radius_m: float, coefficient: float, exponent: float) -> float:
    """Tangent stiffness of the Hertzian contact delta = G P^(2/3), G = coefficient R^exponent."""
    g = coefficient * radius_m**exponent
    return 1.5 * wheel_load_n ** (1.0 / 3.0) / g


def _triple(values: Any, what: str) -> tuple[float, float, float]:
    out = tuple(float(x) for x in values)
    if len(out) != 3:
        raise SimulationError(f"model B sensor: {what} needs three values (a1, a2, a3), got {len(out)}")
    return out


def with_sensor_variant(parameters: dict[str, Any], variant: str) -> dict[str, Any]:
    """A copy of a parameter set read by another sensor part (simulator/sensors.py SENSOR_VARIANTS):
    the part's Butterworth (order, corner) as the sensor's anti-alias filter and its noise before or
    after it; "standard" leaves model B's own MEMS as the set has it."""
    from bogiemon.simulator.sensors import SENSOR_VARIANTS  # model A's sensor module names the parts

    if variant not in SENSOR_VARIANTS:
        raise SimulationError(f"unknown sensor variant '{variant}': use one of {', '.join(SENSOR_VARIANTS)}")
    out = {"model": parameters["model"], "vehicle": {**parameters["vehicle"], "sensor": dict(parameters["vehicle"]["sensor"])}}
    part = SENSOR_VARIANTS[variant]
    if part.order:
        out["vehicle"]["sensor"].update(
            antialias_order=part.order, antialias_fraction_of_fs=part.corner_fraction_of_fs, noise_inside=part.noise_inside
        )
    return out


def wagon_parameters(parameter_set: dict[str, Any], load: str) -> WagonParameters:
    """Typed parameters of model B for `load` ('full' or 'tare')."""
    if not is_parameter_set(parameter_set):
        raise SimulationError(
            "model b needs a model-B parameter set ({'model': 'b', 'vehicle': ...}, "
            "bogiemon.simulator.model_b.parameters.default_parameter_set()); this one is model A's"
        )
    if load not in LOADS:
        raise SimulationError(f"unknown load '{load}': use 'full' or 'tare'")
    try:
        v = parameter_set["vehicle"]
        body, frame, ws, contact, track = v["carbody"], v["bogie_frame"], v["wheelset"], v["contact"], v["track"]
        prim, lenoir, bowl, sb, sens = v["primary"], v["primary"]["lenoir"], v["centre_bowl"], v["side_bearers"], v["sensor"]
        g = float(v["gravity_mps2"])
        m_c = {lo: float(body[f"mass_{lo}_kg"]) for lo in LOADS}
        m_f, m_w = float(frame["mass_kg"]), float(ws["mass_kg"])
        k_o, k_i = float(prim["outer_coil_stiffness_n_per_m"]), float(prim["inner_coil_stiffness_n_per_m"])
        clearance = float(prim["inner_clearance_m"])
        mu_s = float(lenoir["mu_static"])
        # The link ratio: the healthy corner at full load breaks away at the calibration force.
        full_corner_n = (m_c["full"] / 8.0 + m_f / 4.0) * g
        u_full = nest_compression_m(full_corner_n, 2.0 * k_o, 2.0 * k_i, clearance)
        rear_nest_full_n = k_o * u_full + k_i * max(u_full - clearance, 0.0)
        link_ratio = float(lenoir["calibration_fs_full_n"]) / (mu_s * rear_nest_full_n)
        radius = float(ws["wheel_radius_m"])
        wheel_load_n = (m_c[load] / 8.0 + m_f / 4.0 + m_w / 2.0) * g
        k_contact = hertz_stiffness_n_per_m(
            wheel_load_n, radius, float(contact["hertz_coefficient_m_per_n23"]), float(contact["hertz_radius_exponent"])
        )
        sensor = SensorParameters(
            resonance_hz=float(sens["resonance_hz"]),
            resonance_damping_ratio=float(sens["resonance_damping_ratio"]),
            antialias_fraction_of_fs=float(sens["antialias_fraction_of_fs"]),
            noise_density_mps2_per_sqrt_hz=float(sens["noise_density_mps2_per_sqrt_hz"]),
            bias_mps2=_triple(sens["bias_mps2"], "bias_mps2"),
            bias_instability_mps2=float(sens["bias_instability_mps2"]),
            bias_random_walk_mps2_per_sqrt_s=float(sens["bias_random_walk_mps2_per_sqrt_s"]),
            gain=_triple(sens["gain"], "gain"),
            cross_axis=_triple(sens["cross_axis"], "cross_axis"),
            skew_s=_triple(sens["skew_s"], "skew_s"),
            bits=int(sens["bits"]),
            range_g=float(sens["range_g"]),
            hunting_wavelength_m=float(sens["hunting_wavelength_m"]),
            hunting_bandwidth_fraction=float(sens["hunting_bandwidth_fraction"]),
            hunting_rms_mps2_at_100_kmh=float(sens["hunting_rms_mps2_at_100_kmh"]),
            random_lateral_rms_mps2_at_100_kmh=float(sens["random_lateral_rms_mps2_at_100_kmh"]),
            # Parameter sets written before these: no element noise, the 4th-order filter, the noise inside.
            element_noise_density_mps2_per_sqrt_hz=_triple(sens.get("element_noise_density_mps2_per_sqrt_hz", (0.0, 0.0, 0.0)), "element_noise_density_mps2_per_sqrt_hz"),
            antialias_order=int(sens.get("antialias_order", 4)),
            noise_inside=bool(sens.get("noise_inside", True)),
        )
        params = WagonParameters(
            load=load,
            gravity_mps2=g,
            carbody_mass_kg=m_c[load],
            carbody_pitch_inertia_kg_m2=float(body[f"pitch_inertia_{load}_kg_m2"]),
            carbody_roll_inertia_kg_m2=float(body[f"roll_inertia_{load}_kg_m2"]),
            half_bogie_distance_m=float(body["bogie_centre_distance_m"]) / 2.0,
            frame_mass_kg=m_f,
            frame_pitch_inertia_kg_m2=float(frame["pitch_inertia_kg_m2"]),
            frame_roll_inertia_kg_m2=float(frame["roll_inertia_kg_m2"]),
            half_wheelbase_m=float(frame["wheelbase_m"]) / 2.0,
            half_box_spacing_m=float(frame["axle_box_spacing_m"]) / 2.0,
            wheelset_mass_kg=m_w,
            wheelset_roll_inertia_kg_m2=float(ws["roll_inertia_kg_m2"]),
            half_contact_spacing_m=float(ws["contact_spacing_m"]) / 2.0,
            wheel_radius_m=radius,
            contact_stiffness_n_per_m=k_contact,
            contact_damping_n_s_per_m=float(contact["damping_n_s_per_m"]),
            track_mass_kg=float(track["mass_kg"]),
            track_stiffness_n_per_m=float(track["stiffness_n_per_m"]),
            track_damping_n_s_per_m=float(track["damping_n_s_per_m"]),
            outer_coil_n_per_m=k_o,
            inner_coil_n_per_m=k_i,
            inner_clearance_m=clearance,
            primary_damping_n_s_per_m=float(prim["structural_damping_n_s_per_m"]),
            mu_static=mu_s,
            link_ratio=link_ratio,
            kinetic_to_static=float(lenoir["kinetic_to_static"]),
            stribeck_velocity_mps=float(lenoir["stribeck_velocity_mps"]),
            presliding_m=float(lenoir["presliding_displacement_m"]),
            bowl_stiffness_n_per_m=float(bowl["stiffness_n_per_m"]),
            bowl_damping_n_s_per_m=float(bowl["damping_n_s_per_m"]),
            bowl_friction_coefficient=float(bowl["friction_coefficient"]),
            bowl_friction_radius_m=float(bowl["friction_radius_m"]),
            bowl_presliding_rad=float(bowl["presliding_angle_rad"]),
            bowl_kinetic_to_static=float(bowl["kinetic_to_static"]),
            bowl_stribeck_radps=float(bowl["stribeck_rate_radps"]),
            half_bearer_spacing_m=float(sb["lateral_spacing_m"]) / 2.0,
            bearer_clearance_m=float(sb["clearance_m"]),
            bearer_stiffness_n_per_m=float(sb["stiffness_n_per_m"]),
            bearer_damping_n_s_per_m=float(sb["damping_n_s_per_m"]),
            sensor=sensor,
            # Not in the shipped file: the wagon's ends loaded alike.
            carbody_centre_offset_m=float(body.get("centre_of_mass_offset_m", 0.0)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, SimulationError):
            raise
        raise SimulationError(f"model B parameter set is incomplete or malformed: {exc!r}") from None
    _check(params)
    return params


def _check(p: WagonParameters) -> None:
    positive = {
        "carbody mass": p.carbody_mass_kg, "frame mass": p.frame_mass_kg, "wheelset mass": p.wheelset_mass_kg,
        "track mass": p.track_mass_kg, "outer coil stiffness": p.outer_coil_n_per_m,
        "pre-sliding displacement": p.presliding_m, "bowl pre-sliding angle": p.bowl_presliding_rad,
        "Stribeck velocity": p.stribeck_velocity_mps, "bowl Stribeck rate": p.bowl_stribeck_radps,
    }  # fmt: skip
    for name, value in positive.items():
        if not (math.isfinite(value) and value > 0):
            raise SimulationError(f"model B parameter {name} must be positive, got {value}")
    for name, ratio in (("kinetic_to_static", p.kinetic_to_static), ("bowl kinetic_to_static", p.bowl_kinetic_to_static)):
        if not 0.0 < ratio <= 1.0:
            raise SimulationError(f"model B parameter {name} must lie in (0, 1], got {ratio}")
    s = p.sensor
    if s.bits < 0 or s.bits == 1 or s.bits > 32 or (s.bits and not s.range_g > 0):
        raise SimulationError(f"model B sensor: bits must be 0 (no converter) or 2..32 with range_g > 0, got {s.bits}, {s.range_g}")
    if any(t < 0 for t in s.skew_s):
        raise SimulationError(f"model B sensor: skew_s must be >= 0 s (relative sample instants), got {s.skew_s}")
    if not all(math.isfinite(d) and d >= 0 for d in s.element_noise_density_mps2_per_sqrt_hz):
        raise SimulationError(f"model B sensor: element_noise_density_mps2_per_sqrt_hz must be >= 0, got {s.element_noise_density_mps2_per_sqrt_hz}")
    if not 1 <= s.antialias_order <= MAX_ANTIALIAS_ORDER:
        raise SimulationError(f"model B sensor: antialias_order must lie in 1..{MAX_ANTIALIAS_ORDER}, got {s.antialias_order}")
    if not 0.0 < s.antialias_fraction_of_fs < 0.5:
        raise SimulationError(f"model B sensor: antialias_fraction_of_fs must lie in (0, 0.5), got {s.antialias_fraction_of_fs}")


def check_step(params: WagonParameters, step_s: float) -> None:
    """SimulationError unless model B's kernel is valid at this integration step.

    The sensor's resonance must lie below 0.45 x the step rate (it is a digital filter at that
    rate), its skew within the kernel's delay line, and the stiffest mode (the wheel on its
    Hertzian contact) inside the explicit step's accuracy (omega dt <= 1.2).
    """
    rate_hz = 1.0 / step_s
    if params.sensor.resonance_hz and params.sensor.resonance_hz >= 0.45 * rate_hz:
        raise SimulationError(
            f"model b: the sensor resonance at {params.sensor.resonance_hz:g} Hz needs an integration step below "
            f"{0.45 / params.sensor.resonance_hz:.3g} s (--max-step-s), got {step_s:.3g} s"
        )
    if max(params.sensor.skew_s) > MAX_SKEW_STEPS * step_s:
        raise SimulationError(
            f"model b: a sensor skew of {max(params.sensor.skew_s):g} s exceeds {MAX_SKEW_STEPS} integration steps "
            f"of {step_s:.3g} s: use a longer step or a smaller skew"
        )
    k = params.contact_stiffness_n_per_m + params.track_stiffness_n_per_m
    omega = math.sqrt(k / params.track_mass_kg + params.contact_stiffness_n_per_m / (0.5 * params.wheelset_mass_kg))
    if omega * step_s > 1.2:
        raise SimulationError(
            f"model b: an integration step of {step_s:.3g} s is too long for the wheel-rail contact "
            f"(omega {omega:.0f} rad/s): use --max-step-s {1.2 / omega:.2g} or less"
        )
