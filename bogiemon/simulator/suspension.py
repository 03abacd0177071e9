"""The primary suspension of one axle box, and the faults of the paper's tables that change it.

One corner is a two-stage coil-spring nest in parallel with a Lenoir dry-friction damper and a
small viscous term:

    F = k_outer * max(u, 0) + k_inner * max(u - clearance, 0) + F_friction + c * du/dt

with u the nest's compression from the free length of the outer coils (m, positive when the axle
box moves up relative to the frame) and F the upward force on the frame (N). k_outer is the sum
of the front and rear outer coils, k_inner of the two inner coils, which touch only beyond the
clearance: in tare they carry nothing, at full load all four coils work (Kz = 2.56e6 N/m).

The friction element is elasto-plastic (a Jenkins element: a stick spring k_stick in series with
a Coulomb slider of threshold Fs). Its state is the slider position s; with trial force
k_stick (u - s), the element sticks while |trial| <= Fs and otherwise slides, the slider moving
just enough that |F_friction| = Fs (a return mapping, as in plasticity). Why this element:
  - stick-slip transitions need no event detection and no sign(velocity): the force is a
    continuous, bounded function of the displacement history, so a fixed explicit time step never
    chatters at velocity reversals, where the classical sign(v) or tanh(v / v0) models either
    chatter or need tiny steps and leak (creep) under static load;
  - sticking is true sticking (no drift under a constant load below Fs), and the force-
    displacement loop under a slow stroke is the ideal parallelogram of width 2 Fs;
  - k_stick is physical: the elastic compliance of the friction shoe, link and guides in series.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.detection.kinematics import Corner
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.params import VehicleParameters

SPRING_POSITIONS = ("front_outer", "front_inner", "rear_outer", "rear_inner")
FAULT_KINDS = ("type_a", "type_b", "custom")
BOGIES = ("leading", "trailing")
# A fault spec names the bogie by its number ('@2:leading-left'): 1 the leading bogie in the
# direction of travel, 2 the other (the recording's a1..a3 and b1..b3); the older names stay aliases.
BOGIE_PREFIXES = {"1": "leading", "2": "trailing", "leading-bogie": "leading", "trailing-bogie": "trailing"}
# Corner order within a bogie everywhere in the simulator (the kernel's arrays follow it).
CORNER_ORDER: tuple[Corner, Corner, Corner, Corner] = (
    Corner.LEADING_LEFT,
    Corner.LEADING_RIGHT,
    Corner.TRAILING_LEFT,
    Corner.TRAILING_RIGHT,
)
# Severity 1.0 is the healthy spring or damper: accepted everywhere, changes nothing.
HEALTHY_SEVERITY = 1.0


@dataclass(frozen=True)
class CornerSuspension:
    """The primary suspension of one axle box. Stiffnesses in N/m, forces in N."""

    front_outer_n_per_m: float
    rear_outer_n_per_m: float
    front_inner_n_per_m: float
    rear_inner_n_per_m: float
    inner_clearance_m: float
    fs_n: float  # Fs, the friction element's sliding threshold
    stick_stiffness_n_per_m: float
    damping_n_s_per_m: float

    @property
    def outer_n_per_m(self) -> float:
        return self.front_outer_n_per_m + self.rear_outer_n_per_m

    @property
    def inner_n_per_m(self) -> float:
        return self.front_inner_n_per_m + self.rear_inner_n_per_m

    def spring_force_n(self, compression_m: NDArray[np.float64] | float) -> NDArray[np.float64]:
        """Force of the coil nest (no friction, no damping) at a compression from free length."""
        u = np.asarray(compression_m, dtype=np.float64)
        return self.outer_n_per_m * np.maximum(u, 0.0) + self.inner_n_per_m * np.maximum(u - self.inner_clearance_m, 0.0)

    def tangent_stiffness_n_per_m(self, compression_m: float) -> float:
        """Kz at a compression: the paper's corner stiffness at the load that causes it."""
        k = self.outer_n_per_m if compression_m >= 0.0 else 0.0
        return k + (self.inner_n_per_m if compression_m > self.inner_clearance_m else 0.0)

    def as_row(self) -> list[float]:
        """The kernel's per-corner parameters: k_outer, k_inner, clearance, Fs, k_stick, c."""
        return [
            self.outer_n_per_m,
            self.inner_n_per_m,
            self.inner_clearance_m,
            self.fs_n,
            self.stick_stiffness_n_per_m,
            self.damping_n_s_per_m,
        ]


def friction_step(compression_m: float, slider_m: float, stick_n_per_m: float, fs_n: float) -> tuple[float, float]:
    """One return-mapping update of the elasto-plastic friction element: (force N, new slider m).

    Reference form, one corner at a time; the kernel inlines the same three lines.
    """
    trial_n = stick_n_per_m * (compression_m - slider_m)
    if trial_n > fs_n:
        return fs_n, compression_m - fs_n / stick_n_per_m
    if trial_n < -fs_n:
        return -fs_n, compression_m + fs_n / stick_n_per_m
    return trial_n, slider_m


@dataclass(frozen=True)
class Fault:
    """A changed primary suspension at one corner of one bogie.

    kind 'type_a': one coil (position front/rear x outer/inner) at `severity` x its nominal
    stiffness, with the paper's Fs for that case; 'type_b': the damper's Fs of the paper's Table 3
    for `severity`; 'custom': the corner's Kz (its tangent stiffness at the run's load, reached by
    scaling all four coils) and Fs given directly.
    """

    kind: str
    corner: Corner
    bogie: str = "leading"
    position: str | None = None
    severity: float | None = None
    kz_n_per_m: float | None = None  # Kz, custom only
    fs_n: float | None = None  # Fs, custom only

    def __post_init__(self) -> None:
        if self.kind not in FAULT_KINDS:
            raise SimulationError(f"unknown fault kind '{self.kind}': use type_a, type_b or custom")
        if self.bogie not in BOGIES:
            raise SimulationError(f"unknown bogie '{self.bogie}': use 'leading' or 'trailing'")
        if self.kind == "type_a":
            if self.position not in SPRING_POSITIONS:
                raise SimulationError(
                    f"type_a needs a spring position, one of {', '.join(SPRING_POSITIONS)}; got '{self.position or ''}'"
                )
            _check_severity(self.severity, "type_a")
        elif self.kind == "type_b":
            if self.position:
                raise SimulationError(
                    f"type_b changes the friction damper only: leave the position empty (type_b::{self.severity})"
                )
            _check_severity(self.severity, "type_b")
        else:
            kz, fs = self.kz_n_per_m, self.fs_n
            if kz is None or fs is None or not (math.isfinite(kz) and math.isfinite(fs)) or kz <= 0 or fs < 0:
                raise SimulationError(f"custom needs Kz > 0 N/m and Fs >= 0 N, got Kz={kz}, Fs={fs}")

    @property
    def where(self) -> str:
        """The fault's corner: 'leading-left' on bogie 1 (the leading one), '2:leading-left' on bogie 2."""
        return self.corner.value if self.bogie == "leading" else f"2:{self.corner.value}"

    @property
    def bogie_number(self) -> int:
        """1: the leading bogie in the direction of travel (a1..a3), 2: the other (b1..b3)."""
        return BOGIES.index(self.bogie) + 1

    def spec(self) -> str:
        """The fault in the command line's syntax, e.g. 'type_a:rear_outer:0.0@leading-left'."""
        if self.kind == "custom":
            return f"custom:{self.kz_n_per_m!r}:{self.fs_n!r}@{self.where}"
        return f"{self.kind}:{self.position or ''}:{self.severity!r}@{self.where}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "kind": self.kind,
            "bogie": self.bogie,
            "corner": self.corner.value,
            "position": self.position,
            "severity": self.severity,
            "kz_n_per_m": self.kz_n_per_m,
            "fs_n": self.fs_n,
            "spec": self.spec(),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Fault:
        return cls(
            kind=data["kind"],
            corner=Corner(data["corner"]),
            bogie=data["bogie"],
            position=data.get("position"),
            severity=data.get("severity"),
            kz_n_per_m=data.get("kz_n_per_m"),
            fs_n=data.get("fs_n"),
        )


def _check_severity(severity: float | None, kind: str) -> None:
    if severity is None or not math.isfinite(severity) or severity < 0:
        raise SimulationError(f"{kind} needs a severity >= 0 (a fraction of the nominal), got {severity}")


def _number(text: str, what: str, spec: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise SimulationError(f"fault '{spec}': {what} is not a number: '{text}'") from None
    if not math.isfinite(value):
        raise SimulationError(f"fault '{spec}': {what} must be finite, got '{text}'")
    return value


def parse_fault(spec: str) -> Fault:
    """Parse KIND:POSITION:SEVERITY@CORNER (or custom:KZ_N_PER_M:FS_N@CORNER).

    CORNER is a corner of bogie 1, the leading one in the direction of travel (leading-left, ...,
    trailing-right), or 2:CORNER for the wagon's other bogie, at the same named corner of its own
    frame (1:CORNER is the default; trailing-bogie: and leading-bogie: are the older names).
    """
    text = spec.strip()
    if text.count("@") != 1:
        raise SimulationError(
            f"fault '{spec}': expected KIND:POSITION:SEVERITY@CORNER, e.g. type_a:rear_outer:0.0@leading-left"
        )
    what, where = text.split("@")
    bogie = "leading"
    if ":" in where:
        bogie_name, where = where.split(":", 1)
        bogie = BOGIE_PREFIXES.get(bogie_name, "")
        if not bogie:
            raise SimulationError(f"fault '{spec}': unknown bogie '{bogie_name}': use 1 or 2 (e.g. @2:leading-left)")
    try:
        corner = Corner(where)
    except ValueError:
        names = ", ".join(c.value for c in Corner)
        raise SimulationError(f"fault '{spec}': unknown corner '{where}': use one of {names}") from None
    fields = what.split(":")
    if len(fields) != 3:
        raise SimulationError(
            f"fault '{spec}': expected three ':'-separated fields before '@' "
            "(type_a:POSITION:SEVERITY, type_b::SEVERITY or custom:KZ_N_PER_M:FS_N)"
        )
    kind = fields[0]
    if kind == "custom":
        kz = _number(fields[1], "Kz (N/m)", spec)
        fs = _number(fields[2], "Fs (N)", spec)
        return Fault(kind=kind, corner=corner, bogie=bogie, kz_n_per_m=kz, fs_n=fs)
    severity = _number(fields[2], "the severity", spec)
    return Fault(kind=kind, corner=corner, bogie=bogie, position=fields[1] or None, severity=severity)


def _table_entry(table: dict[str, Any], severity: float, kind: str, where: str) -> Any:
    for key, value in table.items():
        try:
            if float(key) == severity:
                return value
        except ValueError:
            continue  # e.g. nominal_Fs
    known = sorted(float(k) for k in table if k.replace(".", "", 1).isdigit())
    raise SimulationError(
        f"{kind} severity {severity} is not a case of the paper's {where}: use one of "
        f"{', '.join(map(str, known + [HEALTHY_SEVERITY]))}, or custom:KZ_N_PER_M:FS_N for any other value"
    )


def healthy_corner(params: VehicleParameters) -> CornerSuspension:
    return CornerSuspension(
        front_outer_n_per_m=params.outer_coil_stiffness_n_per_m,
        rear_outer_n_per_m=params.outer_coil_stiffness_n_per_m,
        front_inner_n_per_m=params.inner_coil_stiffness_n_per_m,
        rear_inner_n_per_m=params.inner_coil_stiffness_n_per_m,
        inner_clearance_m=params.inner_clearance_m,
        fs_n=params.healthy_fs_n,
        stick_stiffness_n_per_m=params.stick_stiffness_n_per_m,
        damping_n_s_per_m=params.structural_damping_n_s_per_m,
    )


def faulty_corner(params: VehicleParameters, fault_cases: dict[str, Any], fault: Fault) -> CornerSuspension:
    """The corner's suspension under one fault, for the load of `params`."""
    healthy = healthy_corner(params)
    load = params.load
    if fault.kind == "custom":
        assert fault.kz_n_per_m is not None and fault.fs_n is not None
        scale = fault.kz_n_per_m / params.healthy_kz_n_per_m
        return CornerSuspension(
            front_outer_n_per_m=healthy.front_outer_n_per_m * scale,
            rear_outer_n_per_m=healthy.rear_outer_n_per_m * scale,
            front_inner_n_per_m=healthy.front_inner_n_per_m * scale,
            rear_inner_n_per_m=healthy.rear_inner_n_per_m * scale,
            inner_clearance_m=healthy.inner_clearance_m,
            fs_n=fault.fs_n,
            stick_stiffness_n_per_m=healthy.stick_stiffness_n_per_m,
            damping_n_s_per_m=healthy.damping_n_s_per_m,
        )
    assert fault.severity is not None
    if fault.severity == HEALTHY_SEVERITY:
        return healthy
    if fault.kind == "type_b":
        # Table 3's published absolute values (see docs/simulator.md on its 22.33 kN nominal).
        fs = float(_table_entry(fault_cases["type_b"][load], fault.severity, "type_b", f"Table 3 ({load})"))
        return CornerSuspension(**{**healthy.__dict__, "fs_n": fs})
    assert fault.position is not None
    coils = {
        "front_outer": healthy.front_outer_n_per_m,
        "rear_outer": healthy.rear_outer_n_per_m,
        "front_inner": healthy.front_inner_n_per_m,
        "rear_inner": healthy.rear_inner_n_per_m,
    }
    table = fault_cases["type_a"][load].get(fault.position)
    if table is None:
        # Tare and an inner coil: it does not touch the frame in tare (the paper's Table 2 lists
        # outer coils only), so the Lenoir link's load, and Fs, are the healthy ones.
        _table_entry({"0.0": 0, "0.5": 0, "1.5": 0, "2.0": 0}, fault.severity, "type_a", "Table 1 and 2")
        fs = healthy.fs_n
    else:
        fs = float(_table_entry(table, fault.severity, "type_a", f"Table {1 if load == 'full' else 2}")[1])
    coils[fault.position] *= fault.severity
    return CornerSuspension(
        front_outer_n_per_m=coils["front_outer"],
        rear_outer_n_per_m=coils["rear_outer"],
        front_inner_n_per_m=coils["front_inner"],
        rear_inner_n_per_m=coils["rear_inner"],
        inner_clearance_m=healthy.inner_clearance_m,
        fs_n=fs,
        stick_stiffness_n_per_m=healthy.stick_stiffness_n_per_m,
        damping_n_s_per_m=healthy.damping_n_s_per_m,
    )


def corner_suspensions(
    params: VehicleParameters, fault_cases: dict[str, Any], faults: tuple[Fault, ...]
) -> tuple[CornerSuspension, ...]:
    """The 8 corners: leading bogie then trailing bogie, each in CORNER_ORDER."""
    corners = [healthy_corner(params)] * 8
    seen: set[tuple[str, Corner]] = set()
    for fault in faults:
        key = (fault.bogie, fault.corner)
        if key in seen:
            raise SimulationError(f"two faults at {fault.where}: give at most one fault per corner (custom for a combination)")
        seen.add(key)
        corners[BOGIES.index(fault.bogie) * 4 + CORNER_ORDER.index(fault.corner)] = faulty_corner(params, fault_cases, fault)
    return tuple(corners)
