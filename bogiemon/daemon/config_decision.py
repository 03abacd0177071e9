"""The [decision] section and the tables `bogiemon calibrate` writes into it: the thresholds of the
paper's indicators, the wagon's fused baseline, its load states and the line between them."""

from __future__ import annotations

from typing import Any, Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from bogiemon.daemon.config_sections import Section
from bogiemon.detection.features import COUPLING_NAMES, LOAD_NAMES
from bogiemon.judgement.events import INDICATOR_FIELDS
from bogiemon.judgement.vocabulary import LoadSetting, LoadState, Method

IndicatorName = Literal["i1", "i2", "i3", "i4", "i1_norm", "i2_norm", "i3_norm", "i4_norm"]
assert set(IndicatorName.__args__) == set(INDICATOR_FIELDS)  # type: ignore[attr-defined]


class ThresholdConfig(Section):
    """One indicator's levels for one load state (method "thresholds"), applied to |value - center|."""

    center: float = Field(0.0, description="The healthy value the deviation is measured from (the median of the healthy windows it was learned from).")
    warning: float = Field(gt=0, description="Deviation at which a window counts as a warning.")
    alarm: float = Field(gt=0, description="Deviation at which a window counts towards confirmation (at least warning).")

    @model_validator(mode="after")
    def _ordered(self) -> ThresholdConfig:
        if self.warning > self.alarm:
            raise ValueError(f"warning ({self.warning}) must not exceed alarm ({self.alarm})")
        return self


# Thresholds when the config names none (the shipped file states the same values): derived for
# 120 s windows by the detection study (docs/study/defaults.md) with calibrate's rule from its
# healthy runs at 40 to 120 km/h on ERRI low and high level track; recalibrate for other windows.
DEFAULT_THRESHOLDS: dict[LoadState, dict[IndicatorName, ThresholdConfig]] = {
    LoadState.FULL: {"i4_norm": ThresholdConfig(center=-9.44e-05, warning=0.059, alarm=0.114)},
    LoadState.TARE: {
        "i4_norm": ThresholdConfig(center=-0.000235, warning=0.0292, alarm=0.044),
        "i3_norm": ThresholdConfig(center=0.00121, warning=0.0408, alarm=0.0657),
    },
}


class FusedBaselineConfig(Section):
    """A wagon's own healthy baseline of the fused score for one load state, written by `bogiemon
    calibrate`: the score is the Mahalanobis distance of a window's coupling vector (pitch-roll and
    bounce-roll coherency in the octave bands from 2 to 64 Hz) from this centre."""

    features: list[str] = Field(default_factory=lambda: list(COUPLING_NAMES), description=(
        "The couplings, in the order of center: this bogiemon's own (c_pr_2..c_pr_6, c_br_2..c_br_6); "
        "a calibration of other features is refused (calibrate again)."
    ))  # fmt: skip
    center: list[float] = Field(description="The mean coupling vector of the wagon's healthy commissioning windows, one value per feature.")
    warning: float = Field(gt=0, description="The window score's warning level (the shipped one raised by how much worse the commissioning runs scored out of sample).")
    alarm: float = Field(gt=0, description="The window score's alarm level (at least warning).")
    trend_warning: float = Field(gt=0, description="The trend's warning level (the trend: the weighted mean of the shifts over the last half hour of running).")
    trend_alarm: float = Field(gt=0, description="The trend's alarm level (at least trend_warning).")
    windows: int = Field(0, ge=0, le=2**31, description="The commissioning windows it was learned from (for people).")
    covariance: list[list[float]] = Field(default_factory=list, description=(
        "The wagon's own spread of the coupling vector, learned at commissioning (shrunk towards the "
        "shipped one): a symmetric, positive definite matrix; empty: the shipped spread of "
        "config/fused_model.toml."
    ))  # fmt: skip

    @model_validator(mode="after")
    def _consistent(self) -> FusedBaselineConfig:
        if tuple(self.features) != COUPLING_NAMES:
            raise ValueError(f"features {self.features} are not this bogiemon's {list(COUPLING_NAMES)}: calibrate again")
        if len(self.center) != len(COUPLING_NAMES):
            raise ValueError(f"center needs {len(COUPLING_NAMES)} values, got {len(self.center)}")
        if self.covariance:
            n = len(COUPLING_NAMES)
            m = np.array(self.covariance, dtype=np.float64) if all(len(r) == n for r in self.covariance) else np.zeros((0, 0))
            if m.shape != (n, n) or not np.all(np.isfinite(m)) or not np.allclose(m, m.T, rtol=1e-9, atol=1e-12):
                raise ValueError(f"covariance must be a finite, symmetric {n} x {n} matrix: calibrate again")
            try:
                np.linalg.cholesky(m)
            except np.linalg.LinAlgError:
                raise ValueError("covariance is not positive definite: calibrate again") from None
        if self.warning > self.alarm or self.trend_warning > self.trend_alarm:
            raise ValueError(
                f"warning levels ({self.warning}, trend {self.trend_warning}) must not exceed the alarm levels ({self.alarm}, trend {self.trend_alarm})"
            )
        return self


class LoadStateConfig(Section):
    """A load state the wagon was commissioned in: the centre and spread of its windows' load
    vector (detection/features.py LOAD_FEATURES: each mode's log power share per band), and the
    distance (RMS of the z-scores) its windows reached, stated beside a window's own as evidence
    (never a gate: judgement/running.py). Written by `bogiemon calibrate`."""

    center: list[float] = Field(description="The centre of the commissioning windows' load vector (21 values: bounce, pitch and roll shares per band).")
    scale: list[float] = Field(description="Its robust spread, one positive value per feature.")
    limit: float = Field(gt=0, description="The distance (RMS of the z-scores) the commissioning windows reached from the centre.")
    windows: int = Field(0, ge=0, le=2**31, description="The commissioning windows it was learned from (for people).")
    lowest_excitation_mps2: float = Field(0.0, ge=0, le=1e6, description=(
        "The gentlest excitation (the median channel's RMS, m/s^2) of its commissioning windows: running "
        "gentler is judged with raised levels, far gentler not at all (judgement/running.py). "
        "Calibrations before it: 0."
    ))  # fmt: skip
    highest_excitation_mps2: float | None = Field(None, gt=0, le=1e6, description=(
        "The roughest excitation of its commissioning windows, in m/s^2: running rougher is judged with "
        "raised levels, far rougher not at all. Absent (calibrations before it): no bound."
    ))  # fmt: skip

    @model_validator(mode="after")
    def _consistent(self) -> LoadStateConfig:
        n = len(LOAD_NAMES)
        if len(self.center) != n or len(self.scale) != n:
            raise ValueError(f"center and scale need {n} values each (the load features), got {len(self.center)} and {len(self.scale)}")
        if not all(np.isfinite(self.center)) or not all(v > 0 and np.isfinite(v) for v in self.scale):
            raise ValueError("center must be finite and scale finite and positive: calibrate again")
        if self.highest_excitation_mps2 is not None and self.highest_excitation_mps2 < self.lowest_excitation_mps2:
            raise ValueError("highest_excitation_mps2 is below lowest_excitation_mps2: calibrate again")
        return self


class LoadDiscriminantConfig(Section):
    """The wagon's own line between its full and tare states (judgement/commissioning.py:
    fit_discriminant): value = weights . load vector + offset, full at or above margin, tare at or
    below -margin, between them not judged. Written by `bogiemon calibrate` with both loads."""

    weights: list[float] = Field(description="One weight per load feature (21 values), scaled so that a state's healthy scatter along the line is 1.")
    offset: float = Field(description="Added to the weighted sum: the line's value is 0 midway between the states.")
    margin: float = Field(gt=0, description="A window whose value lies within +/-margin is between the states: not judged for its running.")
    separation: float = Field(gt=0, description="The distance of the two states' centres along the line, in the same units (at least twice the margin).")

    @model_validator(mode="after")
    def _consistent(self) -> LoadDiscriminantConfig:
        if len(self.weights) != len(LOAD_NAMES):
            raise ValueError(f"weights need {len(LOAD_NAMES)} values (the load features), got {len(self.weights)}")
        if not all(np.isfinite([*self.weights, self.offset, self.margin, self.separation])):
            raise ValueError("weights, offset, margin and separation must be finite: calibrate again")
        if self.separation < 2 * self.margin:
            raise ValueError(f"separation {self.separation:g} is less than twice the margin {self.margin:g}: the states would overlap")
        return self


class DecisionConfig(Section):
    """How a window is judged and when an alarm is raised, confirmed and cleared. The wagon's own
    baselines come from its commissioning (`bogiemon calibrate` writes `[decision.fused.<load>]`,
    `[decision.load_states.<load>]` and `[decision.load_discriminant]` into a file to include); without
    them a load is judged against the simulated fleet's population baseline (config/fused_model.toml),
    which misses all but the strongest faults."""

    method: Method = Field(Method.FUSED, description=(
        "How a window is judged: \"fused\" scores the couplings of bounce, pitch and roll in octave bands "
        "against the wagon's healthy baseline (a Mahalanobis distance); \"thresholds\" judges the paper's "
        "indicators one by one against [decision.thresholds]. docs/robust/README.md compares them."
    ))  # fmt: skip
    load: LoadSetting = Field(LoadSetting.AUTO, description=(
        "The load state: \"full\" or \"tare\" fixes it (`bogiemon run --load` overrides it); \"auto\" takes for "
        "each window the load state the wagon was commissioned in ([decision.load_states]) on its side of "
        "the wagon's own line between them ([decision.load_discriminant]; with one state, the nearest), "
        "and does not judge a window near that line or far outside the commissioning's excitation; "
        "without a commissioning, the shipped load model (config/load_model.toml, a prior fitted on the "
        "simulator) estimates tare or full."
    ))  # fmt: skip
    confirm_k: int = Field(3, ge=1, description=(
        "CONFIRMED needs at least confirm_k of the last confirm_n judged windows at an alarm level; "
        "SUSPECTED one fewer (at least one) at a warning level. At most confirm_n."
    ))  # fmt: skip
    confirm_n: int = Field(5, ge=1, le=100, description="The length of that history, in judged windows.")
    clear_after_windows: int = Field(6, ge=1, le=100_000, description="SUSPECTED or CONFIRMED clears after this many consecutive judged windows below every warning level (with the fused method, the trend below its warning level too).")
    not_judged_after_h: float = Field(2.0, gt=0, le=10_000, description=(
        "Hours of running left unjudged (unlike every state of the commissioning) after which a "
        "NOT_JUDGED event says so (MQTT, the CAN alarm frame, the fleet page); JUDGED_AGAIN ends it."
    ))  # fmt: skip
    thresholds: dict[LoadState, dict[IndicatorName, ThresholdConfig]] = Field(default_factory=lambda: DEFAULT_THRESHOLDS, description=(
        "Method \"thresholds\": per load state and indicator (i1..i4 raw, i1_norm..i4_norm normalised), "
        "`[decision.thresholds.<load>.<indicator>]`. A load state named in a file (or an included "
        "calibration) replaces that state's whole default set. The defaults come from the detection "
        "study (docs/study/defaults.md): I4n at full load, I4n and I3n in tare, for 120 s windows."
    ))  # fmt: skip
    fused: dict[LoadState, FusedBaselineConfig] = Field(default_factory=dict, description=(
        "The wagon's calibrated fused baselines, `[decision.fused.<load>]` (none shipped: without one a "
        "load is judged against the fleet's population baseline, config/fused_model.toml)."
    ))  # fmt: skip
    load_states: dict[LoadState, LoadStateConfig] = Field(default_factory=dict, description=(
        "The load states the wagon was commissioned in, `[decision.load_states.<load>]` (written by "
        "`bogiemon calibrate`); without any, the shipped load model decides (config/load_model.toml, a prior)."
    ))  # fmt: skip
    load_discriminant: LoadDiscriminantConfig | None = Field(None, description=(
        "With both states: the wagon's own line between them, `[decision.load_discriminant]` (written by "
        "`bogiemon calibrate`; absent: the nearest state)."
    ))  # fmt: skip
    models_dir: str = Field("", description=(
        "The folder of the priors the decision starts from (load_model.toml and fused_model.toml: "
        "`bogiemon evaluate --fit-models` writes them); empty: the ones shipped in bogiemon's config "
        "folder, fitted on its own simulator (docs/robust/README.md)."
    ))  # fmt: skip

    @field_validator("thresholds", mode="before")
    @classmethod
    def _per_load_over_defaults(cls, value: Any) -> Any:
        """A load state named in the file replaces that state's default set; others keep theirs."""
        if isinstance(value, dict):
            return {**DEFAULT_THRESHOLDS, **value}
        return value

    @model_validator(mode="after")
    def _consistent(self) -> DecisionConfig:
        if self.confirm_k > self.confirm_n:
            raise ValueError(f"confirm_k ({self.confirm_k}) must not exceed confirm_n ({self.confirm_n})")
        fixed = self.load.fixed()
        loads = tuple(LoadState) if fixed is None else (fixed,)
        if self.method is Method.THRESHOLDS:
            for load in loads:
                if not self.thresholds.get(load):
                    raise ValueError(f"no thresholds for the load state '{load}': add [decision.thresholds.{load}.<indicator>]")
        return self
