"""`fleet analyze s3://bucket/prefix` against a real S3-compatible server (moto's, started on
loopback by the test): the same windows as the local tree, judged alike, every object read bounded."""

from __future__ import annotations

import os
import socket
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
from moto.server import ThreadedMotoServer  # the test extra installs it (pyproject.toml)

from bogiemon.cli.main import main
from bogiemon.drivers.recording import write_parquet_recording
from bogiemon.fleet.calibrate import calibrate_wagon
from bogiemon.fleet.analyze import analyze_day, analyze_fleet, day_tasks, partition_path
from bogiemon.fleet.cluster import InProcess
from bogiemon.fleet.judge import judge_fleet
from bogiemon.fleet.layout import FleetError, scan_fleet
from bogiemon.fleet.objects import Store, fetch, is_url
from bogiemon.drivers.recording_format import RecordingError
from tests.fleet import tiny

BUCKET = "keeper-uploads"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def s3() -> Iterator[str]:
    """An S3 server on loopback and the environment that points S3 clients at it; its endpoint."""
    port = _free_port()
    server = ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    endpoint = f"http://127.0.0.1:{port}"
    saved = {k: os.environ.get(k) for k in ENV}
    os.environ.update({"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_DEFAULT_REGION": "us-east-1",
                       "AWS_ENDPOINT_URL": endpoint, "FSSPEC_S3_ENDPOINT_URL": endpoint})  # fmt: skip
    import fsspec.config

    fsspec.config.set_conf_env(fsspec.config.conf)  # fsspec reads its variables at import: again, now they are set
    try:
        yield endpoint
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        fsspec.config.conf.pop("s3", None)
        server.stop()


ENV = ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_DEFAULT_REGION", "AWS_ENDPOINT_URL", "FSSPEC_S3_ENDPOINT_URL")


def _filesystem() -> Any:
    import fsspec

    return fsspec.filesystem("s3", skip_instance_cache=True)


@pytest.fixture(scope="module")
def trees(s3: str, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A tiny fleet on disk and the same files uploaded under s3://BUCKET/fleet (a Parquet recording too)."""
    root = tiny.fleet(tmp_path_factory.mktemp("local") / "fleet")
    rng = np.random.default_rng(7)
    start_s = 1793772000.0  # 2026-11-03 06:00Z
    n = int(45 * tiny.FS_HZ)
    write_parquet_recording(root / "W2" / tiny.DAYS[1] / "090000_run.parquet", start_s + 3 * 3600 + np.arange(n) / tiny.FS_HZ, rng.normal(0, 1, (n, 3)))
    (root / "fleet.toml").write_text('[fleet]\nname = "Keeper X"\n', encoding="utf-8")
    (root / "W1" / "notes.txt").write_text("a stray file", encoding="utf-8")
    fs = _filesystem()
    fs.mkdir(BUCKET)
    fs.put(str(root) + "/", f"{BUCKET}/fleet/", recursive=True)
    fs.pipe(f"{BUCKET}/fleet/W1/{tiny.DAYS[0]}/../escape.csv", b"time_s,a1,a2,a3\n")  # a key no tree holds
    return root, f"s3://{BUCKET}/fleet"


def _tables(windows: Path, wagons: tuple[str, ...] = ("W1", "W2")) -> dict[tuple[str, str], Any]:
    return {(w, d): pq.read_table(partition_path(windows, w, d)) for w in wagons for d in tiny.DAYS}


def test_a_url_is_told_from_a_folder() -> None:
    assert is_url("s3://b/p") and is_url("gcs://b") and is_url("memory://x")
    assert not is_url("/data/fleet") and not is_url("fleet") and not is_url("file:///data/fleet") and not is_url("C:\\fleet")


def test_the_fleet_in_the_store_is_scanned_as_the_local_one(trees: tuple[Path, str]) -> None:
    root, url = trees
    local, remote = scan_fleet(root), scan_fleet(url)
    assert remote.url == url and remote.location == url and remote.name == local.name == "Keeper X"
    assert [(w.wagon_id, [(d.date, [f.path.name for f in d.files]) for d in w.days]) for w in remote.wagons] == [
        (w.wagon_id, [(d.date, [f.path.name for f in d.files]) for d in w.days]) for w in local.wagons
    ]
    first = remote.wagons[0].days[0].files[0]
    assert first.url == f"{url}/W1/{tiny.DAYS[0]}/060000_run.csv.gz" and first.size_bytes == (root / "W1" / tiny.DAYS[0] / "060000_run.csv.gz").stat().st_size
    reasons = {i.path: i.reason for i in remote.issues}
    assert reasons[f"{url}/W1/notes.txt"] == "not a day folder (YYYY-MM-DD) nor the wagon's config; skipped"
    assert reasons[f"{url}/W1/{tiny.DAYS[0]}/../escape.csv"] == "not in the tree FLEET/<wagon-id>/<YYYY-MM-DD>/<recording>; skipped"


def test_fleet_analyze_on_the_store_gives_the_same_windows_as_on_the_local_tree(trees: tuple[Path, str], tmp_path: Path) -> None:
    root, url = trees
    here = analyze_fleet(root, tmp_path / "local", runner=InProcess())
    there = analyze_fleet(url, tmp_path / "s3", runner=InProcess())
    assert there.root == url and there.windows == here.windows > 0 and there.partitions == here.partitions == 4
    for key, table in _tables(tmp_path / "local").items():
        assert _tables(tmp_path / "s3")[key].equals(table), key  # every column of every window, bit for bit
    again = analyze_fleet(url, tmp_path / "s3", runner=InProcess())
    assert again.analysed == 0 and again.reused == 4  # the objects' sizes and times identify them, as a file's do
    judged_here, judged_there = judge_fleet(tmp_path / "local", tmp_path / "jl"), judge_fleet(tmp_path / "s3", tmp_path / "js")
    assert judged_there.wagons == judged_here.wagons == 2 and judged_there.events == judged_here.events


def test_the_command_analyses_the_store_on_a_dask_worker(trees: tuple[Path, str], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root, url = trees
    assert main(["fleet", "analyze", url, "-o", str(tmp_path / "s3"), "--workers", "1"]) == 0
    assert "2 wagons, 4 wagon-days (4 analysed, 0 up to date)" in capsys.readouterr().out
    analyze_fleet(root, tmp_path / "local", runner=InProcess())
    for key, table in _tables(tmp_path / "local").items():
        assert _tables(tmp_path / "s3")[key].equals(table), key


def test_an_object_is_read_within_its_bound_and_refused_past_it_naming_its_url(trees: tuple[Path, str], tmp_path: Path) -> None:
    _, url = trees
    store = Store(url=url, protocol="s3", root=f"{BUCKET}/fleet")
    key = f"W1/{tiny.DAYS[0]}/060000_run.csv.gz"
    size = _filesystem().size(f"{BUCKET}/fleet/{key}")
    assert fetch(store, key, tmp_path / "ok", size, RecordingError).stat().st_size == size
    with pytest.raises(RecordingError, match=rf"^{url}/{key}: larger than 100 bytes; is this the right object\?$"):
        fetch(store, key, tmp_path / "listed", 100, RecordingError, size_bytes=size)
    # Listed smaller than it is (replaced since the listing): cut at the bound while reading.
    with pytest.raises(RecordingError, match=r": grew past 100 bytes while it was read"):
        fetch(store, key, tmp_path / "grown", 100, RecordingError, size_bytes=50)


def test_a_recording_removed_after_the_listing_is_skipped_and_named_by_its_url(trees: tuple[Path, str], tmp_path: Path) -> None:
    fs = _filesystem()
    fs.put(str(trees[0]) + "/", f"{BUCKET}/gone/", recursive=True)
    url = f"s3://{BUCKET}/gone"
    task = next(t for t in day_tasks(scan_fleet(url), tmp_path) if (t.wagon_id, t.date) == ("W1", tiny.DAYS[0]))
    fs.rm(f"{BUCKET}/gone/W1/{tiny.DAYS[0]}/060000_run.csv.gz")
    result = analyze_day(task)
    assert [(i.path, i.reason) for i in result.skipped] == [
        (f"{url}/W1/{tiny.DAYS[0]}/060000_run.csv.gz", "no longer in the store (removed since it was listed?)")
    ]


def test_a_config_past_its_bound_skips_its_wagon_and_names_it(trees: tuple[Path, str], s3: str) -> None:
    fs = _filesystem()
    fs.put(str(trees[0]) + "/", f"{BUCKET}/big/", recursive=True)
    fs.pipe(f"{BUCKET}/big/W2/bogiemon.toml", b"#" * (2 << 20))
    fleet = scan_fleet(f"s3://{BUCKET}/big")
    assert [w.wagon_id for w in fleet.wagons] == ["W1"]
    assert any(i.path == f"s3://{BUCKET}/big/W2/bogiemon.toml" and "larger than 1024 KiB" in i.reason for i in fleet.issues)


def test_a_prefix_with_nothing_under_it_is_one_line(s3: str) -> None:
    with pytest.raises(FleetError, match=rf"^s3://{BUCKET}/nothing: no such fleet \(no object under the prefix"):
        scan_fleet(f"s3://{BUCKET}/nothing")


def test_calibrate_on_a_store_says_to_calibrate_a_local_copy(trees: tuple[Path, str], tmp_path: Path) -> None:
    _, url = trees
    with pytest.raises(FleetError, match=rf"^{url}: calibrate writes the wagon's calibration.toml beside its config, in a local FLEET"):
        calibrate_wagon(url, tmp_path / "windows", "W1")


def test_a_recording_uploaded_after_a_scan_is_found_by_the_next_scan_in_the_same_process(trees: tuple[Path, str]) -> None:
    fs = _filesystem()
    fs.put(str(trees[0]) + "/", f"{BUCKET}/later/", recursive=True)
    url = f"s3://{BUCKET}/later"
    before = scan_fleet(url).recordings
    fs.copy(f"{BUCKET}/later/W1/{tiny.DAYS[0]}/060000_run.csv.gz", f"{BUCKET}/later/W1/{tiny.DAYS[0]}/070000_run.csv.gz")
    assert scan_fleet(url).recordings == before + 1
