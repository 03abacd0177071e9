"""The recorder and the event store's room (docs/recorder.md, "The reserve"): on real small tmpfs
file systems, the recorder leaves the reserve free, deletes its own oldest files before it writes,
stops recording when there is no room above the reserve and resumes when there is, and never costs
an event a commit. The reserve's figures are checked against what the real store takes.

The tmpfs tests need root (mount); elsewhere they are skipped and say so.
"""

from __future__ import annotations

import dataclasses
import gzip
import json
import os
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, MutableMapping
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import structlog
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from bogiemon.daemon import recorder as recorder_module
from bogiemon.daemon.config import BogiemonConfig, parse_config
from bogiemon.daemon.delivery.status import status_from_monitor
from bogiemon.daemon.messages import encode_status
from bogiemon.daemon.event_json import event_body
from bogiemon.judgement.events import Event, EventKind
from bogiemon.daemon.monitor import STATE_KEY, Monitor
from bogiemon.daemon.recorder import Recorder, RecorderSettings, keep_the_reserve_free
from bogiemon.daemon.recorder_space import (
    DEFAULT_RESERVE_BYTES,
    NAME_PATTERN,
    STORE_EVENT_BYTES,
    STORE_STATUS_BYTES,
    STORE_WAL_BYTES,
    event_store_reserve_bytes,
    recording_bound_bytes,
)
from bogiemon.daemon.service import EXIT_OK, Service
from bogiemon.daemon.store import DB_NAME, EventStore, StoreError
from bogiemon.drivers.base import Block, MemorySource
from bogiemon.drivers.recording import write_csv_recording
from tests.daemon.synthetic import as_blocks, bogie_accel, short_windows_config
from tests.judgement.event_examples import event_of

START_S = 1.7e9
MIB = 1 << 20


# --- small file systems of our own ----------------------------------------------------------------


Mount = Callable[[str, str], Path]


@pytest.fixture
def tmpfs(tmp_path: Path) -> Iterator[Mount]:
    """mount(name, size): a tmpfs of that size (e.g. "24m") at tmp_path/name, unmounted at the end."""
    if os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    mounted: list[Path] = []

    def mount(name: str, size: str) -> Path:
        root = tmp_path / name
        root.mkdir()
        proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size},mode=0755", "tmpfs", str(root)], capture_output=True, text=True)
        if proc.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {proc.stderr.strip()}")
        mounted.append(root)
        return root

    yield mount
    for root in mounted:
        subprocess.run(["umount", "-l", str(root)], capture_output=True)


def free_bytes(path: Path) -> int:
    usage = os.statvfs(path)
    return usage.f_bavail * usage.f_frsize


def used_bytes(path: Path) -> int:
    usage = os.statvfs(path)
    return (usage.f_blocks - usage.f_bavail) * usage.f_frsize


def fill_until_free(path: Path, free: int) -> None:
    """Another program's file, grown until `free` bytes (to the page) are left on path's file system."""
    with path.open("ab") as f:
        while (left := free_bytes(path.parent) - free) > 0:
            f.write(bytes(min(left, MIB)))
            f.flush()
    assert abs(free_bytes(path.parent) - free) < 8192


def take(path: Path, n_bytes: int) -> None:
    """Another program's file grows by n_bytes (the event store growing into the reserve, say)."""
    with path.open("ab") as f:
        f.write(bytes(n_bytes))


def earlier_recordings(directory: Path, sizes: list[int]) -> list[str]:
    """Files of an earlier run, named as the recorder names them (of 2020, so older than any new one)."""
    directory.mkdir(parents=True, exist_ok=True)
    names = [f"202001{day:02d}T000000Z_periodic.csv.gz" for day in range(1, len(sizes) + 1)]
    rng = np.random.default_rng(5)
    for name, size in zip(names, sizes, strict=True):
        (directory / name).write_bytes(rng.bytes(size))
    return names


def config_on(state: Path, recordings: Path, extra: str = "") -> BogiemonConfig:
    return parse_config(
        short_windows_config(state_dir=state) + f'[recorder]\nenabled = true\ndirectory = "{recordings}"\nlead_in_s = 3.0\n{extra}', "test"
    )


def settings_of(config: BogiemonConfig) -> RecorderSettings:
    settings = config.recorder_settings()
    assert settings is not None
    return settings


class FreeAfterEachWrite:
    """The real writer (gzip, fsync), then the free bytes with the whole recording on the disk."""

    def __init__(self, disk: Path) -> None:
        self.disk = disk
        self.free: list[int] = []

    def __call__(self, path: Path, time_s: np.ndarray, accel_mps2: np.ndarray) -> None:
        write_csv_recording(path, time_s, accel_mps2, fsync=True)
        self.free.append(free_bytes(self.disk))


class SerialRun:
    """A Monitor with a Recorder, fed block by block, each block's recordings written before the
    next block: the store's commits and the recorder's writes never overlap, so the free space
    measured after a write is what the recorder left."""

    def __init__(self, config: BogiemonConfig, write: FreeAfterEachWrite | None = None) -> None:
        self.recorder = Recorder(settings_of(config), write=write)
        assert self.recorder.ready.wait(10)
        self.store = EventStore(config.state.directory)
        self.monitor = Monitor(
            config.monitor_settings(), self.store, observers=[self.recorder.on_window], taps=[self.recorder.on_block]
        )
        self.events: list[Event] = []

    def feed(self, blocks: list[Block], after_block: Callable[[list[Event]], None] | None = None) -> None:
        for block in blocks:
            new = self.monitor.feed(block)
            self.events += new
            assert self.recorder.wait_written(30)
            if after_block is not None:
                after_block(new)

    def close(self) -> None:
        self.recorder.close()
        self.store.close()

    def kinds(self) -> list[str]:
        return [e.kind.value for e in self.events]


def stored_events(state: Path) -> list[Event]:
    store = EventStore(state, readonly=True)
    try:
        return store.events()
    finally:
        store.close()


def faults_and_clears() -> np.ndarray:
    """SUSPECTED and CONFIRMED, CLEARED, then SUSPECTED and CONFIRMED again (the short windows)."""
    return np.vstack([bogie_accel(12, seed=2, pitch_roll_coupling=1.0), bogie_accel(30, seed=1), bogie_accel(12, seed=3, pitch_roll_coupling=1.0)])


KINDS = ["SUSPECTED", "CONFIRMED", "CLEARED", "SUSPECTED", "CONFIRMED"]
# A periodic recording of 3 s every 7.2 s of running, on top of the snapshots.
PERIODIC = "periodic_every_h = 0.002\nperiodic_s = 3.0\n"


# --- the bound of a recording's size --------------------------------------------------------------

_VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.floats(-200.0, 200.0),  # accelerations, -0.0 and the 9.9999996 that rounds up to 10 included
    st.sampled_from([-0.0, -1e-9, 9.9999996, 99.9999995, -999.9999999, 1e15]),
)


@settings(max_examples=200, deadline=None)
@given(hnp.arrays(np.float64, st.tuples(st.integers(1, 60), st.just(4)), elements=_VALUES))
def test_the_bound_of_a_recording_is_never_less_than_the_file_the_real_writer_writes(rows: np.ndarray) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "r.csv.gz"
        write_csv_recording(path, rows[:, 0], rows[:, 1:])
        assert recording_bound_bytes(rows[:, 0], rows[:, 1:]) >= path.stat().st_size
        # The text bound holds before compression too: gzip of incompressible text is the text and more.
        assert recording_bound_bytes(rows[:, 0], rows[:, 1:]) >= len(gzip.decompress(path.read_bytes()))


def test_the_bound_of_a_default_snapshot_is_about_three_times_what_a_bogies_samples_compress_to(tmp_path: Path) -> None:
    # 220 s at 500 Hz of the synthetic bogie, Unix times: the figure docs/recorder.md states.
    accel = bogie_accel(1100, seed=1)  # 110 000 instants (the synthetic signals are made at 100 Hz)
    time_s = 1.8e9 + np.arange(accel.shape[0]) / 500.0
    write_csv_recording(tmp_path / "s.csv.gz", time_s, accel.astype(np.float32))
    written = (tmp_path / "s.csv.gz").stat().st_size
    bound = recording_bound_bytes(time_s, accel.astype(np.float32))
    assert 1.6e6 < written < 2.0e6 and 5.0e6 < bound < 5.4e6
    assert 2.5 < bound / written < 3.2


# --- the reserve: what the event store takes --------------------------------------------------------


def real_bodies(tmp_path: Path) -> tuple[Event, dict, str]:
    """A CONFIRMED, the state committed with it and a status message, as a monitor makes them."""
    store = EventStore(tmp_path / "bodies")
    monitor = Monitor(parse_config(short_windows_config(), "t").monitor_settings(), store)
    events = [e for b in as_blocks(bogie_accel(20, 3, pitch_roll_coupling=1.0)) for e in monitor.feed(b)]
    confirmed = next(e for e in events if e.kind is EventKind.CONFIRMED)
    status = encode_status(status_from_monitor(monitor, "wagon-2026-0042", 1.8e9, store.outbox.counts()))
    state = {STATE_KEY: monitor.state_dict()}
    store.close()
    return confirmed, state, status


def test_the_reserve_holds_what_the_event_store_takes_for_its_wal_events_and_status_messages(tmpfs: Mount, tmp_path: Path) -> None:
    disk = tmpfs("store", "32m")
    confirmed, state, status = real_bodies(tmp_path)
    events_n, status_n = 1500, 1500  # past the WAL's ceiling (about 135 event commits) by far
    before = used_bytes(disk)
    main_file = disk / "state" / DB_NAME
    peak = peak_wal = 0

    def commit_all(commit: Callable[[EventStore, int], object], n: int) -> int:
        """n commits on a store opened afresh (its WAL grows again); the main file's size once closed."""
        nonlocal peak, peak_wal
        store = EventStore(disk / "state")
        for i in range(n):
            commit(store, i)
            peak, peak_wal = max(peak, used_bytes(disk) - before), max(peak_wal, os.path.getsize(f"{main_file}-wal"))
        store.close()  # the last connection checkpoints the WAL into the main file and deletes it
        return main_file.stat().st_size

    empty = commit_all(lambda store, i: None, 0)
    with_events = commit_all(lambda store, i: store.append([dataclasses.replace(confirmed, event_id=f"e{i}")], state=state), events_n)
    with_status = commit_all(lambda store, i: store.outbox.queue_status(1.8e9 + i, status), status_n)
    per_event, per_status = (with_events - empty) / events_n, (with_status - with_events) / status_n
    # Measured here: the WAL at most 4 152 992 B; 860 B an event of 711 B with its state of 844 B;
    # 819 B a status message of 795 B; the store took 6.5 MB at most.
    assert len(json.dumps(event_body(confirmed))) > 600 and len(json.dumps(state)) > 600 and len(status) > 600
    assert 3.9e6 < peak_wal < STORE_WAL_BYTES - 32 * 1024  # the WAL's ceiling, with its 32 KiB -shm beside it
    assert 700 < per_event <= STORE_EVENT_BYTES and 700 < per_status <= STORE_STATUS_BYTES, (per_event, per_status)
    assert peak <= STORE_WAL_BYTES + events_n * STORE_EVENT_BYTES + status_n * STORE_STATUS_BYTES


def test_the_reserve_has_room_for_the_mqtt_outbox_only_when_mqtt_sends_status_messages(tmp_path: Path) -> None:
    def reserve_of(extra: str) -> int:
        settings = parse_config(short_windows_config() + f'[recorder]\nenabled = true\ndirectory = "{tmp_path}"\n' + extra, "t").recorder_settings()
        assert settings is not None
        return settings.reserve_bytes

    mqtt = '[wagon]\nid = "w1"\n[mqtt]\nenabled = true\n'
    assert reserve_of("") == event_store_reserve_bytes(0) == 20_602_880  # 19.6 MiB
    assert reserve_of(mqtt) == event_store_reserve_bytes(10_000) == DEFAULT_RESERVE_BYTES == 30_842_880  # 29.4 MiB
    assert reserve_of(mqtt + "outbox_max_messages = 100000\n") == event_store_reserve_bytes(100_000)
    assert reserve_of(mqtt + "status_period_s = 0\n") == event_store_reserve_bytes(0)


# --- the recorder on the event store's file system ---------------------------------------------------


def test_near_a_full_disk_the_recorder_deletes_its_oldest_files_before_writing_and_never_takes_the_reserve(tmpfs: Mount) -> None:
    disk = tmpfs("disk", "24m")
    state, recordings = disk / "state", disk / "state" / "recordings"
    config = config_on(state, recordings, PERIODIC)
    reserve = settings_of(config).reserve_bytes
    earlier = earlier_recordings(recordings, [60_000] * 8)
    (recordings / "notes.txt").write_bytes(bytes(50_000))  # not the recorder's: never counted or deleted
    (recordings / "20190101T000000Z_confirmed.csv.gz").symlink_to(disk / "filler")
    fill_until_free(disk / "filler", reserve + 100 * 1024)  # less than any recording's bound above the reserve
    filler_size = (disk / "filler").stat().st_size
    write = FreeAfterEachWrite(disk)
    run = SerialRun(config, write)
    run.feed(as_blocks(faults_and_clears(), start_s=START_S))
    run.close()
    assert run.kinds() == KINDS
    assert run.monitor.store_failures == 0 and stored_events(state) == run.events  # every commit went through
    counters = run.recorder.counters
    assert counters.snapshots_written == 4 and counters.periodic_written == 7 and counters.no_room == 0
    assert len(write.free) == 11 and min(write.free) >= reserve  # with each recording whole on the disk
    assert free_bytes(disk) >= reserve
    names = sorted(p.name for p in recordings.iterdir())
    kept = [n for n in earlier if n in names]
    assert kept == earlier[len(earlier) - len(kept) :] and len(kept) < len(earlier)  # the oldest went first
    own = [n for n in names if NAME_PATTERN.fullmatch(n) and not (recordings / n).is_symlink()]
    assert counters.files_deleted == len(earlier) + 11 - len(own)  # each recording is kept or counted deleted
    assert {"notes.txt", "20190101T000000Z_confirmed.csv.gz"} <= set(names) and (disk / "filler").stat().st_size == filler_size


def test_with_no_room_above_the_reserve_recording_stops_says_so_and_resumes_once_there_is_room(tmpfs: Mount) -> None:
    disk = tmpfs("disk", "24m")
    state, recordings = disk / "state", disk / "recordings"
    config = config_on(state, recordings)
    reserve = settings_of(config).reserve_bytes
    fill_until_free(disk / "filler", reserve + 100 * 1024)  # another program's file; no recording of ours to delete

    def free_the_disk_once_cleared(new: list[Event]) -> None:
        if any(e.kind is EventKind.CLEARED for e in new):
            (disk / "filler").unlink()

    with structlog.testing.capture_logs() as logs:
        run = SerialRun(config)
        run.feed(as_blocks(faults_and_clears(), start_s=START_S), after_block=free_the_disk_once_cleared)
        run.close()
    assert run.kinds() == KINDS
    assert run.monitor.store_failures == 0 and stored_events(state) == run.events  # the first CONFIRMED too, with the recorder stopped
    counters = run.recorder.counters
    assert counters.no_room == 2 and counters.snapshots_written == 2 and counters.files_deleted == 0
    said = [(e["log_level"], e["event"]) for e in logs if e.get("component") == "recorder" and e["event"].startswith("recording ")]
    assert said == [
        ("warning", "recording stopped: no room above the event store's reserve, the events come first"),
        ("info", "recording not written: still no room above the event store's reserve"),
        ("info", "recording written"),
        ("info", "recording resumed: there is room above the event store's reserve again"),
        ("info", "recording written"),
    ]
    stopped = next(e for e in logs if e["event"].startswith("recording stopped"))
    assert stopped["reason"] == "suspected" and stopped["reserve_bytes"] == reserve and stopped["free_bytes"] < reserve + stopped["needed_bytes"]
    assert next(e for e in logs if e["event"].startswith("recording resumed"))["not_written"] == 2
    assert [e["no_room"] for e in logs if e["event"] == "recorder stopped"] == [2]
    assert sorted(n.split("_")[1] for n in os.listdir(recordings)) == ["confirmed.csv.gz", "suspected.csv.gz"]


def test_while_idle_the_recorder_gives_its_files_back_when_the_disk_fills_into_the_reserve(tmpfs: Mount, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(recorder_module, "SPACE_CHECK_S", 0.05)
    disk = tmpfs("disk", "24m")
    recordings = disk / "recordings"
    config = config_on(disk / "state", recordings)
    reserve = settings_of(config).reserve_bytes
    earlier = earlier_recordings(recordings, [200_000] * 5)
    recorder = Recorder(settings_of(config))
    assert recorder.ready.wait(10) and free_bytes(disk) > reserve + 1_000_000
    assert sorted(os.listdir(recordings)) == earlier  # room enough: nothing deleted
    take(disk / "filler", free_bytes(disk) - (reserve - 300_000))  # the store, or another program, took the reserve's room
    deadline = time.monotonic() + 10
    while free_bytes(disk) < reserve and time.monotonic() < deadline:
        time.sleep(0.02)
    recorder.close()
    assert sorted(os.listdir(recordings)) == earlier[2:]  # the two oldest: 400 kB back
    assert free_bytes(disk) >= reserve and recorder.counters.files_deleted == 2 and recorder.counters.bytes_deleted == 400_000


class GatedSource(MemorySource):
    """A finite source that gives its first block once the recorder has looked at its folder (a
    gateway's first window ends minutes after the start; a test's would end within milliseconds)."""

    finite = True

    def __init__(self, blocks: list[Block], ready: threading.Event) -> None:
        super().__init__(blocks)
        self._ready = ready

    def read(self, timeout_s: float) -> Block | None:
        assert self._ready.wait(10)
        return super().read(timeout_s)


def _disk_full_of_recordings(tmpfs: Mount, free_left_bytes: int) -> tuple[Path, Path, Path, list[str]]:
    """A 24 MiB state file system holding a store and an earlier run's recordings, the last (a
    confirmation's) grown until free_left_bytes are free: (disk, state, recordings, their names)."""
    disk = tmpfs("disk", "24m")
    state, recordings = disk / "state", disk / "state" / "recordings"
    EventStore(state).close()
    earlier = earlier_recordings(recordings, [1_000_000] * 24)
    earlier.append("20200201T000000Z_confirmed.csv.gz")
    fill_until_free(recordings / earlier[-1], free_left_bytes)
    return disk, state, recordings, earlier


def _run_the_service_with_its_recorder(tmp_path: Path, state: Path, recordings: Path) -> tuple[Service, list[MutableMapping[str, Any]]]:
    """The service with its recorder over a broken spring's 30 s; it must store the SUSPECTED and
    the CONFIRMED with nothing logged at crit."""
    config_path = tmp_path / "bogiemon.toml"
    config_path.write_text(short_windows_config(state_dir=state) + f'[recorder]\nenabled = true\ndirectory = "{recordings}"\n')
    blocks = as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0), start_s=START_S)
    service: Service

    def source(config: BogiemonConfig) -> GatedSource:
        assert service.recorder is not None
        return GatedSource(blocks, service.recorder.ready)

    service = Service(config_path, source, sinks=[])
    with structlog.testing.capture_logs() as logs:
        assert service.run() == EXIT_OK
    assert [e.kind.value for e in stored_events(state)] == ["SUSPECTED", "CONFIRMED"]
    assert not [e for e in logs if e["log_level"] == "critical"]
    return service, logs


def test_the_next_start_on_a_disk_full_of_recordings_gives_their_room_back_and_commits_the_confirmed(tmpfs: Mount, tmp_path: Path) -> None:
    # The finding: the recordings of a run at the default cap filled the state's file system; the
    # next start held the CONFIRMED, lost it and exited 3.
    disk, state, recordings, earlier = _disk_full_of_recordings(tmpfs, 48 * 1024)  # room for the store to open (its 32 KiB -shm), not to commit
    reserve = settings_of(config_on(state, recordings)).reserve_bytes
    service, logs = _run_the_service_with_its_recorder(tmp_path, state, recordings)
    assert service.recorder is not None
    counters = service.recorder.counters
    kept = sorted(n for n in os.listdir(recordings) if n.startswith("2020"))
    assert kept == earlier[len(earlier) - len(kept) :] and 0 < len(kept) < len(earlier)  # the oldest gave the room back
    # Given back by the service before it opened the store (the recorder, not yet started, counts none).
    assert counters.files_deleted == 0 and counters.snapshots_written == 2
    assert free_bytes(disk) >= reserve
    gave_back = next(e for e in logs if e["event"] == "deleted the oldest recordings to keep the event store's reserve free")
    assert gave_back["needed_bytes"] == 0 and gave_back["free_bytes"] >= reserve and gave_back["files"] == len(earlier) - len(kept)


def test_before_the_store_opens_the_reserve_is_given_back_on_a_disk_filled_to_the_last_page(tmpfs: Mount) -> None:
    disk = tmpfs("disk", "24m")
    state, recordings = disk / "state", disk / "state" / "recordings"
    EventStore(state).close()
    earlier = earlier_recordings(recordings, [1_000_000] * 24)
    (recordings / "notes.txt").write_bytes(b"not a recording")
    earlier.append("20200201T000000Z_confirmed.csv.gz")
    fill_until_free(recordings / earlier[-1], 0)
    with pytest.raises(StoreError, match="is full, 0 KiB free"):
        EventStore(state)  # its -shm has no room: the service would not start, and no recorder run
    settings = settings_of(config_on(state, recordings))
    with structlog.testing.capture_logs() as logs:
        keep_the_reserve_free(settings)
    assert free_bytes(disk) >= settings.reserve_bytes
    kept = sorted(n for n in os.listdir(recordings) if n.startswith("2020"))
    assert kept == earlier[len(earlier) - len(kept) :] and 0 < len(kept) < len(earlier) and (recordings / "notes.txt").exists()
    (line,) = [e for e in logs if e["event"] == "deleted the oldest recordings to keep the event store's reserve free"]
    assert line["files"] == len(earlier) - len(kept) and line["free_bytes"] == free_bytes(disk)
    store = EventStore(state)
    store.append([event_of(EventKind.CONFIRMED, 1.8e9, config_hash="x")])
    store.close()


def test_the_service_gives_the_reserve_back_before_it_opens_the_store_on_a_disk_filled_to_the_last_page(tmpfs: Mount, tmp_path: Path) -> None:
    # As above, through the service: without the give-back before the store opens, the store's
    # -shm finds no room, the start is refused, and no recorder ever runs to make room.
    disk, state, recordings, _ = _disk_full_of_recordings(tmpfs, 0)
    reserve = settings_of(config_on(state, recordings)).reserve_bytes
    _run_the_service_with_its_recorder(tmp_path, state, recordings)
    assert free_bytes(disk) >= reserve


# --- the recorder on a file system of its own ---------------------------------------------------------


def test_recordings_on_another_file_system_keep_their_own_budget_and_never_touch_the_stores(tmpfs: Mount) -> None:
    store_disk, recording_disk = tmpfs("store", "8m"), tmpfs("recordings", "32m")
    state, recordings = store_disk / "state", recording_disk / "recordings"
    config = config_on(state, recordings, "max_total_bytes = 1048576\n")
    earlier = earlier_recordings(recordings, [400_000, 400_000, 200_000])
    EventStore(state).close()
    fill_until_free(store_disk / "filler", 1 * MIB)  # the store's file system far below the reserve
    store_files = sorted(os.listdir(state))
    run = SerialRun(config)
    run.feed(as_blocks(faults_and_clears(), start_s=START_S))
    run.close()
    assert run.kinds() == KINDS and run.monitor.store_failures == 0 and stored_events(state) == run.events
    counters = run.recorder.counters
    assert counters.snapshots_written == 4 and counters.no_room == 0  # not stopped by the store's full disk
    names = sorted(os.listdir(recordings))
    own_bytes = sum((recordings / n).stat().st_size for n in names)
    assert own_bytes <= 1 * MIB and earlier[0] not in names and earlier[2] in names  # the budget: the oldest went
    assert counters.files_deleted == 1 and counters.bytes_deleted == 400_000
    assert sorted(os.listdir(state)) == store_files == [DB_NAME] and sorted(os.listdir(store_disk)) == ["filler", "state"]
