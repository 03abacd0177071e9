"""A non-linear multibody model of a Y25 wagon producing healthy and faulty bogie accelerations.

The public API (imported lazily, so that `import bogiemon.simulator.errors` stays cheap for the
command line): Scenario, SpeedProfile, SensorModel, Fault, parse_fault, simulate,
simulate_batch, write_recording, rerun_sidecar, read_sidecar, SimulationResult, SimulationError.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "Scenario": "scenario",
    "SpeedProfile": "scenario",
    "read_sidecar": "scenario",
    "SensorModel": "sensors",
    "Fault": "suspension",
    "parse_fault": "suspension",
    "simulate": "run",
    "simulate_batch": "run",
    "write_recording": "run",
    "rerun_sidecar": "run",
    "SimulationResult": "run",
    "SimulationError": "errors",
    "TRACKS": "track",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"bogiemon.simulator.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'bogiemon.simulator' has no attribute {name!r}")
