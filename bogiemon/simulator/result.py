"""What a simulation gives back: the recording of one scenario and the wagon that ran it (both
models' runners return it: simulator/run.py and simulator/model_b/run.py)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from bogiemon.simulator.scenario import Scenario
from bogiemon.simulator.vehicle import State, VehicleModel

if TYPE_CHECKING:
    from bogiemon.simulator.model_b import bodies as model_b_bodies


@dataclass(frozen=True)
class SimulationResult:
    """The recording of one scenario: time_s (n,) from 0 and accel_mps2 (n, 3 x scenario.bogies):
    a1..a3 on bogie 1, the leading bogie in the direction of travel, then (two bogies) b1..b3 on
    bogie 2 at the same named corners of its own frame (both frames' x towards the direction of travel)."""

    scenario: Scenario
    time_s: NDArray[np.float64]
    accel_mps2: NDArray[np.float64]
    # The wagon that ran, and its state at the end of the run (for checks): model A's types for a
    # scenario of model "a", model_b.bodies' WagonModel and State for "b".
    model: VehicleModel | model_b_bodies.WagonModel
    final_state: State | model_b_bodies.State
    derived: dict[str, Any]  # integration step, pre-roll, each corner's Kz and Fs, ...
