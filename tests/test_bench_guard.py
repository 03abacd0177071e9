"""The bench's regression guard (bench/guard.py): the comparison, the machine class, the records file.

Its logic only: no timing is measured or asserted here.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import guard  # noqa: E402
from guard import GuardError, MachineClass, Record  # noqa: E402
from timing import Figure  # noqa: E402

EPYC = MachineClass("x86_64", "AMD EPYC", 2)
GATEWAY = MachineClass("aarch64", "Raspberry Pi Compute Module 4 Rev 1.1", 4)
KEY = "daemon_can_cpu_s_per_h"


def figure(median: float, key: str = KEY, target: float | None = 72.0) -> Figure:
    return Figure.of(key, "daemon, CAN", "CPU s/h", [median], "make bench-daemon", higher_is_better=False, target=target)


def record(median: float, machine: MachineClass = EPYC, key: str = KEY, date: str = "2026-12-03T18:00:00+00:00") -> Record:
    return Record(machine, key, "CPU s/h", median, median, median, 3, date, "e8f3d9f0", "bench/bench_daemon.py --record")


def test_cpu_model_of_reads_the_model_name_of_an_x86_cpuinfo() -> None:
    cpuinfo = "processor\t: 0\nvendor_id\t: AuthenticAMD\nmodel name\t: AMD EPYC\nflags\t\t: fpu\n\nprocessor\t: 1\nmodel name\t: AMD EPYC\n"
    assert guard.cpu_model_of(cpuinfo) == "AMD EPYC"


def test_cpu_model_of_an_arm_cpuinfo_without_a_model_name_is_the_board_then_the_cpu_part() -> None:
    cpuinfo = "processor\t: 0\nBogoMIPS\t: 108.00\nCPU implementer\t: 0x41\nCPU part\t: 0xd08\n"
    assert guard.cpu_model_of(cpuinfo, "Raspberry Pi Compute Module 4 Rev 1.1\x00") == "Raspberry Pi Compute Module 4 Rev 1.1"
    assert guard.cpu_model_of(cpuinfo, "") == "implementer 0x41 part 0xd08"


def test_the_target_is_25_percent_above_the_last_record_of_the_same_machine_class() -> None:
    judged = guard.judge(figure(20.0), record(16.0), EPYC)
    assert judged.target == pytest.approx(20.0)
    assert judged.meets_target is True  # exactly +25 % still passes


def test_a_figure_more_than_25_percent_above_the_record_is_missed_though_within_the_budget() -> None:
    judged = guard.judge(figure(20.1), record(16.0), EPYC)
    assert judged.meets_target is False
    assert guard.missed([judged]) == [judged]


def test_the_absolute_budget_stays_the_target_when_it_is_below_the_record_plus_25_percent() -> None:
    judged = guard.judge(figure(70.0), record(60.0), EPYC)
    assert judged.target == 72.0


def test_a_machine_class_without_a_record_keeps_the_absolute_target_and_says_so() -> None:
    judged = guard.judge(figure(69.1), None, GATEWAY)
    assert judged.target == 72.0 and judged.meets_target is True
    assert "no record for this machine class (aarch64, Raspberry Pi Compute Module 4 Rev 1.1, 4 cores)" in judged.note


def test_a_figure_the_guard_does_not_watch_is_left_as_it_is() -> None:
    latency = figure(0.3, key="daemon_can_latency_s", target=None)
    assert guard.judge(latency, record(0.1, key="daemon_can_latency_s"), EPYC) == latency


def test_the_record_in_force_is_the_last_appended_for_that_machine_class_and_figure() -> None:
    records = [
        record(30.0, date="2026-12-01T00:00:00+00:00"),
        record(16.0, date="2026-12-03T00:00:00+00:00"),
        record(9.0, machine=GATEWAY),
        record(40.0, key="daemon_can_per_node_cpu_s_per_h"),
    ]
    assert guard.last_record(records, EPYC, KEY) == records[1]
    assert guard.last_record(records, GATEWAY, KEY) == records[2]
    assert guard.last_record(records, MachineClass("x86_64", "AMD EPYC", 4), KEY) is None  # another core count is another class


def test_records_come_back_from_the_file_as_they_were_written(tmp_path: Path) -> None:
    path = tmp_path / "records.json"
    records = [record(16.0), record(9.0, machine=GATEWAY)]
    guard.save_records(records, path)
    assert guard.load_records(path) == records
    data = json.loads(path.read_text())
    assert data["format"] == guard.FORMAT and data["records"][1]["machine"] == {"arch": "aarch64", "cpu_model": GATEWAY.cpu_model, "cores": 4}


def test_no_records_file_means_no_records(tmp_path: Path) -> None:
    assert guard.load_records(tmp_path / "records.json") == []


@pytest.mark.parametrize("text", ['{"format": 99, "records": []}', "not json", '{"format": 1, "records": [{"key": "x"}]}'])
def test_a_records_file_that_does_not_parse_is_refused_naming_it(tmp_path: Path, text: str) -> None:
    path = tmp_path / "records.json"
    path.write_text(text)
    with pytest.raises(GuardError, match="records.json"):
        guard.load_records(path)


def test_a_record_in_another_unit_is_refused() -> None:
    with pytest.raises(GuardError, match="recorded in MB"):
        guard.judge(figure(20.0), replace(record(16.0), unit="MB"), EPYC)


def test_a_missed_figure_is_recorded_only_when_a_worse_figure_is_accepted() -> None:
    worse = guard.judge(figure(30.0), record(16.0), EPYC)
    kept, refused = guard.to_record([record(16.0)], [worse], EPYC, "2026-12-04T00:00:00+00:00", "abc", "cmd")
    assert kept == [record(16.0)] and len(refused) == 1 and "not recorded" in refused[0]
    accepted, refused = guard.to_record([record(16.0)], [worse], EPYC, "2026-12-04T00:00:00+00:00", "abc", "cmd", accept_worse=True)
    assert refused == [] and accepted[-1].median == 30.0 and guard.last_record(accepted, EPYC, KEY) == accepted[-1]


def test_check_writes_records_only_when_asked_and_never_from_a_quick_run(tmp_path: Path) -> None:
    path = tmp_path / "records.json"
    measured = [figure(20.0), figure(0.3, key="daemon_can_latency_s", target=None)]
    assert guard.check(measured, "cmd", path=path).status == 0
    assert not path.exists()
    guard.check(measured, "cmd", record=True, quick=True, path=path)
    assert not path.exists()
    outcome = guard.check(measured, "cmd", record=True, path=path)
    assert [r.key for r in guard.load_records(path)] == [KEY]  # only the guarded figure
    assert outcome.status == 0


def test_check_exits_1_on_a_regression_against_this_machines_record(tmp_path: Path) -> None:
    path = tmp_path / "records.json"
    guard.save_records([record(16.0, machine=guard.machine_class())], path)
    outcome = guard.check([figure(21.0)], "cmd", record=True, path=path)
    assert outcome.status == 1
    assert any("MISSED" in m for m in outcome.messages) and any("not recorded" in m for m in outcome.messages)
    assert len(guard.load_records(path)) == 1
