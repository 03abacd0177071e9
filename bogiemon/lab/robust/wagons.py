"""The robustness evaluation's wagons: a varied fleet drawn on either wagon model.

THE FLEET. Each wagon is drawn from its own seed: masses and inertias of carbody and bogie frames
+/-10 %, the coil springs +/-5 % (the wagon's batch) and each corner's nest another +/-5 %, the
friction dampers' Fs +/-10 % per wagon (every Fs of the paper's tables, so a fault keeps its
meaning relative to the wagon's healthy damper) and +/-10 % per corner, the dampers' stick
stiffness and the side bearers' stiffness +/-10 % and +/-20 %; and its three sensors: gain
+/-3 %, bias +/-0.3 m/s^2, white noise 0.005 to 0.03 m/s^2 per sample, 16-bit quantisation over
+/-16 g. All uniform. A corner's own tolerance is put on as the simulator's `custom` fault of that
corner (its tangent stiffness and Fs), so a healthy wagon is never exactly symmetric.
The plan's wagon MODEL ("a", simulator/vehicle.py; or "b", simulator/model_b, built independently)
takes the same draws on its own parameter set (WAGON_KEYS says which key each spread scales), so
wagon i of a fleet differs from the nominal alike on both models; on model B the sensor errors go
into its own [sensor] section (gain, bias, noise density) instead of model A's SensorModel.
BOGIE 2's three sensors (runs that record both bogies, lab/sister) are other parts, drawn alike
from a stream of the wagon's seed of their own (so every draw above stays what it was); on model B
also their cross-axis sensitivity and sample instants (simulator/model_b/sensors.py other_part's
tolerances), so that each physical bogie keeps its parts whichever way the wagon runs.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bogiemon.detection import Corner
from bogiemon.simulator.model_b import parameters as model_b_parameters
from bogiemon.simulator.params import default_parameter_set
from bogiemon.simulator.sensors import SensorModel
from bogiemon.simulator.suspension import CORNER_ORDER, Fault

# Spread of a wagon (half-widths of uniform distributions, relative).
MASS_SPREAD = 0.10
COIL_BATCH_SPREAD = 0.05
COIL_CORNER_SPREAD = 0.05
FRICTION_WAGON_SPREAD = 0.10
FRICTION_CORNER_SPREAD = 0.10
STICK_SPREAD = 0.10
SIDE_BEARER_SPREAD = 0.20
SENSOR_GAIN_SPREAD = 0.03
SENSOR_BIAS_MPS2 = 0.3
SENSOR_NOISE_RANGE_MPS2 = (0.005, 0.03)
SENSOR_QUANTUM_MPS2 = 2 * 16 * 9.80665 / 65536  # 16 bits over +/-16 g



@dataclass(frozen=True)
class Wagon:
    """One simulated wagon: its parameter set, its corners' tolerances and its sensors."""

    name: str
    seed: int
    parameters: dict[str, Any] = field(repr=False)  # the model's own parameter set
    corner_kz_scale: tuple[float, ...]  # 8 corners: leading bogie then trailing, CORNER_ORDER
    corner_fs_scale: tuple[float, ...]
    # Model A: the sensors' errors as the simulator applies them. Model B: the same draws, which
    # live in its parameter set's [sensor]; the scenario's SensorModel is then the exact one.
    sensor: SensorModel
    spread: dict[str, float]  # the drawn wagon-level factors, for the report
    model: str = "a"  # the simulator's wagon model (Scenario.model)
    # Bogie 2's sensors (module docstring): model A's SensorModel; model B's [sensor] values of them.
    sensor_bogie_2: SensorModel = field(default_factory=SensorModel)
    part_bogie_2: dict[str, Any] = field(default_factory=dict, repr=False)

    def tolerance_fault(self, physical: Corner, bogie: str, config_corner: Corner, load: str) -> Fault:
        """The healthy corner with its tolerances, as the simulator's custom fault at `physical`.

        The tolerances belong to the corner of the frame (named in the config's reference
        direction), wherever the direction of travel puts it.
        """
        k = (0 if bogie == "leading" else 4) + CORNER_ORDER.index(config_corner)
        kz_n_per_m, fs_n = self.healthy_corner(load)
        return Fault(kind="custom", corner=physical, bogie=bogie, kz_n_per_m=kz_n_per_m * self.corner_kz_scale[k], fs_n=fs_n * self.corner_fs_scale[k])

    def healthy_corner(self, load: str) -> tuple[float, float]:
        """(Kz N/m, Fs N) of this wagon's nominal corner at the load, in its model's own terms."""
        if self.model == "b":
            from bogiemon.simulator.model_b.bodies import nominal_corner_values  # model B's statics, when used

            return nominal_corner_values(model_b_parameters.wagon_parameters(self.parameters, load))
        cases = self.parameters["fault_cases"]["healthy"][load]
        return float(cases["Kz"]), float(cases["Fs"])

    def bogie_sensors(self, leading: int) -> tuple[SensorModel, SensorModel | None, dict[str, Any]]:
        """(sensor, sensor_bogie_2, parameters) of a two-bogie scenario whose leading bogie in the
        direction of travel is this wagon's bogie `leading` (1 or 2): each physical bogie reads
        through its own parts whichever way the wagon runs."""
        if self.model == "a":
            first, second = (self.sensor, self.sensor_bogie_2) if leading == 1 else (self.sensor_bogie_2, self.sensor)
            return first, second, self.parameters
        params = copy.deepcopy(self.parameters)
        own = params["vehicle"]["sensor"]
        part_1 = {key: own[key] for key in self.part_bogie_2}
        first_part, second_part = (part_1, self.part_bogie_2) if leading == 1 else (self.part_bogie_2, part_1)
        own.update(copy.deepcopy(first_part))
        params["vehicle"]["sensor_bogie_2"] = copy.deepcopy(second_part)
        return SensorModel(), None, params

    @property
    def scenario_sensor(self) -> SensorModel:
        """The SensorModel a scenario of this wagon gets (model B's errors are in its parameters)."""
        return self.sensor if self.model == "a" else SensorModel()


def _scale_fs(cases: dict[str, Any], factor: float) -> None:
    """Every Fs of the paper's tables times factor (the Lenoir link scales them all alike)."""
    for load in ("full", "tare"):
        cases["healthy"][load]["Fs"] = float(cases["healthy"][load]["Fs"]) * factor
        for position in cases["type_a"][load].values():
            for entry in position.values():
                entry[1] = float(entry[1]) * factor
        for key, value in cases["type_b"][load].items():
            if key != "nominal_Fs":
                cases["type_b"][load][key] = float(value) * factor


# The wagon-level spreads, in the order they are drawn (the order fixes every wagon of a seed).
WAGON_SPREADS: tuple[tuple[str, float], ...] = (
    *((f"{what}_{load}", MASS_SPREAD) for load in ("full", "tare") for what in ("carbody_mass", "carbody_pitch_inertia", "carbody_roll_inertia")),
    ("frame_mass", MASS_SPREAD),
    ("frame_pitch_inertia", MASS_SPREAD),
    ("frame_roll_inertia", MASS_SPREAD),
    ("coils", COIL_BATCH_SPREAD),
    ("stick_stiffness", STICK_SPREAD),
    ("side_bearers", SIDE_BEARER_SPREAD),
    ("friction", FRICTION_WAGON_SPREAD),
)
# Which keys each spread scales, per model: (table path, key, inverse): the value times the factor,
# or divided by it where `inverse`. Model B has no stick stiffness of its own: its Lenoir shoe's contact
# stiffness is Fs / pre-sliding displacement, so a stiffer stick is a shorter pre-sliding stroke;
# its friction level is the healthy full-load Fs its link ratio is calibrated on (the tare Fs and
# every fault's follow from it through the physics).
WAGON_KEYS: dict[str, dict[str, tuple[tuple[tuple[str, ...], str, bool], ...]]] = {
    "a": {
        **{f"carbody_mass_{ld}": ((("fault_cases", "wagon"), f"carbody_mass_{ld}_kg", False),) for ld in ("full", "tare")},
        **{f"carbody_{ax}_inertia_{ld}": ((("vehicle", "carbody"), f"{ax}_inertia_{ld}_kg_m2", False),) for ld in ("full", "tare") for ax in ("pitch", "roll")},
        "frame_mass": ((("vehicle", "bogie_frame"), "mass_kg", False),),
        "frame_pitch_inertia": ((("vehicle", "bogie_frame"), "pitch_inertia_kg_m2", False),),
        "frame_roll_inertia": ((("vehicle", "bogie_frame"), "roll_inertia_kg_m2", False),),
        "coils": ((("vehicle", "primary"), "outer_coil_stiffness_n_per_m", False), (("vehicle", "primary"), "inner_coil_stiffness_n_per_m", False)),
        "stick_stiffness": ((("vehicle", "primary"), "stick_stiffness_n_per_m", False),),
        "side_bearers": ((("vehicle", "side_bearers"), "stiffness_n_per_m", False),),
        "friction": (),  # every Fs of the paper's tables: _scale_fs
    },
    "b": {
        **{f"carbody_mass_{ld}": ((("vehicle", "carbody"), f"mass_{ld}_kg", False),) for ld in ("full", "tare")},
        **{f"carbody_{ax}_inertia_{ld}": ((("vehicle", "carbody"), f"{ax}_inertia_{ld}_kg_m2", False),) for ld in ("full", "tare") for ax in ("pitch", "roll")},
        "frame_mass": ((("vehicle", "bogie_frame"), "mass_kg", False),),
        "frame_pitch_inertia": ((("vehicle", "bogie_frame"), "pitch_inertia_kg_m2", False),),
        "frame_roll_inertia": ((("vehicle", "bogie_frame"), "roll_inertia_kg_m2", False),),
        "coils": ((("vehicle", "primary"), "outer_coil_stiffness_n_per_m", False), (("vehicle", "primary"), "inner_coil_stiffness_n_per_m", False)),
        "stick_stiffness": ((("vehicle", "primary", "lenoir"), "presliding_displacement_m", True),),
        "side_bearers": ((("vehicle", "side_bearers"), "stiffness_n_per_m", False),),
        "friction": ((("vehicle", "primary", "lenoir"), "calibration_fs_full_n", False),),
    },
}
# Model B's sensor noise is a density shaped by its own anti-alias filter at this fraction of the
# output rate; the drawn per-sample RMS is turned into the density that gives it at NOMINAL_FS_HZ.
NOMINAL_FS_HZ = 500.0


def _table(params: dict[str, Any], path: tuple[str, ...]) -> dict[str, Any]:
    table = params
    for name in path:
        table = table[name]
    return table


def apply_spread(params: dict[str, Any], model: str, spread: Mapping[str, float]) -> None:
    """Scale a parameter set of `model` (in place) by the wagon-level factors (WAGON_KEYS)."""
    for name, f in spread.items():
        for path, key, inverse in WAGON_KEYS[model][name]:
            table = _table(params, path)
            table[key] = float(table[key]) / f if inverse else float(table[key]) * f
        if model == "a" and name == "friction":
            _scale_fs(params["fault_cases"], f)


def make_wagon(name: str, seed: int, model: str = "a") -> Wagon:
    """Draw one wagon of the fleet (module docstring) from its seed, on the wagon model's own
    parameter set; the draws do not depend on the model."""
    if model not in WAGON_KEYS:
        raise ValueError(f"unknown wagon model '{model}'")
    rng = np.random.default_rng(seed)

    def factor(half_width: float) -> float:
        return float(1.0 + rng.uniform(-half_width, half_width))

    spread = {name_: factor(width) for name_, width in WAGON_SPREADS}
    params = copy.deepcopy(default_parameter_set() if model == "a" else model_b_parameters.default_parameter_set())
    apply_spread(params, model, spread)
    kz = tuple(factor(COIL_CORNER_SPREAD) for _ in range(8))
    fs = tuple(factor(FRICTION_CORNER_SPREAD) for _ in range(8))
    sensor = SensorModel(
        noise_mps2=float(rng.uniform(*SENSOR_NOISE_RANGE_MPS2)),
        bias_mps2=tuple(float(b) for b in rng.uniform(-SENSOR_BIAS_MPS2, SENSOR_BIAS_MPS2, 3)),  # type: ignore[arg-type]
        quantum_mps2=SENSOR_QUANTUM_MPS2,
        gain=tuple(factor(SENSOR_GAIN_SPREAD) for _ in range(3)),  # type: ignore[arg-type]
    )
    if model == "b":
        own = params["vehicle"]["sensor"]
        own["gain"], own["bias_mps2"] = list(sensor.gain), list(sensor.bias_mps2)
        # White noise of the drawn RMS per sample once B's anti-alias filter has shaped it (16 bits
        # over +/-16 g there too: model B's shipped converter).
        band_hz = float(own["antialias_fraction_of_fs"]) * NOMINAL_FS_HZ
        own["noise_density_mps2_per_sqrt_hz"] = sensor.noise_mps2 / math.sqrt(band_hz)
    other = np.random.default_rng([seed, 2])  # bogie 2's parts: a stream apart
    sensor_2 = SensorModel(
        noise_mps2=float(other.uniform(*SENSOR_NOISE_RANGE_MPS2)),
        bias_mps2=tuple(float(b) for b in other.uniform(-SENSOR_BIAS_MPS2, SENSOR_BIAS_MPS2, 3)),  # type: ignore[arg-type]
        quantum_mps2=SENSOR_QUANTUM_MPS2,
        gain=tuple(float(1.0 + other.uniform(-SENSOR_GAIN_SPREAD, SENSOR_GAIN_SPREAD)) for _ in range(3)),  # type: ignore[arg-type]
    )
    part_2: dict[str, Any] = {}
    if model == "b":
        from bogiemon.simulator.model_b import sensors as model_b_sensors  # model B's part tolerances

        skew = other.uniform(0.0, model_b_sensors.OTHER_PART_SKEW_S, 3)
        part_2 = {
            "gain": list(sensor_2.gain),
            "bias_mps2": list(sensor_2.bias_mps2),
            "noise_density_mps2_per_sqrt_hz": sensor_2.noise_mps2 / math.sqrt(band_hz),
            "cross_axis": [float(c) for c in other.uniform(-model_b_sensors.OTHER_PART_CROSS_AXIS, model_b_sensors.OTHER_PART_CROSS_AXIS, 3)],
            "skew_s": [0.0, float(skew[1]), float(skew[2])],
        }
    return Wagon(name, seed, params, kz, fs, sensor, spread, model, sensor_2, part_2)
