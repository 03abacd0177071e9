"""Gating: why a window cannot be judged whatever the sensors (the wagon stands, stops or starts
within it, or runs too gently).

THE GATES. Standstill: every channel quiet. Non-stationary: the window holds a hop near
standstill, or its quietest hop's RMS is below min_hop_rms_ratio of its loudest (the median
channel's per-hop RMS, detection/channel_stats.py). A running frame's RMS grows with speed as
about v^a, a = 1.2 to 2 on both simulated wagon models (lab/robust/health_check.py prints it), so
a ratio of 0.25 between two hops of one window is a speed change by a factor 0.25^(-1/a) = 2 to
3.2 within two minutes: braking to a stop, standing, or starting. Running hops differ far less:
the ratio stayed above 0.34 on every window of the simulated fleets, whose speed drifts within
50-110 km/h, and above 0.6 at a steady 10-30 km/h. The couplings of such a
window mix running with standing, and the dry-friction dampers stick at low speed: not judged.
Weak excitation: moving, but the median channel's RMS is too small to judge the suspension.

"""

from __future__ import annotations

import enum

import numpy as np

from bogiemon.detection import WindowIndicators
from bogiemon.judgement.settings import HealthSettings



class Gate(enum.Enum):
    STANDSTILL = "standstill"  # every channel quiet: the wagon stands
    # The excitation changes too much within the window: a stop, a start or a standstill inside it.
    NON_STATIONARY = "non_stationary"
    WEAK_EXCITATION = "weak_excitation"  # moving, but too little excitation to judge


def window_gate(window: WindowIndicators, settings: HealthSettings) -> Gate | None:
    """Why the window cannot be judged whatever the sensors (None: it can)."""
    rms = np.asarray(window.rms_mps2)
    if np.all(rms < settings.standstill_rms_mps2):
        return Gate.STANDSTILL
    # The median channel: one faulty sensor (noisy, dead) moves neither of them.
    hop_min = float(np.median(window.channels.hop_rms_min_mps2))
    hop_max = float(np.median(window.channels.hop_rms_max_mps2))
    if hop_min < settings.standstill_rms_mps2 or hop_min < settings.min_hop_rms_ratio * hop_max:  # NaN (not measured): neither
        return Gate.NON_STATIONARY
    if float(np.median(rms)) < settings.min_excitation_rms_mps2:
        return Gate.WEAK_EXCITATION
    return None

