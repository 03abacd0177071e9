"""A commissioning never covers everything (issue 26): running it never met is judged, with its
levels raised where the excitation lies outside the commissioning's, and never alarms while the
wagon is healthy; a fault whose windows lie outside every commissioned load state is reported."""

from __future__ import annotations

from pathlib import Path

import pytest

from bogiemon.daemon.calibrate import calibrate_loads, fragment
from bogiemon.daemon.config import BogiemonConfig, load_config
from bogiemon.judgement.models import load_features
from bogiemon.judgement.verdict import Outcome, WindowJudge, WindowVerdict
from bogiemon.judgement.vocabulary import LoadState
from bogiemon.detection import Corner, IndicatorStream
from bogiemon.simulator import Fault, Scenario, SpeedProfile, simulate, simulate_batch
from bogiemon.simulator.run import write_recording
from bogiemon.judgement.events import ConfirmedDetails
from tests.judgement.event_examples import details_as

CONFIG = load_config(None)
ALARMS = {"SUSPECTED", "CONFIRMED"}


def _scenario(load: str, seed: int, track: str, speed_kmh: float, faults: tuple[Fault, ...] = ()) -> Scenario:
    return Scenario(load=load, track=track, speed=SpeedProfile.constant(speed_kmh), duration_s=300.0, seed=seed, faults=faults)


def _commission(folder: Path, paths: dict[str, list[Path]]) -> BogiemonConfig:
    (folder / "calibration.toml").write_text(fragment(calibrate_loads(paths, CONFIG)))
    (folder / "bogiemon.toml").write_text('include = ["calibration.toml"]\n[decision]\nload = "auto"\n')
    return load_config(folder / "bogiemon.toml")


@pytest.fixture(scope="module")
def narrow(tmp_path_factory: pytest.TempPathFactory) -> dict[str, BogiemonConfig]:
    """Two wagons' configs from the same narrow commissioning, one track quality (ERRI low) at 80 and
    95 km/h: "both" commissioned both loads, "full" only the loaded wagon."""
    folder = tmp_path_factory.mktemp("narrow")
    plan = [(load, seed, speed) for load in ("full", "tare") for seed, speed in ((31, 80.0), (32, 95.0))]
    runs = simulate_batch([_scenario(load, seed, "erri-low", speed) for load, seed, speed in plan])
    paths: dict[str, list[Path]] = {"full": [], "tare": []}
    for (load, seed, _), run in zip(plan, runs, strict=True):
        write_recording(run, folder / f"{load}-{seed}.csv")
        paths[load].append(folder / f"{load}-{seed}.csv")
    (folder / "both").mkdir()
    (folder / "full").mkdir()
    return {"both": _commission(folder / "both", paths), "full": _commission(folder / "full", {"full": paths["full"]})}


def _judge(config: BogiemonConfig, scenario: Scenario) -> list[WindowVerdict]:
    stream = IndicatorStream(config.processing_settings(scenario.fs_hz), config.bogie_geometry())
    judge = WindowJudge(config.monitor_settings())
    return [judge.judge(w) for w in stream.process(simulate(scenario).accel_mps2)]


def _kinds(verdicts: list[WindowVerdict]) -> set[str]:
    return {e.kind.value for v in verdicts for e in v.events}


def _judged_share(verdicts: list[WindowVerdict]) -> float:
    moving = [v for v in verdicts if v.outcome is not Outcome.GATED]
    assert moving, "the run should move the wagon"
    return sum(v.outcome is Outcome.JUDGED for v in moving) / len(moving)


def test_a_track_quality_the_commissioning_never_ran_is_judged_with_raised_levels_and_no_alarm(narrow) -> None:
    # FRA class 5 shakes the frame about twice as hard as anything the commissioning ran.
    verdicts = _judge(narrow["both"], _scenario("full", 41, "fra-5", 80.0))
    assert _judged_share(verdicts) == 1.0 and not _kinds(verdicts) & ALARMS
    judged = [v.judgement for v in verdicts if v.judgement is not None]
    assert all(j.level_margin > 1.0 for j in judged)
    assert {v.load for v in verdicts if v.judgement is not None} == {LoadState.FULL}


def test_speeds_below_the_commissioning_are_judged_and_raise_no_alarm(narrow) -> None:
    verdicts = _judge(narrow["both"], _scenario("full", 42, "erri-low", 60.0))
    assert _judged_share(verdicts) >= 0.9 and not _kinds(verdicts) & ALARMS
    assert {v.load for v in verdicts if v.judgement is not None} == {LoadState.FULL}


def test_a_load_the_commissioning_never_ran_is_judged_against_the_population_and_raises_no_alarm(narrow) -> None:
    verdicts = _judge(narrow["full"], _scenario("tare", 43, "erri-low", 80.0))
    assert _judged_share(verdicts) == 1.0 and not _kinds(verdicts) & ALARMS
    judged = [v for v in verdicts if v.judgement is not None]
    assert {v.load for v in judged} == {LoadState.TARE} and {v.judgement.baseline for v in judged if v.judgement} == {"population"}


def test_a_fault_whose_windows_lie_outside_every_commissioned_load_state_is_reported(narrow) -> None:
    # A broken rear outer coil in the empty wagon moves its load vector (how the modes share their
    # power between the bands) beyond what either commissioned state's windows reached: the gate
    # that once left such windows unjudged kept this fault silent. Judged, it is confirmed.
    config = narrow["both"]
    broken = Fault(kind="type_a", corner=Corner.LEADING_LEFT, position="rear_outer", severity=0.0)
    verdicts = _judge(config, _scenario("tare", 44, "erri-low", 80.0, (broken,)))
    states = config.load_signatures()
    outside = [v for v in verdicts if (x := load_features(v.window, config.bogie_geometry())) is not None and all(s.distance(x) > s.limit for s in states)]
    assert len(outside) >= 0.8 * len(verdicts)
    assert all(v.outcome is Outcome.JUDGED for v in outside)
    assert "CONFIRMED" in _kinds(verdicts)
    confirmed = next(e for v in verdicts for e in v.events if e.kind.value == "CONFIRMED")
    details = details_as(confirmed, ConfirmedDetails)
    assert details.load is LoadState.TARE and details.running is not None and details.running.load_distance is not None
    assert details.running.load_distance > 1.0
