"""The wagon judge (judgement/wagon.py): both bogies' verdicts, the sister evidence in the one decision."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bogiemon.detection import BogieGeometry, ProcessingSettings, WindowIndicators
from bogiemon.detection.features import COUPLING_NAMES
from bogiemon.drivers.base import ALL_OK, SensorStatus
from bogiemon.judgement.decision import DecisionSettings
from bogiemon.judgement.events import Event
from bogiemon.judgement.settings import HealthSettings
from bogiemon.judgement.sister import SISTER_SCORE, SisterBaseline
from bogiemon.judgement.verdict import MonitorSettings, Outcome
from bogiemon.judgement.vocabulary import LoadSetting, LoadState, Method, Mode
from bogiemon.judgement.wagon import WagonJudge, WagonSettings
from tests.judgement.test_fused import BASELINE, HOP_S, window

N = len(COUPLING_NAMES)
BOGIE = MonitorSettings(
    processing=ProcessingSettings(), geometry=BogieGeometry(), health=HealthSettings(structure_checks=False),
    decision=DecisionSettings({}, confirm_k=3, confirm_n=5, clear_after_windows=2, method=Method.FUSED, baselines={LoadState.FULL: BASELINE}),
    load=LoadSetting.FULL, config_hash="test",
)  # fmt: skip
# The sister's: log I2's difference, healthy 0 with a spread of 0.1 (z = 10 d); alarm at a score of 40.
SISTER = SisterBaseline("commissioned", ("log_i2",), np.zeros(1), np.array([[10.0]]), 20.0, 40.0)


def pair(t_s: float, i2_ratio: float = 1.0, coupling_2: float = 0.0) -> tuple[WindowIndicators, WindowIndicators]:
    """Bogie 1 healthy; bogie 2's I2 i2_ratio times bogie 1's, its couplings all at coupling_2."""
    one = window(np.zeros(N), t_s)
    two = window(np.full(N, coupling_2), t_s)
    return (type(one)(**{**vars(one), "i2": 1.0}), type(two)(**{**vars(two), "i2": i2_ratio}))


def run(judge: WagonJudge, n: int, **kwargs: float) -> list:
    verdicts = []
    for i in range(n):
        w1, w2 = pair(HOP_S * i, **kwargs)
        verdicts.append(judge.judge(w1, w2))
    return verdicts


def test_a_healthy_pair_gives_sister_evidence_and_no_event() -> None:
    verdicts = run(WagonJudge(WagonSettings((BOGIE, BOGIE), {"full": SISTER})), 6)
    assert all(v.sister is not None and v.sister.score == 0.0 and not v.events for v in verdicts)
    assert all(v.verdicts[0].outcome is Outcome.JUDGED for v in verdicts)


def test_the_sister_confirms_the_bogie_whose_own_couplings_moved_and_only_that_one() -> None:
    # Bogie 2's I2 doubled (sister score 48 >= 40) and its couplings moved a little: an own score of
    # 3.6, below its own warning of 20, yet clearly above bogie 1's 0.
    judge = WagonJudge(WagonSettings((BOGIE, BOGIE), {"full": SISTER}))
    verdicts = run(judge, 5, i2_ratio=2.0, coupling_2=0.06)
    assert verdicts[0].sister is not None and verdicts[0].sister.score == pytest.approx((10 * math.log(2.0)) ** 2)
    assert verdicts[0].sister.blamed == 2
    confirmed = [e for v in verdicts for e in v.events if e.kind.value == "CONFIRMED"]
    assert len(confirmed) == 1 and confirmed[0].bogie == "2" and SISTER_SCORE in confirmed[0].indicators
    assert confirmed[0].details.sister is not None and confirmed[0].details.sister.blamed == 2
    assert verdicts[-1].modes == (Mode.NORMAL, Mode.CONFIRMED)
    assert SISTER_SCORE not in verdicts[-1].verdicts[0].judgement.values  # bogie 1 never judged by it


def test_without_sister_baselines_each_bogie_is_judged_alone() -> None:
    verdicts = run(WagonJudge(WagonSettings((BOGIE, BOGIE))), 5, i2_ratio=2.0, coupling_2=0.06)
    assert all(v.sister is None and not v.events for v in verdicts)


def test_neither_bogie_is_named_when_their_own_scores_do_not_tell_them_apart() -> None:
    verdicts = run(WagonJudge(WagonSettings((BOGIE, BOGIE), {"full": SISTER})), 5, i2_ratio=2.0)
    assert all(v.sister is not None and v.sister.blamed is None and not v.events for v in verdicts)


def test_a_sensor_fault_on_bogie_2_gives_no_sister_evidence_and_never_blames_bogie_1() -> None:
    judge = WagonJudge(WagonSettings((BOGIE, BOGIE), {"full": SISTER}))
    faulty = (SensorStatus.OK, SensorStatus.SENSOR_FAULT, SensorStatus.OK)
    events: list[Event] = []
    for i in range(6):
        w1, w2 = pair(HOP_S * i, i2_ratio=5.0, coupling_2=0.0)
        verdict = judge.judge(w1, w2, status=(ALL_OK, faulty))
        assert verdict.sister is None and verdict.verdicts[1].outcome is Outcome.SENSOR
        events += verdict.events
    assert {(e.kind.value, e.bogie) for e in events} == {("SENSOR_FAULT", "2")}


def test_windows_that_do_not_cover_the_same_time_are_refused() -> None:
    w1, _ = pair(0.0)
    _, w2 = pair(3 * HOP_S)
    with pytest.raises(ValueError, match="not aligned"):
        WagonJudge(WagonSettings((BOGIE, BOGIE))).judge(w1, w2)


def test_the_judges_state_survives_a_restart() -> None:
    judge = WagonJudge(WagonSettings((BOGIE, BOGIE), {"full": SISTER}))
    run(judge, 2, i2_ratio=2.0, coupling_2=0.06)
    again = WagonJudge(judge.settings, judge.state_dict())
    w1, w2 = pair(2 * HOP_S, i2_ratio=2.0, coupling_2=0.06)
    assert [e.bogie for e in again.judge(w1, w2).events if e.kind.value == "CONFIRMED"] == ["2"]
