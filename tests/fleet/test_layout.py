"""The recordings tree: wagons, configs (and their calibration), days; what is skipped and why."""

from __future__ import annotations

from pathlib import Path

import pytest

from bogiemon.fleet.layout import FleetError, scan_fleet
from tests.fleet.tree import DEMO_CALIBRATION


def _wagon(root: Path, wagon_id: str, config: str | None = "", days: tuple[str, ...] = ("2026-11-02",)) -> Path:
    folder = root / wagon_id
    folder.mkdir(parents=True)
    if config is not None:
        (folder / "bogiemon.toml").write_text(config, encoding="utf-8")
    for day in days:
        (folder / day).mkdir()
        (folder / day / "060000_run.csv.gz").write_bytes(b"")
    return folder


def test_wagons_days_and_types_come_from_the_tree_and_fleet_toml(tmp_path: Path) -> None:
    _wagon(tmp_path, "31-80-001", days=("2026-11-03", "2026-11-02"))
    _wagon(tmp_path, "31-80-002")
    (tmp_path / "fleet.toml").write_text('[fleet]\nname = "Keeper X"\ndefault_type = "Sgns"\n[wagons."31-80-002"]\ntype = "Habbiins"\n')
    fleet = scan_fleet(tmp_path)
    assert fleet.name == "Keeper X"
    assert [(w.wagon_id, w.wagon_type) for w in fleet.wagons] == [("31-80-001", "Sgns"), ("31-80-002", "Habbiins")]
    assert [d.date for d in fleet.wagon("31-80-001").days] == ["2026-11-02", "2026-11-03"]
    assert fleet.issues == ()


def test_a_calibration_beside_the_config_is_merged_over_it(tmp_path: Path) -> None:
    folder = _wagon(tmp_path, "W1", config='[decision]\nload = "full"\n')
    assert scan_fleet(tmp_path).wagon("W1").commissioned == ()
    (folder / "calibration.toml").write_text(DEMO_CALIBRATION.read_text())
    wagon = scan_fleet(tmp_path).wagon("W1")
    assert wagon.commissioned == ("full",) and wagon.config.decision.load == "full"


def test_a_config_named_in_fleet_toml_is_used_instead(tmp_path: Path) -> None:
    _wagon(tmp_path, "W1", config=None)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "w1.toml").write_text('[sensors]\na3 = "trailing-right"\n')
    (tmp_path / "fleet.toml").write_text('[wagons.W1]\nconfig = "configs/w1.toml"\n')
    fleet = scan_fleet(tmp_path)
    assert fleet.wagon("W1").config.sensors.a3.value == "trailing-right"
    assert fleet.issues == ()  # the folder of the configs is no wagon


def test_unusable_parts_are_issues_and_the_rest_is_scanned(tmp_path: Path) -> None:
    _wagon(tmp_path, "good")
    _wagon(tmp_path, "noconfig", config=None)
    _wagon(tmp_path, "typo", config="[decision]\nlaod = 1\n")
    bad_day = _wagon(tmp_path, "baddays", days=())
    (bad_day / "2026-13-45").mkdir()
    (bad_day / "2026-11-02").mkdir()
    (bad_day / "notes.txt").write_text("x")
    (tmp_path / "bad id!").mkdir()
    fleet = scan_fleet(tmp_path)
    reasons = {Path(i.path).name: i.reason for i in fleet.issues}
    assert [w.wagon_id for w in fleet.wagons] == ["baddays", "good"]
    assert "no config" in reasons["noconfig"]
    assert "does not validate" in reasons["bogiemon.toml"] and "laod" in reasons["bogiemon.toml"]
    assert "no date" in reasons["2026-13-45"]
    assert "empty day" in reasons["2026-11-02"]
    assert "not a day folder" in reasons["notes.txt"]
    assert "not a wagon id" in reasons["bad id!"]


@pytest.mark.parametrize(
    ("text", "message"),
    [("[fleet\n", "cannot be read as TOML"), ("[trucks]\n", "unknown table"), ("[fleet]\ncolour = 1\n", "unknown key"),
     ('[wagons.W1]\ntype = 3\n', "expected type")],
)  # fmt: skip
def test_a_broken_fleet_toml_is_one_clear_error(tmp_path: Path, text: str, message: str) -> None:
    (tmp_path / "fleet.toml").write_text(text)
    with pytest.raises(FleetError, match=message):
        scan_fleet(tmp_path)


def test_a_missing_fleet_folder_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FleetError, match="no such fleet folder"):
        scan_fleet(tmp_path / "nowhere")
