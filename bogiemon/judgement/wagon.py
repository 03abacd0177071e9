"""One verdict per pair of aligned windows of a wagon's two bogies: each bogie's own verdict with
the sister evidence (judgement/sister.py) combined into its one decision.

    judge = WagonJudge(WagonSettings((settings_1, settings_2), sister=baselines))
    verdict = judge.judge(window_1, window_2)      # the windows that cover the same time
    verdict.verdicts[0].mode, verdict.events       # events name their bogie (Event.bogie)

HOW THE EVIDENCE IS COMBINED. Each bogie keeps its own judge (WindowJudge: sensors, gating, load
state, its fused score against its own baseline, trend, diagnosis). Both windows are prepared
first (WindowJudge.prepare); when both are judgeable in one load state, the pair's sister evidence
is computed and, where it names a bogie, its score joins that bogie's window as one more judged
value with its own limit (Decider.update's extra): an alarm of it counts in the same k of n as
the window's own alarms, a warning in SUSPECTED's, and CLEARED asks for both to be quiet. So a
fault is confirmed once, on its bogie, by whichever evidence (or both together) reaches k of n
first, and the other bogie's decision never sees it. docs/wagon.md measures why: the difference
between the bogies is the better reference for the amplitudes (their spread 5 to 50 times smaller
than one bogie's across tracks and speeds), each bogie's own for its couplings (its spread about
as small, and a fault's shift shows in full on its own bogie, halved against noise in a difference).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from bogiemon.detection import WindowIndicators
from bogiemon.drivers.base import ALL_OK
from bogiemon.judgement.events import ConfirmedDetails, Event, SuspectedDetails
from bogiemon.judgement.models import finite_or_none
from bogiemon.judgement.sister import SisterBaseline, SisterEvidence, feature_vector, sister_evidence
from bogiemon.judgement.verdict import MonitorSettings, Prepared, Status, WindowCounts, WindowJudge, WindowVerdict
from bogiemon.judgement.vocabulary import LoadState, Mode

BOGIE_IDS = ("1", "2")
# Two windows of one pair cover the same time to within this share of a hop.
ALIGNMENT_HOPS = 0.5


@dataclass(frozen=True)
class WagonSettings:
    """Each bogie's settings (bogie 1's, then bogie 2's), their ids as events name them, and the
    sister baselines in force per load state (none: each bogie judged alone)."""

    bogies: tuple[MonitorSettings, MonitorSettings]
    sister: Mapping[str, SisterBaseline] = dataclasses.field(default_factory=dict)
    ids: tuple[str, str] = BOGIE_IDS
    blame_ratio: float = 2.0  # judgement/sister.py BLAME_RATIO


@dataclass(frozen=True)
class WagonVerdict:
    """Both bogies' verdicts of one pair of windows, the sister evidence (None: the pair gave none)
    and every event of the pair, each naming its bogie."""

    verdicts: tuple[WindowVerdict, WindowVerdict]
    sister: SisterEvidence | None
    events: tuple[Event, ...]

    @property
    def modes(self) -> tuple[Mode, Mode]:
        return (self.verdicts[0].mode, self.verdicts[1].mode)


class WagonJudge:
    """The two bogies' judges and the sister evidence between them (module docstring)."""

    def __init__(self, settings: WagonSettings, saved: Sequence[Mapping[str, Any] | None] = (None, None), counts: Sequence[WindowCounts] | None = None) -> None:
        self.settings = settings
        tallies = tuple(counts) if counts is not None else (WindowCounts(), WindowCounts())
        self.judges = tuple(WindowJudge.restore(s, state, c) for s, state, c in zip(settings.bogies, saved, tallies, strict=True))

    def state_dict(self) -> list[dict[str, Any]]:
        """Each bogie's judge state (WindowJudge.state_dict), bogie 1's first."""
        return [j.state_dict() for j in self.judges]

    def judge(
        self, window_1: WindowIndicators, window_2: WindowIndicators, status: tuple[Status, Status] = (ALL_OK, ALL_OK), gaps_last_hour: tuple[int, int] = (0, 0)
    ) -> WagonVerdict:
        """The verdict of one pair of windows that cover the same time (ValueError otherwise)."""
        hop_s = self.settings.bogies[0].processing.hop_s
        if abs(window_1.start_s - window_2.start_s) > ALIGNMENT_HOPS * hop_s:
            raise ValueError(f"the bogies' windows are not aligned: they start at {window_1.start_s:.3f} and {window_2.start_s:.3f} s")
        prepared = (self.judges[0].prepare(window_1, status[0], gaps_last_hour[0]), self.judges[1].prepare(window_2, status[1], gaps_last_hour[1]))
        evidence = self.evidence(prepared[0], prepared[1])
        verdicts = tuple(j.conclude(p, evidence.extra_for(k + 1) if evidence else None) for k, (j, p) in enumerate(zip(self.judges, prepared, strict=True)))
        events = tuple(self._named(e, k, evidence) for k, v in enumerate(verdicts) for e in v.events)
        return WagonVerdict((verdicts[0], verdicts[1]), evidence, events)

    def evidence(self, p1: Prepared, p2: Prepared) -> SisterEvidence | None:
        """The pair's sister evidence; None unless both windows are judgeable in one load state
        with a sister baseline for it and every feature finite on both bogies."""
        if not (p1.judgeable and p2.judgeable and p1.choice is not None and p2.choice is not None):
            return None
        load = p1.choice.load
        baseline = self.settings.sister.get(load) if load is not None else None
        if load is None or baseline is None or p2.choice.load != load:
            return None
        x1 = feature_vector(p1.window, p1.features, baseline.features)
        x2 = feature_vector(p2.window, p2.features, baseline.features)
        if x1 is None or x2 is None:
            return None
        own = [self._own_score(k, p, load) for k, p in enumerate((p1, p2))]
        return sister_evidence(x2 - x1, baseline, own[0], own[1], self.settings.blame_ratio)

    def _own_score(self, k: int, p: Prepared, load: LoadState) -> float:
        """Bogie k's own coupling score against its own fused baseline (NaN without one)."""
        own = self.settings.bogies[k].decision.baselines.get(load)
        x = finite_or_none(p.features.coupling) if p.features is not None else None
        return float(own.score(x)) if own is not None and x is not None else float(np.nan)

    def _named(self, event: Event, k: int, evidence: SisterEvidence | None) -> Event:
        details = event.details
        if evidence is not None and isinstance(details, SuspectedDetails | ConfirmedDetails):
            details = dataclasses.replace(details, sister=evidence.details())
        return dataclasses.replace(event, bogie=self.settings.ids[k], details=details)
