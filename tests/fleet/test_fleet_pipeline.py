"""The back office end to end on a small simulated fleet: analyze on a real Dask LocalCluster, judge,
calibrate; offline equals onboard, resume, and bad inputs that never stop the rest."""

from __future__ import annotations

import json
import math
import shutil
import time
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bogiemon.daemon.calibrate import calibrate
from bogiemon.daemon.config import load_config
from bogiemon.daemon.event_json import event_body
from bogiemon.daemon.messages import EventMessage, decode
from bogiemon.judgement.events import Event
from bogiemon.drivers.atomic import temporary_name
from bogiemon.daemon.replay import replay
from bogiemon.daemon.sinks import EventSink
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.fleet.analyze import analyze_fleet, partition_path
from bogiemon.fleet.calibrate import calibrate_wagon
from bogiemon.fleet.cluster import InProcess
from bogiemon.fleet.judge import judge_fleet
from bogiemon.fleet.layout import scan_fleet
from tests.fleet import tree

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def client():
    from bogiemon.fleet.analyze import local_client

    c = local_client(2)
    yield c
    cluster = c.cluster
    c.close()
    cluster.close()


def _worker_settings() -> tuple[str | None, bool, float]:
    import os

    import dask.config
    from dask.utils import parse_timedelta

    return os.environ.get("MALLOC_TRIM_THRESHOLD_"), dask.config.get("distributed.worker.profile.enabled"), parse_timedelta(dask.config.get("distributed.admin.tick.interval"))


def test_the_local_clusters_workers_keep_glibcs_dynamic_mmap_threshold_and_sample_no_profile(client) -> None:
    import os

    assert set(client.run(_worker_settings).values()) == {(None, False, 1.0)}
    assert "MALLOC_TRIM_THRESHOLD_" not in os.environ  # nor set here, in the cluster's process, for what it starts later


def _fleet(root: Path, runs: tree.Runs) -> dict[str, list[Path]]:
    """W1 (commissioned): a healthy day, then a day where the spring breaks; W2 healthy, not commissioned."""
    w1, w2 = tree.wagon(root, "W1", commissioned=True), tree.wagon(root, "W2", commissioned=False)
    return {
        "W1": [
            tree.place(runs.healthy[0], w1, "2026-11-02", "06:00"),
            tree.place(runs.healthy[1], w1, "2026-11-02", "07:30", suffix=".csv"),
            tree.place(runs.healthy[0], w1, "2026-11-03", "06:00"),
            tree.place(runs.faulty, w1, "2026-11-03", "09:00"),
        ],
        "W2": [tree.place(runs.healthy[1], w2, "2026-11-02", "06:00"), tree.place(runs.healthy[0], w2, "2026-11-03", "06:00")],
    }


class _Collect(EventSink):
    def __init__(self) -> None:
        self.events: list[Event] = []

    def publish(self, event: Event) -> None:
        self.events.append(event)


def _comparable(event: Event) -> tuple[object, ...]:
    return (event.kind, event.time_s, event.severity, json.dumps(dict(event.indicators), sort_keys=True),
            json.dumps(event_body(event)["details"], sort_keys=True))  # fmt: skip


def test_fleet_judge_gives_the_same_events_as_replay_of_the_same_recordings(tmp_path: Path, runs: tree.Runs, client) -> None:
    files = _fleet(tmp_path / "fleet", runs)
    analyze_fleet(tmp_path / "fleet", tmp_path / "windows", client=client)
    judge_fleet(tmp_path / "windows", tmp_path / "judged")
    lines = (tmp_path / "judged" / "events.jsonl").read_text().splitlines()
    offline = [json.loads(line) for line in lines]
    offline_w1 = [decode(EventMessage, line.encode()).to_event() for line, e in zip(lines, offline, strict=True) if e["wagon_id"] == "W1"]

    config = scan_fleet(tmp_path / "fleet").wagon("W1").config
    sink = _Collect()
    replay(files["W1"], config, sinks=[sink])

    assert [e.kind.value for e in sink.events] == [e.kind.value for e in offline_w1]
    assert "CONFIRMED" in [e.kind.value for e in offline_w1]
    assert [_comparable(e) for e in offline_w1] == [_comparable(e) for e in sink.events]
    assert [e["seq"] for e in offline if e["wagon_id"] == "W1"] == list(range(1, len(offline_w1) + 1))
    wagons = {w["wagon"]: w for w in json.loads((tmp_path / "judged" / "wagons.json").read_text())["wagons"]}
    # The broken spring's corner, or "unknown" where the confirming windows do not single it out.
    assert wagons["W1"]["state"] == "CONFIRMED" and wagons["W1"]["diagnosis"]["corners"] in (["leading-left", "trailing-right"], [])
    assert wagons["W2"]["state"] == "NORMAL"
    assert next(iter(wagons)) == "W1"  # the most urgent first


def _nan(value: object) -> bool:
    return isinstance(value, float) and math.isnan(value)


def _replayed_row(verdict: WindowVerdict) -> tuple[object, ...]:
    """A window's verdict as the judge's series holds it: end, judged, mode, headline score, any sensor problem."""
    score = verdict.judgement.headline()[0] if verdict.judgement is not None else math.nan
    return (verdict.window.end_s, verdict.judgement is not None, verdict.mode.value, score, bool(verdict.health.problems))


def _series_rows(series: pa.Table) -> list[tuple[object, ...]]:
    columns = [series.column(name).to_pylist() for name in ("time_s", "judged", "mode", "score", "sensor_problems")]
    return [(t, judged, mode, score, bool(problems)) for t, judged, mode, score, problems in zip(*columns, strict=True)]


def test_replay_and_fleet_judge_give_the_same_verdict_on_every_window_of_a_day_of_recordings(tmp_path: Path, runs: tree.Runs) -> None:
    # A day of ten recordings within the hour, each starting as the one before ends, the last one
    # where the spring breaks: nine boundaries, more than the gaps an hour may hold before the
    # sensors are faulted for dropouts (health max_gaps_per_hour, 6). Each boundary between
    # recordings is a new segment, never a dropout of the source: replayed in one call, they are
    # judged as `fleet judge` judges the day (issue 27, 5).
    w1 = tree.wagon(tmp_path / "fleet", "W1", commissioned=True)
    day = "2026-11-02"
    healthy = [tree.place(runs.healthy[i % 2], w1, day, f"06:{5 * i:02d}") for i in range(9)]
    files = [*healthy, tree.place(runs.faulty, w1, day, "06:45")]
    analyze_fleet(tmp_path / "fleet", tmp_path / "windows", runner=InProcess())
    judge_fleet(tmp_path / "windows", tmp_path / "judged")
    offline = _series_rows(pq.read_table(tmp_path / "judged" / "series" / "wagon=W1" / "part-0.parquet"))
    offline_events = [decode(EventMessage, line.encode()).to_event() for line in (tmp_path / "judged" / "events.jsonl").read_text().splitlines()]

    verdicts: list[WindowVerdict] = []
    sink = _Collect()
    replay(files, scan_fleet(tmp_path / "fleet").wagon("W1").config, sinks=[sink], observers=[verdicts.append])
    replayed = [_replayed_row(v) for v in verdicts]

    assert len(replayed) == len(offline) > 10 * 10
    for window, (a, b) in enumerate(zip(replayed, offline, strict=True)):
        assert a[:3] == b[:3] and (a[3] == b[3] or _nan(a[3]) and _nan(b[3])), f"window {window}: replay {a}, fleet judge {b}"
    assert not any(row[4] for row in replayed), "a window with a sensor problem: a boundary read as a dropout?"
    assert [_comparable(e) for e in sink.events] == [_comparable(e) for e in offline_events]
    assert "SENSOR_FAULT" not in [e.kind.value for e in sink.events] and "CONFIRMED" in [e.kind.value for e in sink.events]


def _interrupt_after_the_first(done: int, total: int) -> None:
    if done == 1:
        raise KeyboardInterrupt


def _workers_idle(client) -> bool:
    """No task runs on any worker, cancelled ones included: a task cancelled while it ran leaves
    the scheduler at once (client.processing() no longer lists it) but its thread runs on and
    writes its partition; the workers' own count of executing tasks still holds it."""
    executing = client.run(lambda dask_worker: dask_worker.state.executing_count)
    return not any(executing.values()) and not any(client.processing().values())


def _resumes_without_redoing(tmp_path: Path, written: list[Path], **how: object) -> None:
    """The resumed analysis reuses what the interrupted one wrote, untouched, and does the rest;
    its partitions equal a fresh analysis' and a third run has nothing to do."""
    mtimes = {p: p.stat().st_mtime_ns for p in written}
    # A run killed while writing leaves a temporary file: cleaned, never read as a partition.
    stale = temporary_name(written[0])
    stale.write_bytes(b"half a parquet file")

    resumed = analyze_fleet(tmp_path / "fleet", tmp_path / "windows", **how)  # type: ignore[arg-type]
    fresh = analyze_fleet(tmp_path / "fleet", tmp_path / "fresh", **how)  # type: ignore[arg-type]

    assert (resumed.analysed, resumed.reused) == (4 - len(written), len(written))
    assert all(p.stat().st_mtime_ns == mtimes[p] for p in written)
    assert not stale.exists()
    for wagon_id, date in (("W1", "2026-11-02"), ("W1", "2026-11-03"), ("W2", "2026-11-02"), ("W2", "2026-11-03")):
        a = pq.read_table(partition_path(tmp_path / "windows", wagon_id, date))
        b = pq.read_table(partition_path(tmp_path / "fresh", wagon_id, date))
        assert a.num_rows == b.num_rows > 0
        assert a.column("end_s").to_pylist() == b.column("end_s").to_pylist()
    again = analyze_fleet(tmp_path / "fleet", tmp_path / "windows", **how)  # type: ignore[arg-type]
    assert again.analysed == 0 and again.windows == fresh.windows


def _partitions(tmp_path: Path) -> list[Path]:
    return sorted((tmp_path / "windows").glob("wagon=*/date=*/part-0.parquet"))


def test_an_interrupted_analysis_resumes_without_redoing_or_duplicating(tmp_path: Path, runs: tree.Runs) -> None:
    # In this process the interrupt lands exactly after the first partition: one written, three to do.
    _fleet(tmp_path / "fleet", runs)
    with pytest.raises(KeyboardInterrupt):
        analyze_fleet(tmp_path / "fleet", tmp_path / "windows", runner=InProcess(), progress=_interrupt_after_the_first)
    written = _partitions(tmp_path)
    assert len(written) == 1
    _resumes_without_redoing(tmp_path, written, runner=InProcess())


def test_an_analysis_interrupted_on_the_dask_cluster_resumes_without_redoing_or_duplicating(tmp_path: Path, runs: tree.Runs, client) -> None:
    _fleet(tmp_path / "fleet", runs)
    with pytest.raises(KeyboardInterrupt):
        analyze_fleet(tmp_path / "fleet", tmp_path / "windows", client=client, progress=_interrupt_after_the_first)
    # The tasks already running when the interrupt came end and write their partitions whole (the
    # rest are cancelled): count only once no worker runs a task. How many ran depends on how soon
    # the interrupt reached the cluster, which the machine's load decides: one at least, four at most.
    deadline_s = time.monotonic() + 600.0
    while not _workers_idle(client):
        assert time.monotonic() < deadline_s, "the Dask workers still ran tasks 600 s after the interrupt"
        time.sleep(0.05)
    written = _partitions(tmp_path)
    assert 1 <= len(written) <= 4
    _resumes_without_redoing(tmp_path, written, client=client)


def test_a_new_day_is_the_only_work_of_the_next_run(tmp_path: Path, runs: tree.Runs, client) -> None:
    _fleet(tmp_path / "fleet", runs)
    analyze_fleet(tmp_path / "fleet", tmp_path / "windows", client=client)
    tree.place(runs.healthy[1], tmp_path / "fleet" / "W2", "2026-11-04", "06:00")
    summary = analyze_fleet(tmp_path / "fleet", tmp_path / "windows", client=client)
    assert (summary.analysed, summary.reused) == (1, 4)
    assert [r.date for r in summary.results if not r.reused] == ["2026-11-04"]


def test_bad_inputs_are_reported_and_never_stop_the_rest(tmp_path: Path, runs: tree.Runs, client) -> None:
    root = tmp_path / "fleet"
    _fleet(root, runs)
    good = tree.place(runs.healthy[0], root / "W2", "2026-11-04", "06:00")
    truncated = good.with_name("070000_cut.csv.gz")
    truncated.write_bytes(good.read_bytes()[: len(good.read_bytes()) // 2])
    (root / "W2" / "2026-11-04" / "080000_garbage.csv").write_bytes(b"time_s,a1,a2,a3\n1,2,x,4\n")
    (root / "W2" / "2026-11-05").mkdir()  # an empty day
    (root / "W2" / "not-a-day").mkdir()
    (root / "W3" / "2026-11-02").mkdir(parents=True)  # a wagon with no config
    shutil.copy(good, root / "W3" / "2026-11-02" / good.name)
    wrong_day = tree.place(runs.healthy[1], root / "W2", "2026-11-06", "06:00")
    wrong_day.rename(root / "W2" / "2026-11-04" / "090000_elsewhere.csv.gz")

    summary = analyze_fleet(root, tmp_path / "windows", client=client)

    reasons = {Path(i.path).name: i.reason for i in summary.issues}
    assert "cut short" in reasons["070000_cut.csv.gz"]
    assert "line 2" in reasons["080000_garbage.csv"]
    assert "empty day" in reasons["2026-11-05"]
    assert "no date" in reasons["not-a-day"]
    assert "no config" in reasons["W3"]
    assert "day out of order" in reasons["090000_elsewhere.csv.gz"]
    day = pq.read_table(partition_path(tmp_path / "windows", "W2", "2026-11-04"))
    assert set(day.column("recording").to_pylist()) == {good.name}
    assert summary.partitions == 5 and summary.windows > 0
    judged = judge_fleet(tmp_path / "windows", tmp_path / "judged")
    assert judged.wagons == 2
    notes = {w["wagon"]: w["notes"] for w in json.loads((tmp_path / "judged" / "wagons.json").read_text())["wagons"]}
    assert any("3 input(s) skipped" in n for n in notes["W2"])


def test_fleet_calibrate_learns_what_bogiemon_calibrate_learns_from_the_same_days(tmp_path: Path, runs: tree.Runs, client) -> None:
    root = tmp_path / "fleet"
    files = _fleet(root, runs)
    analyze_fleet(root, tmp_path / "windows", client=client)

    done = calibrate_wagon(root, tmp_path / "windows", "W2", days=["2026-11-02", "2026-11-03"], load="full")

    expected = calibrate(files["W2"], load_config(root / "W2" / "bogiemon.toml"), "full")
    assert done.path == root / "W2" / "calibration.toml"
    assert done.result.loads[0].fused == expected.loads[0].fused
    assert done.result.loads[0].indicators == expected.loads[0].indicators
    assert scan_fleet(root).wagon("W2").commissioned == ("full",)
