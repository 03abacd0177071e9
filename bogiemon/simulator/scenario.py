"""A scenario: everything that defines one simulated run, and its JSON sidecar.

A scenario is complete: the wagon model ("a" or "b"), the load, the speed profile, the track and
its seed, the faults, the sensors (corners, spacing, sample rate, errors), the integration step and
every vehicle parameter, so that the sidecar written beside a recording reproduces it exactly.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bogiemon.detection.kinematics import BogieGeometry, Corner
from bogiemon.simulator.errors import SimulationError
from bogiemon.simulator.model_b import parameters as model_b_parameters
from bogiemon.simulator.params import LOADS, default_parameter_set
from bogiemon.simulator.sensors import SENSOR_VARIANTS, SensorModel
from bogiemon.simulator.suspension import Fault
from bogiemon.simulator.track import TRACKS

SIDECAR_FORMAT = "bogiemon-simulation/1"
MONITORED_BOGIE = "leading"  # the sensors sit on the wagon's leading bogie
MAX_SPEED_KMH = 200.0
# Bogies recorded: 1, the leading bogie in the direction of travel (a1..a3); 2, both (a1..a3 then
# b1..b3: bogie 2's sensors at the same named corners of its own frame, seen in the direction of travel).
BOGIE_COUNTS = (1, 2)
# The wagon models: "a" (simulator/vehicle.py, docs/simulator.md) and "b", built independently of it
# (simulator/model_b, docs/simulator-b.md) so that what is fitted on one can be judged on the other.
MODELS = ("a", "b")


@dataclass(frozen=True)
class SpeedProfile:
    """Speed over the recording's time: piecewise linear through (time_s, speed_kmh) points.

    Held constant before the first and after the last point; one point is a constant speed.
    """

    points: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        if not self.points:
            raise SimulationError("a speed profile needs at least one time_s:speed_kmh point")
        times = [t for t, _ in self.points]
        for t, v in self.points:
            if not (math.isfinite(t) and math.isfinite(v)):
                raise SimulationError(f"speed profile point {t}:{v} is not finite")
            if not 0.0 <= v <= MAX_SPEED_KMH:
                raise SimulationError(f"speed {v:g} km/h is outside 0..{MAX_SPEED_KMH:g} km/h")
        if any(b <= a for a, b in itertools.pairwise(times)):
            raise SimulationError(f"speed profile times must increase strictly, got {times}")
        if times[0] < 0:
            raise SimulationError(f"speed profile times start at 0 s or later, got {times[0]:g}")

    @classmethod
    def constant(cls, speed_kmh: float) -> SpeedProfile:
        return cls(((0.0, float(speed_kmh)),))

    @classmethod
    def parse(cls, text: str) -> SpeedProfile:
        """'0:60,120:100' -> 60 km/h at 0 s rising linearly to 100 km/h at 120 s."""
        points = []
        for item in text.split(","):
            parts = item.strip().split(":")
            try:
                if len(parts) != 2:
                    raise ValueError
                points.append((float(parts[0]), float(parts[1])))
            except ValueError:
                raise SimulationError(
                    f"speed profile '{text}': '{item.strip()}' is not time_s:speed_kmh (e.g. '0:60,120:100')"
                ) from None
        return cls(tuple(points))

    def spec(self) -> str:
        return ",".join(f"{t:g}:{v:g}" for t, v in self.points)

    def arrays_mps(self) -> tuple[np.ndarray, np.ndarray]:
        """(times_s, speeds_mps) for the kernel."""
        return np.array([t for t, _ in self.points]), np.array([v / 3.6 for _, v in self.points])

    def speed_mps(self, time_s: float) -> float:
        times, speeds = self.arrays_mps()
        return float(np.interp(time_s, times, speeds))

    def distance_m(self, duration_s: float) -> float:
        """Distance run from time 0 to duration_s (exact for the piecewise-linear speed)."""
        times, speeds = self.arrays_mps()
        grid = np.unique(np.concatenate([[0.0, duration_s], times[(times > 0) & (times < duration_s)]]))
        v = np.interp(grid, times, speeds)
        return float(np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(grid)))


def speed_table(profiles: list[SpeedProfile]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The kernels' packing of a batch's speed profiles: times (s) and speeds (m/s) per scenario,
    padded to the longest, with each one's number of points."""
    n_points = max(len(p.points) for p in profiles)
    speed_t = np.zeros((len(profiles), n_points))
    speed_v = np.zeros((len(profiles), n_points))
    n_speed = np.zeros(len(profiles), dtype=np.int64)
    for b, profile in enumerate(profiles):
        t, v = profile.arrays_mps()
        speed_t[b, : t.size], speed_v[b, : t.size], n_speed[b] = t, v, t.size
    return speed_t, speed_v, n_speed


def _geometry_dict(geometry: BogieGeometry) -> dict[str, Any]:
    return {
        "wheelbase_m": geometry.wheelbase_m,
        "sensor_spacing_m": geometry.sensor_spacing_m,
        "corners": [c.value for c in geometry.corners],
    }


@dataclass(frozen=True)
class Scenario:
    """One simulated run. Defaults: a healthy wagon at full load, 80 km/h on ERRI low-level track."""

    load: str = "full"
    speed: SpeedProfile = field(default_factory=lambda: SpeedProfile.constant(80.0))
    track: str = "erri-low"
    duration_s: float = 120.0
    seed: int = 0
    faults: tuple[Fault, ...] = ()
    # The faults appear at this time of the recording (a spring breaking under the running wagon);
    # before it the suspension is healthy. 0: faulty from the start.
    fault_onset_s: float = 0.0
    fs_hz: float = 500.0
    geometry: BogieGeometry = field(default_factory=BogieGeometry)
    sensor: SensorModel = field(default_factory=SensorModel)
    # Longest integration step; the step used is fs_hz / (whole number) at or below it.
    max_step_s: float = 2.5e-4
    # Every vehicle parameter ({'vehicle': ..., 'fault_cases': ...}); None: the shipped files.
    parameters: dict[str, Any] | None = field(default=None, compare=True, repr=False)
    # Corners that differ from the nominal from the start, before and after the fault onset: a
    # wagon's own tolerances (custom faults), on which the `faults` appear at fault_onset_s.
    standing_faults: tuple[Fault, ...] = ()
    # Which wagon model runs the scenario (MODELS); `parameters` must be that model's set.
    model: str = "a"
    # Bogies recorded (BOGIE_COUNTS): the result has 3 x bogies channels.
    bogies: int = 1
    # Model A: bogie 2's sensors, other parts than bogie 1's (None: errors like `sensor`'s, their
    # noise drawn apart). Model B draws bogie 2's parts itself (simulator/model_b/sensors.py other_part).
    sensor_bogie_2: SensorModel | None = None

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise SimulationError(f"unknown model '{self.model}': use 'a' or 'b' (docs/simulator-b.md)")
        if self.parameters is None:
            default = model_b_parameters.default_parameter_set() if self.model == "b" else default_parameter_set()
            object.__setattr__(self, "parameters", default)
        if model_b_parameters.is_parameter_set(self.parameters) != (self.model == "b"):
            given = "model B's" if self.model == "a" else "model A's"
            raise SimulationError(
                f"model {self.model} cannot run {given} parameter set: give the model's own "
                "(or none for the shipped one)"
            )
        object.__setattr__(self, "faults", tuple(self.faults))
        object.__setattr__(self, "standing_faults", tuple(self.standing_faults))
        if self.load not in LOADS:
            raise SimulationError(f"unknown load '{self.load}': use 'full' or 'tare'")
        if self.track not in TRACKS:
            raise SimulationError(f"unknown track '{self.track}': use one of {', '.join(TRACKS)}")
        if not (math.isfinite(self.duration_s) and self.duration_s > 0):
            raise SimulationError(f"duration must be positive, got {self.duration_s:g} s")
        if not (math.isfinite(self.fault_onset_s) and 0.0 <= self.fault_onset_s < self.duration_s):
            raise SimulationError(f"fault onset must lie in [0, duration) = [0, {self.duration_s:g}) s, got {self.fault_onset_s:g}")
        if self.fault_onset_s > 0.0 and not self.faults:
            raise SimulationError("a fault onset time needs a fault (--fault)")
        if not (math.isfinite(self.fs_hz) and self.fs_hz > 0):
            raise SimulationError(f"sample rate must be positive, got {self.fs_hz:g} Hz")
        if self.n_samples < 2:
            raise SimulationError(f"{self.duration_s:g} s at {self.fs_hz:g} Hz is fewer than 2 samples: run longer")
        if not (math.isfinite(self.max_step_s) and 0 < self.max_step_s <= 0.002):
            raise SimulationError(f"integration step must lie in (0, 0.002] s, got {self.max_step_s:g}")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or self.seed < 0:
            raise SimulationError(f"seed must be a whole number >= 0, got {self.seed!r}")
        if self.bogies not in BOGIE_COUNTS or isinstance(self.bogies, bool):
            raise SimulationError(f"bogies recorded must be 1 or 2, got {self.bogies!r}")
        if self.sensor_bogie_2 is not None and (self.bogies != 2 or self.model != "a"):
            raise SimulationError("sensor_bogie_2 describes model A's second bogie's sensors: give it with bogies=2 on model a")
        for s in (self.sensor,) if self.sensor_bogie_2 is None else (self.sensor, self.sensor_bogie_2):
            self._check_sensor(s)

    def _check_sensor(self, s: SensorModel) -> None:
        if not (s.noise_mps2 >= 0 and s.quantum_mps2 >= 0 and len(s.bias_mps2) == 3):
            raise SimulationError("sensor noise and quantum must be >= 0 m/s^2 and the bias three values")
        if len(s.gain) != 3 or not all(math.isfinite(g) and g != 0 for g in s.gain):
            raise SimulationError(f"sensor gains must be three finite, non-zero values, got {s.gain}")
        if s.variant not in SENSOR_VARIANTS:
            raise SimulationError(f"unknown sensor variant '{s.variant}': use one of {', '.join(SENSOR_VARIANTS)} (docs/simulator.md)")
        if self.model == "b" and s.variant != "standard":
            # B's part is its own chain (its filter runs in its kernel, its noise inside or after).
            raise SimulationError(
                f"model b reads its sensor part from its parameter set: give parameters="
                f"model_b.parameters.with_sensor_variant(parameters, '{s.variant}') and the standard sensor variant"
            )
        if len(s.element_noise_mps2) != 3 or not all(math.isfinite(n) and n >= 0 for n in s.element_noise_mps2):
            raise SimulationError(f"sensor element noise must be three values >= 0 m/s^2, got {s.element_noise_mps2}")

    @property
    def oversampling(self) -> int:
        """Integration steps per output sample."""
        return max(1, math.ceil(1.0 / (self.fs_hz * self.max_step_s) - 1e-9))

    @property
    def integration_step_s(self) -> float:
        return 1.0 / (self.fs_hz * self.oversampling)

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s * self.fs_hz))

    @property
    def onset_sample(self) -> int:
        """The first output sample (of the recording) with the faults applied."""
        return int(round(self.fault_onset_s * self.fs_hz))

    def to_dict(self) -> dict[str, Any]:
        out = self._to_dict()
        if self.bogies != 1:  # a one-bogie sidecar stays as it was
            out["bogies"] = self.bogies
        if self.sensor_bogie_2 is not None:
            out["sensor_bogie_2"] = _sensor_dict(self.sensor_bogie_2)
        return out

    def _to_dict(self) -> dict[str, Any]:
        return {
            "load": self.load,
            "speed_profile": [list(p) for p in self.speed.points],
            "track": self.track,
            "duration_s": self.duration_s,
            "seed": self.seed,
            "faults": [f.to_dict() for f in self.faults],
            "fault_onset_s": self.fault_onset_s,
            "fs_hz": self.fs_hz,
            "geometry": _geometry_dict(self.geometry),
            "sensor": _sensor_dict(self.sensor),
            "max_step_s": self.max_step_s,
            "parameters": self.parameters,
            "standing_faults": [f.to_dict() for f in self.standing_faults],
            "model": self.model,
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Scenario:
        try:
            geometry = data["geometry"]
            sensor = data["sensor"]
            return cls(
                load=data["load"],
                speed=SpeedProfile(tuple((float(t), float(v)) for t, v in data["speed_profile"])),
                track=data["track"],
                duration_s=float(data["duration_s"]),
                seed=int(data["seed"]),
                faults=tuple(Fault.from_dict(f) for f in data["faults"]),
                fault_onset_s=float(data.get("fault_onset_s", 0.0)),
                fs_hz=float(data["fs_hz"]),
                geometry=BogieGeometry(
                    wheelbase_m=float(geometry["wheelbase_m"]),
                    sensor_spacing_m=float(geometry["sensor_spacing_m"]),
                    corners=tuple(Corner(c) for c in geometry["corners"]),  # type: ignore[arg-type]
                ),
                sensor=_sensor_of(sensor),
                max_step_s=float(data["max_step_s"]),
                parameters=data["parameters"],
                standing_faults=tuple(Fault.from_dict(f) for f in data.get("standing_faults", ())),
                # Sidecars written before model B existed are model A's, before two bogies of one.
                model=str(data.get("model", "a")),
                bogies=int(data.get("bogies", 1)),
                sensor_bogie_2=_sensor_of(data["sensor_bogie_2"]) if data.get("sensor_bogie_2") is not None else None,
            )
        except (KeyError, TypeError, ValueError) as exc:
            if isinstance(exc, SimulationError):
                raise
            raise SimulationError(f"not a complete scenario: {exc!r}") from None


def _sensor_dict(sensor: SensorModel) -> dict[str, Any]:
    return {
        "noise_mps2": sensor.noise_mps2,
        "bias_mps2": list(sensor.bias_mps2),
        "quantum_mps2": sensor.quantum_mps2,
        "gain": list(sensor.gain),
        "variant": sensor.variant,
        "element_noise_mps2": list(sensor.element_noise_mps2),
    }


def _sensor_of(sensor: dict[str, Any]) -> SensorModel:
    return SensorModel(
        noise_mps2=float(sensor["noise_mps2"]),
        bias_mps2=tuple(float(b) for b in sensor["bias_mps2"]),  # type: ignore[arg-type]
        quantum_mps2=float(sensor["quantum_mps2"]),
        # Sidecars written before the gain existed: exact sensors.
        gain=tuple(float(g) for g in sensor.get("gain", (1.0, 1.0, 1.0))),  # type: ignore[arg-type]
        # Sidecars written before the sensor variants: the standard part, no element noise.
        variant=str(sensor.get("variant", "standard")),
        element_noise_mps2=tuple(float(n) for n in sensor.get("element_noise_mps2", (0.0, 0.0, 0.0))),  # type: ignore[arg-type]
    )


def bogiemon_version() -> str:
    from bogiemon import __version__  # the package's own, installed or not

    return __version__


def sidecar_path(csv_path: str | Path) -> Path:
    """FILE.json beside FILE.csv."""
    return Path(csv_path).with_suffix(".json")


def write_sidecar(path: str | Path, scenario: Scenario, derived: dict[str, Any]) -> None:
    document = {
        "format": SIDECAR_FORMAT,
        "bogiemon_version": bogiemon_version(),
        "monitored_bogie": MONITORED_BOGIE,
        "scenario": scenario.to_dict(),
        "derived": derived,
    }
    Path(path).write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")


def read_sidecar(path: str | Path) -> Scenario:
    """The scenario stored in a sidecar; SimulationError naming the file if it is not one."""
    path = Path(path)
    try:
        document = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SimulationError(f"{path}: cannot read the sidecar: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise SimulationError(f"{path}: not a JSON sidecar: {exc}") from None
    if not isinstance(document, dict) or document.get("format") != SIDECAR_FORMAT:
        raise SimulationError(f"{path}: not a bogiemon simulation sidecar (format '{SIDECAR_FORMAT}')")
    try:
        return Scenario.from_dict(document["scenario"])
    except SimulationError as exc:
        raise SimulationError(f"{path}: {exc}") from None
