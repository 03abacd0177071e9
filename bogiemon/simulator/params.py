"""The wagon's parameters: the shipped TOML files (config/y25_wagon.toml and the paper's fault tables).

A parameter set is kept as the plain dict parsed from the files (`ParameterSet.data`), so that a
scenario's JSON sidecar carries every number it was simulated with; `vehicle_parameters()` turns
it into typed values for one load case.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from typing import Any, Literal

from bogiemon.simulator.errors import SimulationError

Load = Literal["full", "tare"]
LOADS: tuple[Load, ...] = ("full", "tare")
DEFAULT_VEHICLE_FILE = "y25_wagon.toml"


def _read_shipped(name: str) -> dict[str, Any]:
    try:
        text = resources.files("bogiemon.config").joinpath(name).read_text(encoding="utf-8")
    except (OSError, ValueError):
        raise SimulationError(f"{name}: no such vehicle parameter file in bogiemon's config folder") from None
    return tomllib.loads(text)


def default_parameter_set() -> dict[str, Any]:
    """{'vehicle': <y25_wagon.toml>, 'fault_cases': <y25_fault_cases.toml>} as parsed dicts."""
    vehicle = _read_shipped(DEFAULT_VEHICLE_FILE)
    return {"vehicle": vehicle, "fault_cases": _read_shipped(vehicle["fault_cases"])}


@dataclass(frozen=True)
class VehicleParameters:
    """Everything the equations of motion need for one load case. SI units."""

    load: Load
    gravity_mps2: float
    carbody_mass_kg: float
    carbody_pitch_inertia_kg_m2: float
    carbody_roll_inertia_kg_m2: float
    bogie_centre_distance_m: float
    frame_mass_kg: float
    frame_pitch_inertia_kg_m2: float
    frame_roll_inertia_kg_m2: float
    wheelbase_m: float
    axle_box_spacing_m: float
    wheelset_mass_kg: float
    contact_spacing_m: float
    outer_coil_stiffness_n_per_m: float
    inner_coil_stiffness_n_per_m: float
    inner_clearance_m: float
    stick_stiffness_n_per_m: float
    structural_damping_n_s_per_m: float
    bowl_stiffness_n_per_m: float
    bowl_damping_n_s_per_m: float
    side_bearer_spacing_m: float
    side_bearer_stiffness_n_per_m: float
    side_bearer_damping_n_s_per_m: float
    healthy_kz_n_per_m: float  # the paper's healthy corner stiffness for this load
    healthy_fs_n: float  # the paper's healthy sliding force for this load
    # The carbody's centre of mass this far from mid-way between the bogie centres, towards the
    # leading bogie (a wagon whose ends are loaded unequally); its inertias are about that point.
    carbody_centre_offset_m: float = 0.0

    @property
    def bogie_centres_x_m(self) -> tuple[float, float]:
        """The leading and the trailing bogie centre's x from the carbody's centre of mass."""
        a = self.bogie_centre_distance_m / 2
        return (a - self.carbody_centre_offset_m, -a - self.carbody_centre_offset_m)

    @property
    def sprung_mass_kg(self) -> float:
        """Mass on the primary springs: carbody and both bogie frames."""
        return self.carbody_mass_kg + 2.0 * self.frame_mass_kg

    @property
    def axle_offsets_m(self) -> tuple[float, float, float, float]:
        """Distance of each axle behind the wagon's first axle: axles 1, 2 (leading bogie), 3, 4."""
        wb, bc = self.wheelbase_m, self.bogie_centre_distance_m
        return (0.0, wb, bc, bc + wb)


def centre_offset_m(leading_share: float, bogie_centre_distance_m: float) -> float:
    """The carbody's centre-of-mass offset (towards the leading bogie) that puts `leading_share` of
    its weight on the leading bogie: moments about it, share = (a + e) / 2a with a half the distance."""
    if not 0.0 < leading_share < 1.0:
        raise SimulationError(f"a bogie's share of the carbody's weight lies between 0 and 1, got {leading_share:g}")
    return (2.0 * leading_share - 1.0) * bogie_centre_distance_m / 2.0


def vehicle_parameters(parameter_set: dict[str, Any], load: str) -> VehicleParameters:
    """Typed parameters for `load` ('full' or 'tare') from a parameter set."""
    if load not in LOADS:
        raise SimulationError(f"unknown load '{load}': use 'full' or 'tare'")
    try:
        v, cases = parameter_set["vehicle"], parameter_set["fault_cases"]
        body, frame, ws, prim = v["carbody"], v["bogie_frame"], v["wheelset"], v["primary"]
        bowl, sb = v["centre_bowl"], v["side_bearers"]
        return VehicleParameters(
            load=load,
            gravity_mps2=float(v["gravity_mps2"]),
            carbody_mass_kg=float(cases["wagon"][f"carbody_mass_{load}_kg"]),
            carbody_pitch_inertia_kg_m2=float(body[f"pitch_inertia_{load}_kg_m2"]),
            carbody_roll_inertia_kg_m2=float(body[f"roll_inertia_{load}_kg_m2"]),
            bogie_centre_distance_m=float(body["bogie_centre_distance_m"]),
            frame_mass_kg=float(frame["mass_kg"]),
            frame_pitch_inertia_kg_m2=float(frame["pitch_inertia_kg_m2"]),
            frame_roll_inertia_kg_m2=float(frame["roll_inertia_kg_m2"]),
            wheelbase_m=float(frame["wheelbase_m"]),
            axle_box_spacing_m=float(frame["axle_box_spacing_m"]),
            wheelset_mass_kg=float(ws["mass_kg"]),
            contact_spacing_m=float(ws["contact_spacing_m"]),
            outer_coil_stiffness_n_per_m=float(prim["outer_coil_stiffness_n_per_m"]),
            inner_coil_stiffness_n_per_m=float(prim["inner_coil_stiffness_n_per_m"]),
            inner_clearance_m=float(prim["inner_clearance_m"]),
            stick_stiffness_n_per_m=float(prim["stick_stiffness_n_per_m"]),
            structural_damping_n_s_per_m=float(prim["structural_damping_n_s_per_m"]),
            bowl_stiffness_n_per_m=float(bowl["stiffness_n_per_m"]),
            bowl_damping_n_s_per_m=float(bowl["damping_n_s_per_m"]),
            side_bearer_spacing_m=float(sb["lateral_spacing_m"]),
            side_bearer_stiffness_n_per_m=float(sb["stiffness_n_per_m"]),
            side_bearer_damping_n_s_per_m=float(sb["damping_n_s_per_m"]),
            healthy_kz_n_per_m=float(cases["healthy"][load]["Kz"]),
            healthy_fs_n=float(cases["healthy"][load]["Fs"]),
            # Not in the shipped file: the wagon's ends loaded alike.
            carbody_centre_offset_m=float(body.get("centre_of_mass_offset_m", 0.0)),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise SimulationError(f"vehicle parameter set is incomplete or malformed: {exc!r}") from None
