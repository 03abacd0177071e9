"""The load state of a window (judgement/running.py) where the shipped load model alone decides: an
uncommissioned wagon, load "auto"."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bogiemon.detection.features import LOAD_NAMES
from bogiemon.judgement.models import shipped_models
from bogiemon.judgement.running import choose_load
from bogiemon.judgement.vocabulary import LoadSetting, LoadState

MODEL = shipped_models().load


def _centre() -> np.ndarray:
    """A load vector at the model's mean: a finite P(full)."""
    x = np.zeros(len(LOAD_NAMES))
    for name, mean in zip(MODEL.features, MODEL.mean, strict=True):
        x[LOAD_NAMES.index(name)] = mean
    return x


def test_an_uncommissioned_window_with_no_load_vector_is_not_judged_rather_than_judged_as_tare() -> None:
    choice = choose_load(LoadSetting.AUTO, None, 1.0, (), None, MODEL)
    assert choice.load is None and choice.unjudged == "no load vector: a mode had no power"


@pytest.mark.parametrize("feature", MODEL.features)
def test_an_uncommissioned_window_whose_load_model_gives_nan_is_not_judged(feature: str) -> None:
    x = _centre()
    x[LOAD_NAMES.index(feature)] = math.nan  # that mode had no power
    assert math.isnan(MODEL.probability_of(x))
    choice = choose_load(LoadSetting.AUTO, x, 1.0, (), None, MODEL)
    assert choice.load is None and choice.unjudged is not None and "P(full) is not a number" in choice.unjudged


def test_an_uncommissioned_window_with_a_finite_p_full_is_judged_on_its_side_of_one_half() -> None:
    x = _centre()
    p_full = MODEL.probability_of(x)
    choice = choose_load(LoadSetting.AUTO, x, 1.0, (), None, MODEL)
    assert choice.load is (LoadState.FULL if p_full >= 0.5 else LoadState.TARE) and choice.unjudged is None
    assert choice.p_full == p_full and choice.source == "estimated"
