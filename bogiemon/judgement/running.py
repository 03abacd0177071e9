"""What the running is, for one window: its load state, and how its excitation compares with the
commissioning's. Only this may leave a running window unjudged.

A broken spring or a seized damper changes how the modes share their power between the bands and
how they couple: the very things the judgement looks at. So nothing a one-corner fault changes may
decide that a window is "unlike the commissioning"; the load state comes from the line between the
wagon's commissioned states (its load vector moves far more with the load than with any fault:
a load is a whole carbody's mass, a fault one corner's spring) and a window is not judged only
when it has no load vector, lies between the states, or runs at an excitation far outside the
commissioning's. The load vector's distance from the state is stated with the judgement as
evidence, never a gate: such a gate left 17 of 128 fault runs of an independently built wagon model
wholly unjudged (issue 26's probe), among them broken springs at full load.

A commissioning never covers every track and speed. Running gentler or rougher than it, within
JUDGED_DOWN_TO..JUDGED_UP_TO of its range, is judged against the state with its levels raised by
level_margin: the square root of how far outside the range the window runs. Chosen by judging
every window of the transfer evaluation's training and evaluation fleets (both wagon models, each
commissioned on a random draw of 10 runs per load) against its load state: with this margin and no
distance gate every healthy window in the range was judged with no more confirmations than the
gate had allowed, and more broken springs were confirmed (the evaluation fleets informed the
choice: docs/robust/transfer says so).

The wagon's own line between its load states is fitted on its commissioning and extrapolates
beyond it as a straight line: a loaded wagon of model A at 50 km/h, commissioned at 80-95 km/h on
one track, lay on the empty side of it, while the shipped load model (fitted across every speed and
track of a fleet) gave P(full) 1.0 and the loaded state was the nearer by far. So three rules
vote: the line (abstaining within its margin), the load model and the nearer state; the line's
side stands when one of the others agrees, else the other two's when they agree, else the window
lies between the states and is not judged.

A load the wagon was never commissioned in (a commissioning of one load) is judged against the
fleet's population baseline, which is what an uncommissioned wagon runs on: the shipped load model
tells the loads apart.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
import numpy as np
from numpy.typing import NDArray

from bogiemon.judgement.events import RunningContext
from bogiemon.judgement.models import LoadDiscriminant, LoadModel, LoadSignature
from bogiemon.judgement.vocabulary import LoadSetting, LoadSource, LoadState

# The excitation judged, relative to the commissioning's gentlest and roughest windows. Below half
# the gentlest the dry-friction dampers stick (the couplings of a healthy wagon change with them);
# above four times the roughest lies a track no wagon runs for long. Outside: not judged.
JUDGED_DOWN_TO = 0.5
JUDGED_UP_TO = 4.0


def level_margin(excitation_outside: float) -> float:
    """The factor on a window's levels for running this far outside the commissioning's excitation
    (LoadSignature.excitation_outside): 1 within; sqrt(2) at half the gentlest or twice the roughest."""
    return math.sqrt(max(excitation_outside, 1.0))


@dataclass(frozen=True)
class LoadChoice:
    """A window's load state and how it is judged in it (load None: not judged, `unjudged` says why)."""

    load: LoadState | None
    source: LoadSource
    unjudged: str | None = None
    level_margin: float = 1.0  # the window's levels x this (running outside the commissioning's excitation)
    excitation_outside: float = 1.0
    distance: float = math.nan  # the load vector's distance from the state (LoadSignature.distance)
    p_full: float | None = None  # the shipped load model's P(full), where it decided

    def context(self) -> RunningContext:
        """What the events' details state of how the window was judged."""
        raised = self.level_margin > 1.0
        return RunningContext(
            load_source=self.source,
            load_distance=round(self.distance, 3) if math.isfinite(self.distance) else None,
            p_full=round(self.p_full, 4) if self.p_full is not None and math.isfinite(self.p_full) else None,
            excitation_outside=round(self.excitation_outside, 3) if raised else None,
            level_margin=round(self.level_margin, 3) if raised else None,
        )


def choose_load(
    load: LoadSetting,
    x: NDArray[np.float64] | None,
    excitation_mps2: float,
    states: Sequence[LoadSignature],
    discriminant: LoadDiscriminant | None,
    model: LoadModel | None,
) -> LoadChoice:
    """The load state of a window of load vector x (None: a mode had no power) and excitation
    (excitation_of), for the configured load setting and the wagon's commissioned states."""
    fixed = load.fixed()
    by_load = {s.load: s for s in states}
    if fixed is not None:
        return _against(LoadChoice(fixed, LoadSource.CONFIGURED), by_load.get(fixed), x, excitation_mps2)
    if states and x is None:
        return LoadChoice(None, LoadSource.COMMISSIONED, unjudged="no load vector: a mode had no power")
    if discriminant is not None and set(by_load) == set(LoadState):
        assert x is not None
        line = discriminant.load_of(x)  # None: within its margin, it abstains
        p_full = model.probability_of(x) if model is not None else math.nan
        modelled = LoadState.FULL if p_full >= 0.5 else LoadState.TARE if p_full < 0.5 else None
        nearest = min(states, key=lambda s: s.distance(x)).load
        side = line if line is not None and (modelled is line or nearest is line) else modelled if modelled is nearest else None
        if side is None:
            why = f"between the commissioned load states (the wagon's line says {line or 'neither'}, the load model {modelled}, the nearer state {nearest})"
            return LoadChoice(None, LoadSource.COMMISSIONED, unjudged=why, distance=min(s.distance(x) for s in states), p_full=p_full)
        return _against(LoadChoice(side, LoadSource.COMMISSIONED, p_full=p_full), by_load[side], x, excitation_mps2)
    if len(by_load) == len(LoadState):  # both states, no line between them: the nearer
        assert x is not None
        closest = min(states, key=lambda s: s.distance(x))
        return _against(LoadChoice(closest.load, LoadSource.COMMISSIONED), closest, x, excitation_mps2)
    if model is None:
        raise ValueError("load 'auto' needs the load model")
    if x is None:
        return LoadChoice(None, LoadSource.ESTIMATED, unjudged="no load vector: a mode had no power")
    p_full = model.probability_of(x)
    if not math.isfinite(p_full):
        # NaN is neither side of 0.5: a comparison would make it tare, and an empty wagon's levels
        # are not a loaded one's. What cannot be told is not judged.
        return LoadChoice(None, LoadSource.ESTIMATED, unjudged="the load model cannot tell the load: its P(full) is not a number")
    # A wagon is loaded or empty; the estimate is either side of 0.5 by a wide margin on the
    # simulated fleets (docs/robust/README.md): no third state is needed.
    estimated = LoadState.FULL if p_full >= 0.5 else LoadState.TARE
    own = by_load.get(estimated)  # one load commissioned: the other runs on the population baseline
    choice = LoadChoice(estimated, LoadSource.COMMISSIONED if own is not None else LoadSource.ESTIMATED, p_full=p_full)
    return _against(choice, own, x, excitation_mps2)


def _against(choice: LoadChoice, state: LoadSignature | None, x: NDArray[np.float64] | None, excitation_mps2: float) -> LoadChoice:
    """The choice judged against its commissioned state's excitation (none: as it is)."""
    if state is None:
        return choice
    distance = state.distance(x) if x is not None else math.nan
    outside = state.excitation_outside(excitation_mps2)
    low, high = state.lowest_excitation_mps2 * JUDGED_DOWN_TO, state.highest_excitation_mps2 * JUDGED_UP_TO
    if not low <= excitation_mps2 <= high:
        why = (
            f"excitation {excitation_mps2:.3g} m/s^2 outside {low:.3g}-{high:.3g} m/s^2 "
            f"({JUDGED_DOWN_TO:g}x the gentlest to {JUDGED_UP_TO:g}x the roughest of the {state.load} commissioning)"
        )
        return LoadChoice(None, choice.source, unjudged=why, excitation_outside=outside, distance=distance, p_full=choice.p_full)
    return LoadChoice(choice.load, choice.source, None, level_margin(outside), outside, distance, choice.p_full)
