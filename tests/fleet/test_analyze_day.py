"""One wagon-day's analysis: time order, overlapping recorder snapshots, the windows of `analyze`."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest

from bogiemon.daemon.analysis import analyze_recording, open_recording
from bogiemon.drivers.recording import read_csv_recording, write_csv_recording
from bogiemon.fleet.analyze import FORMAT, analyze_day, day_tasks, is_done
from bogiemon.fleet.windows_files import DIGEST_KEY, METADATA_KEY, PartitionError, read_partition
from bogiemon.fleet.layout import scan_fleet
from tests.fleet import tree


def _task(root: Path, out: Path):  # type: ignore[no-untyped-def]
    (task,) = day_tasks(scan_fleet(root), out)
    return task


def test_a_recordings_windows_are_those_of_bogiemon_analyze(tmp_path: Path, runs: tree.Runs) -> None:
    folder = tree.wagon(tmp_path / "fleet", "W1", commissioned=False)
    placed = tree.place(runs.healthy[0], folder, "2026-11-02", "06:00")
    task = _task(tmp_path / "fleet", tmp_path / "windows")
    analyze_day(task)
    partition = read_partition(task.path, task.midnight_s)
    expected = list(analyze_recording(open_recording(placed, task.config), task.config))
    assert partition.windows() == expected
    recording = read_csv_recording(placed)
    assert partition.meta.segment_starts == [(float(recording.time_s[0]), recording.fs_hz, False)]


def test_overlapping_snapshots_give_each_sample_once(tmp_path: Path, runs: tree.Runs) -> None:
    folder = tree.wagon(tmp_path / "fleet", "W1", commissioned=False)
    whole = tree.place(runs.healthy[0], folder, "2026-11-02", "06:00")
    rec = read_csv_recording(whole)
    day = whole.parent
    # The recorder's way: a SUSPECTED snapshot, then a CONFIRMED one holding it and more, then one
    # that starts inside the last (named so that name order is not time order).
    n = rec.n_samples
    for name, (a, b) in {"b_suspected.csv.gz": (0, 2 * n // 5), "a_confirmed.csv.gz": (0, 9 * n // 20), "c_later.csv.gz": (2 * n // 5, n)}.items():
        write_csv_recording(day / name, rec.time_s[a:b], rec.accel_mps2[a:b])
    whole.unlink()
    task = _task(tmp_path / "fleet", tmp_path / "windows")
    result = analyze_day(task)
    partition = read_partition(task.path, task.midnight_s)
    table = partition.table
    ends = np.array(table.column("end_s").to_pylist())
    assert partition.meta.covered == 1 and result.recordings == 2 and result.skipped == ()
    assert np.all(np.diff(ends) > 0)  # no window twice
    assert result.samples == n  # every sample once
    assert set(table.column("recording").to_pylist()) == {"a_confirmed.csv.gz", "c_later.csv.gz"}


def test_a_partition_of_an_older_format_is_redone_and_never_read_as_this_one(tmp_path: Path, runs: tree.Runs) -> None:
    # A format change (e.g. new columns) must not be misread by `fleet judge` or skipped by the resume.
    folder = tree.wagon(tmp_path / "fleet", "W1", commissioned=False)
    tree.place(runs.healthy[0], folder, "2026-11-02", "06:00")
    task = _task(tmp_path / "fleet", tmp_path / "windows")
    analyze_day(task)
    table = pq.read_table(task.path)
    older = json.dumps({**json.loads(table.schema.metadata[METADATA_KEY]), "format": FORMAT - 1}).encode()
    pq.write_table(table.replace_schema_metadata({METADATA_KEY: older, DIGEST_KEY: hashlib.sha256(older).hexdigest().encode()}), task.path)
    assert not is_done(task)
    with pytest.raises(PartitionError, match=f"written in format {FORMAT - 1}, this bogiemon reads {FORMAT}; run `bogiemon fleet analyze` again$"):
        read_partition(task.path, task.midnight_s)
