"""The simulated fleet (lab/fleetsim.py): the recordings tree of docs/fleet-formats.md section 1,
its truth, faults only from their day on, and byte-identical trees from one seeded plan.

The tiny plan is simulated once for the module (about 10 s); the determinism test simulates it
a second time.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import hashlib
import itertools
import json
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from bogiemon.daemon.config import load_config
from bogiemon.detection import PAPER_LAYOUT, Corner
from bogiemon.drivers.recording import Recording, read_csv_recording
from bogiemon.lab.fleetsim import FaultOnset, FleetPlan, FleetSimError, FleetTruth, SensorOnset, simulate_fleet
from bogiemon.lab.robust.fleet import MIRROR, draw_conditions

PLAN = FleetPlan.tiny()
WAGON_ID = re.compile(r"^[A-Za-z0-9_\-][A-Za-z0-9_.\-]{0,63}$")  # the contract's folder names


@pytest.fixture(scope="module")
def tree(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, FleetTruth, list[float]]:
    root = tmp_path_factory.mktemp("fleetsim") / "FLEET"
    fractions: list[float] = []
    truth = simulate_fleet(root, PLAN, fractions.append)
    return root, truth, fractions


@pytest.fixture(scope="module")
def recordings(tree) -> dict[str, Recording]:
    """Every recording of the tree, by its path relative to the root, as the back office reads it."""
    root, _, _ = tree
    return {p.relative_to(root).as_posix(): read_csv_recording(p) for p in sorted(root.glob("*/*/*.csv.gz"))}


def truth_json(root: Path) -> dict:
    return json.loads((root / "truth.json").read_text(encoding="utf-8"))


# ---- the plan


def test_the_demo_plan_puts_full_load_faults_on_full_load_wagons_and_the_damage_on_a_tare_one() -> None:
    plan = FleetPlan()
    assert (plan.n_wagons, plan.days, plan.commission_runs, plan.runs_per_day, plan.run_s) == (8, 3, 6, 3, 600.0)
    assert [(f.key, f.severity, f.corner, f.day) for f in plan.faults] == [
        ("type_a.full.rear_outer", 0.0, Corner.LEADING_LEFT, 2),
        ("type_a.full.rear_outer", 0.0, Corner.TRAILING_LEFT, 1),
    ]
    assert all(plan.wagon_load(f.wagon) == f.load == "full" for f in plan.faults)
    assert len({f.wagon for f in plan.faults}) == 2
    assert [(plan.wagon_load(d.wagon), d.damage, d.day) for d in plan.sensor_damages] == [("tare", "noisy a3", 2)]


def test_every_run_of_a_plan_has_its_own_seed_and_another_fleet_seed_gives_others() -> None:
    runs = FleetPlan().runs()
    seeds = {r.seed for r in runs}
    assert len(seeds) == len(runs) == 8 * (6 + 2 * 3)
    assert seeds.isdisjoint({r.seed for r in FleetPlan(fleet_seed=7).runs()})
    assert FleetPlan().wagon_seed(0) != FleetPlan(fleet_seed=7).wagon_seed(0)


def test_a_fault_changes_nothing_else_of_the_runs_conditions() -> None:
    with_faults, without = PLAN.runs(), dataclasses.replace(PLAN, faults=(), sensor_damages=()).runs()
    assert [r.seed for r in with_faults] == [r.seed for r in without]
    assert [draw_conditions(r) for r in with_faults] == [draw_conditions(r) for r in without]
    assert [r.key for r in with_faults] != [r.key for r in without]


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"faults": (FaultOnset(1, 1, "type_a.full.rear_outer", 0.0, Corner.LEADING_LEFT),)}, "full-load case, wagon 1 runs tare"),
        ({"faults": (FaultOnset(0, 0, "type_a.full.rear_outer", 0.0, Corner.LEADING_LEFT),)}, "day 0 is the healthy commissioning"),
        ({"faults": (FaultOnset(3, 1, "type_a.full.rear_outer", 0.0, Corner.LEADING_LEFT),)}, "the plan's wagons are 0..2"),
        ({"sensor_damages": (SensorOnset(1, 2, "noisy a3"),)}, "a day of 1..1"),
        (
            {"faults": (FaultOnset(0, 1, "type_b.full", 0.5, Corner.LEADING_LEFT), FaultOnset(0, 1, "type_b.full", 1.5, Corner.TRAILING_LEFT))},
            "wagon 0 has more than one fault",
        ),
        ({"runs_per_day": 13}, "end after midnight"),
        ({"run_every_s": 300.0}, "would overlap"),
        ({"start_date": "2026-13-01"}, "start_date must be a date"),
        ({"loads": ("full", "empty", "tare")}, "loads must name 'full' or 'tare'"),
    ],
)
def test_a_plan_that_cannot_be_simulated_is_refused_naming_why(change: dict, words: str) -> None:
    with pytest.raises(FleetSimError, match=re.escape(words)):
        dataclasses.replace(PLAN, **change)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        ((0, 1, "type_a.full.middle_outer", 0.0, "leading-left"), "unknown case 'type_a.full.middle_outer'"),
        ((0, 1, "type_a.full.rear_outer", 0.25, "leading-left"), "has no severity 0.25"),
        ((0, 1, "type_a.full.rear_outer", 0.0, "middle-left"), "unknown corner 'middle-left'"),
    ],
)
def test_a_fault_that_is_no_case_of_the_papers_tables_is_refused(args: tuple, words: str) -> None:
    with pytest.raises(FleetSimError, match=re.escape(words)):
        FaultOnset(*args)


def test_a_corner_given_by_name_becomes_the_corner() -> None:
    assert FaultOnset(0, 1, "type_a.full.rear_outer", 0.0, "trailing-right").corner is Corner.TRAILING_RIGHT  # type: ignore[arg-type]


def test_an_unknown_sensor_damage_is_refused() -> None:
    with pytest.raises(FleetSimError, match="unknown 'wet a4'"):
        SensorOnset(0, 1, "wet a4")


def test_a_folder_that_is_not_empty_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    (tmp_path / "keeper.txt").write_text("real recordings")
    with pytest.raises(FleetSimError, match="not an empty folder"):
        simulate_fleet(tmp_path, PLAN)
    assert [p.name for p in tmp_path.iterdir()] == ["keeper.txt"]


# ---- the tree


def test_the_top_of_the_tree_holds_fleet_toml_truth_json_and_one_folder_per_wagon(tree) -> None:
    root, _, _ = tree
    ids = [PLAN.wagon_id(w) for w in range(PLAN.n_wagons)]
    assert ids == ["31-80-4557-001", "31-80-4557-002", "31-80-4557-003"]
    assert all(WAGON_ID.match(i) for i in ids)
    assert sorted(p.name for p in root.iterdir()) == sorted([*ids, "fleet.toml", "truth.json"])


def test_fleet_toml_names_the_fleet_and_lists_every_wagon_with_its_type(tree) -> None:
    root, _, _ = tree
    fleet = tomllib.loads((root / "fleet.toml").read_text(encoding="utf-8"))
    assert fleet["fleet"] == {"name": PLAN.name, "default_type": "Sgns-Y25"}
    assert fleet["wagons"] == {PLAN.wagon_id(w): {"type": "Sgns-Y25"} for w in range(PLAN.n_wagons)}


def test_every_wagon_has_a_config_load_config_accepts_and_no_calibration(tree) -> None:
    root, _, _ = tree
    for w in range(PLAN.n_wagons):
        folder = root / PLAN.wagon_id(w)
        config = load_config(folder / "bogiemon.toml", log_warnings=False)
        assert config.bogie_geometry().corners == PAPER_LAYOUT
        assert (config.decision.load, config.wagon.id, config.processing.fs_hz) == ("auto", folder.name, PLAN.fs_hz)
        assert not (folder / "calibration.toml").exists()


def test_day_folders_are_the_plans_dates_each_holding_its_runs(tree) -> None:
    root, _, _ = tree
    for w in range(PLAN.n_wagons):
        days = sorted(p for p in (root / PLAN.wagon_id(w)).iterdir() if p.is_dir())
        assert [p.name for p in days] == ["2026-11-02", "2026-11-03"]
        assert [sorted(f.name for f in d.iterdir()) for d in days] == [
            ["060000_run1.csv.gz", "073000_run2.csv.gz", "090000_run3.csv.gz"],
            ["060000_run1.csv.gz", "073000_run2.csv.gz"],
        ]


def test_recordings_are_gzip_without_a_time_stamp(tree) -> None:
    root, _, _ = tree
    paths = list(root.glob("*/*/*.csv.gz"))
    assert len(paths) == 15
    for path in paths:
        head = path.read_bytes()[:8]
        assert head[:2] == b"\x1f\x8b" and head[4:8] == b"\0\0\0\0"


def test_every_recording_reads_back_at_the_plans_rate_and_length(recordings) -> None:
    assert len(recordings) == 15
    for rec in recordings.values():
        assert rec.n_samples == int(PLAN.run_s * PLAN.fs_hz)
        assert rec.fs_hz == pytest.approx(PLAN.fs_hz, rel=1e-9)


def test_the_recordings_are_compressed_at_zlibs_fastest_level(tree) -> None:
    root, _, _ = tree
    files = sorted(root.glob("*/*/*.csv.gz"))
    assert len(files) == 15 and {f.read_bytes()[8] for f in files} == {4}  # gzip's header: 4 is the fastest level


def test_recording_times_are_unix_seconds_within_their_day_folders_date_at_the_planned_start(recordings, tree) -> None:
    _, truth, _ = tree
    starts = {r.file: r.start_s for w in truth.wagons for r in w.runs}
    for name, rec in recordings.items():
        folder_date = name.split("/")[1]
        for t in (rec.time_s[0], rec.time_s[-1]):
            assert dt.datetime.fromtimestamp(float(t), tz=dt.UTC).date().isoformat() == folder_date
        assert rec.time_s[0] == starts[name]
        assert dt.datetime.fromtimestamp(float(rec.time_s[0]), tz=dt.UTC).strftime("%H%M%S") == name.split("/")[2][:6]


def test_a_wagons_recordings_do_not_overlap(recordings) -> None:
    for w in range(PLAN.n_wagons):
        spans = sorted((float(r.time_s[0]), float(r.time_s[-1])) for n, r in recordings.items() if n.startswith(PLAN.wagon_id(w)))
        assert len(spans) == 5
        assert all(later[0] > earlier[1] for earlier, later in itertools.pairwise(spans))


def test_no_temporary_file_is_left_in_the_tree(tree) -> None:
    root, _, _ = tree
    assert [p for p in root.rglob(".*")] == []


def test_progress_rises_from_zero_to_one(tree) -> None:
    _, _, fractions = tree
    assert fractions[0] == 0.0 and fractions[-1] == 1.0
    assert all(b >= a for a, b in itertools.pairwise(fractions))
    assert len(fractions) > 10


# ---- the truth


def test_truth_json_is_the_returned_truth(tree) -> None:
    root, truth, _ = tree
    assert truth_json(root) == json.loads(json.dumps(truth.to_dict()))


def test_truth_states_each_wagons_load_faults_and_damages_as_planned(tree) -> None:
    root, _, _ = tree
    wagons = truth_json(root)["wagons"]
    assert [(w["wagon"], w["load"], w["type"]) for w in wagons] == [
        ("31-80-4557-001", "full", "Sgns-Y25"),
        ("31-80-4557-002", "tare", "Sgns-Y25"),
        ("31-80-4557-003", "full", "Sgns-Y25"),
    ]
    assert wagons[0]["faults"] == [
        {"day": 1, "date": "2026-11-03", "corner": "leading-left", "key": "type_a.full.rear_outer", "severity": 0.0, "kind": "spring-softer"}
    ]
    assert wagons[1]["sensor_damages"] == [{"day": 1, "date": "2026-11-03", "damage": "noisy a3", "problem": "noisy", "channels": ["a3"]}]
    assert [w["faults"] for w in wagons[1:]] == [[], []]
    assert [w["sensor_damages"] for w in (wagons[0], wagons[2])] == [[], []]


def test_truths_run_list_names_exactly_the_recordings_written(tree) -> None:
    root, _, _ = tree
    files = [r["file"] for w in truth_json(root)["wagons"] for r in w["runs"]]
    assert sorted(files) == sorted(p.relative_to(root).as_posix() for p in root.glob("*/*/*.csv.gz"))
    assert len(files) == len(set(files)) == 15


def test_runs_differ_in_track_speed_or_direction(tree) -> None:
    root, _, _ = tree
    runs = [r for w in truth_json(root)["wagons"] for r in w["runs"]]
    assert len({r["mean_speed_kmh"] for r in runs}) == len(runs)
    assert all(50.0 <= r["mean_speed_kmh"] <= 110.0 for r in runs)
    assert len({r["track"] for r in runs}) > 1 and len({r["reversed"] for r in runs}) == 2


def test_the_fault_is_simulated_from_its_days_first_run_on_and_never_before(tree) -> None:
    root, _, _ = tree
    wagons = truth_json(root)["wagons"]
    faulty = wagons[0]["runs"]
    assert [r["simulated_faults"] for r in faulty if r["day"] == 0] == [[], [], []]
    later = [r for r in faulty if r["day"] == 1]
    assert len(later) == 2
    for r in later:
        # The simulator's corner is the physical one: a reversed run mirrors the config's corner.
        corner = MIRROR[Corner.LEADING_LEFT] if r["reversed"] else Corner.LEADING_LEFT
        assert r["simulated_faults"] == [f"type_a:rear_outer:0.0@{corner.value}"]
    assert all(r["simulated_faults"] == [] for w in wagons[1:] for r in w["runs"])


def test_the_damaged_sensor_is_noisy_in_the_recordings_from_its_day_on_only(tree, recordings) -> None:
    root, _, _ = tree
    wagon = truth_json(root)["wagons"][1]
    assert [r["damage"] for r in wagon["runs"]] == [None, None, None, "noisy a3", "noisy a3"]
    for r in wagon["runs"]:
        var = np.var(recordings[r["file"]].accel_mps2, axis=0)
        # On the rigid frame the three channels vary alike; the loose a3 adds white noise of 8 m/s^2.
        excess = var[2] - (var[0] + var[1]) / 2
        assert 64.0 - 10.0 < excess < 64.0 + 10.0 if r["damage"] else abs(excess) < 5.0


@pytest.mark.slow
def test_a_seeded_plan_writes_a_byte_identical_tree(tree, tmp_path: Path) -> None:
    root, _, _ = tree
    again = tmp_path / "again"
    simulate_fleet(again, PLAN)

    def digests(folder: Path) -> dict[str, str]:
        return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in folder.rglob("*") if p.is_file()}

    first = digests(root)
    assert len(first) == 15 + 3 + 2  # recordings, wagon configs, fleet.toml and truth.json
    assert digests(again) == first
