"""[duty]: a battery-fed unit's duty cycle (daemon/duty.py, docs/gateway.md). Bogiemon's config is
split by topic: the sections and their base in config_sections.py, the sources in config_sources.py,
what goes off the gateway in config_delivery.py, the decision in config_decision.py."""

from __future__ import annotations

from pydantic import Field, model_validator

from bogiemon.daemon.config_sections import Section


class DutyConfig(Section):
    """A battery-fed unit's duty cycle (docs/gateway.md, "A wagon's day"): while the wagon runs, measure
    measure_min minutes in every every_min; while it stands, rest, but for a short listen every
    probe_every_s that notices it moving again. Standing is every channel's standard deviation over a
    block (about a second) below [health] standstill_rms_mps2. A rest closes the CAN socket or the
    serial port; the first window after it is judged window_s of samples later. `bogiemon replay
    --duty` runs a recording through the duty cycle, to see what it costs the detection."""

    enabled: bool = Field(False, description="Rest while the wagon stands, and measure on the cycle below while it runs. Off: read everything.")
    measure_min: float = Field(60.0, gt=0, le=1440, description=(
        "Minutes of measurement in every cycle while the wagon runs; more than processing.window_s and a "
        "hop, else no window is judged. At most every_min; equal to it: no cycle, the running all measured."
    ))  # fmt: skip
    every_min: float = Field(60.0, gt=0, le=1440, description="The cycle in minutes: a measurement starts every every_min minutes while the wagon runs; at most 1440.")
    standing_after_s: float = Field(60.0, gt=0, le=3600, description=(
        "Seconds of every channel still before the wagon counts as standing and the source rests (a stop "
        "at a signal shorter than this is measured through); at most 3600."
    ))  # fmt: skip
    probe_every_s: float = Field(60.0, gt=0, le=3600, description=(
        "While the wagon stands, seconds between two listens for motion (the longest it may run before the "
        "daemon notices); at most 3600."
    ))  # fmt: skip
    probe_s: float = Field(2.0, gt=0, le=60, description="Seconds of samples each listen reads (nothing of them is judged); at most 60.")

    @model_validator(mode="after")
    def _measure_within_the_cycle(self) -> DutyConfig:
        if self.measure_min > self.every_min:
            raise ValueError(f"measure_min ({self.measure_min:g}) must not exceed every_min ({self.every_min:g})")
        return self
