"""The words the daemon compares, as types written once: the load states, the decision methods and
the decision's modes.

StrEnums, so that a value reads and writes as its word (TOML, JSON, the event details, the fleet's
series) and a word from a file validates into it (pydantic). A leaf: a reader of the words (the
fleet's report) loads nothing else. The events' kinds and severities live with the event record
(judgement/events.py). The simulator keeps its own carbody load
(simulator/params.py): it is a scenario's mass, not a state the daemon judges in.
"""

from __future__ import annotations

import enum


class LoadState(enum.StrEnum):
    """A load state a wagon is judged in: loaded or empty."""

    FULL = "full"
    TARE = "tare"


class LoadSetting(enum.StrEnum):
    """decision.load: a fixed load state, or "auto" (decided per window)."""

    AUTO = "auto"
    FULL = "full"
    TARE = "tare"

    def fixed(self) -> LoadState | None:
        """The load state it fixes; None for auto."""
        return None if self is LoadSetting.AUTO else LoadState(self.value)


class LoadSource(enum.StrEnum):
    """How a window's load state was decided (judgement/running.py)."""

    CONFIGURED = "configured"  # decision.load fixes it
    COMMISSIONED = "commissioned"  # from the wagon's commissioned load states
    ESTIMATED = "estimated"  # by the shipped load model (a load the wagon was not commissioned in)


class Method(enum.StrEnum):
    """decision.method: how a window's level is decided (judgement/decision.py)."""

    FUSED = "fused"
    THRESHOLDS = "thresholds"


class Mode(enum.StrEnum):
    """The suspension decision's mode (judgement/decision.py's state machine)."""

    NORMAL = "normal"
    SUSPECTED = "suspected"
    CONFIRMED = "confirmed"
