"""The recorder (issue 15): snapshots around alarms and periodic samples as .csv.gz, written by a
thread of its own under a size cap; real files, real gzip, the real Monitor and event store."""

from __future__ import annotations

import threading
import time
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
import structlog

from bogiemon.daemon.config import BogiemonConfig, load_config, parse_config
from bogiemon.detection.kinematics import Corner
from bogiemon.judgement.events import ConfirmedDetails, EventKind, Trigger
from tests.judgement.event_examples import details_as
from bogiemon.daemon.monitor import Monitor
from bogiemon.judgement.verdict import WindowVerdict
from bogiemon.daemon.recorder import Recorder, RecorderSettings
from bogiemon.daemon.recorder_space import NAME_PATTERN
from bogiemon.daemon.replay import replay
from bogiemon.daemon.service import Service
from bogiemon.daemon.sinks import MemorySink
from bogiemon.daemon.store import EventStore
from bogiemon.drivers.base import Block, MemorySource
from bogiemon.drivers.recording import read_csv_recording, read_recording, write_csv_recording
from tests.daemon.synthetic import FS_HZ, as_blocks, bogie_accel, short_windows_config
from tests.daemon.test_service import Feed, FeedSource, own_signal_handlers  # noqa: F401 - a fixture

START_S = 1.7e9  # 2023-11-14T22:13:20Z
# The short windows of the daemon tests: 6 s windows every 2 s, CONFIRMED at 2 of the last 3.
WINDOW_S, HOP_S, CONFIRM_N = 6.0, 2.0, 3
# float32 in the ring, then 6 decimals in the file.
ACCEL_TOLERANCE_MPS2 = 5e-7 + 2e-6


def recorder_config(directory: Path, extra: str = "", lead_in_s: float = 3.0) -> BogiemonConfig:
    return parse_config(
        short_windows_config() + f'[recorder]\nenabled = true\ndirectory = "{directory}"\nlead_in_s = {lead_in_s}\n{extra}', "test"
    )


class Run:
    """A Monitor with a Recorder attached, fed block by block in this thread."""

    def __init__(self, tmp_path: Path, config: BogiemonConfig, recorder: Recorder | None = None) -> None:
        settings = config.recorder_settings()
        assert settings is not None
        self.recorder = recorder or Recorder(settings)
        self.reports: list[WindowVerdict] = []
        self.monitor = Monitor(
            config.monitor_settings(), EventStore(tmp_path / "state"), observers=[self.reports.append, self.recorder.on_window],
            taps=[self.recorder.on_block],
        )  # fmt: skip
        self.events: list = []

    def feed(self, blocks: list[Block]) -> None:
        for block in blocks:
            self.events += self.monitor.feed(block)

    def kinds(self) -> list[str]:
        return [e.kind.value for e in self.events]

    def event_time(self, kind: EventKind) -> float:
        return next(e.time_s for e in self.events if e.kind is kind)


def recordings(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir())


def stamp(time_s: float) -> str:
    return time.strftime("%Y%m%dT%H%M%SZ", time.gmtime(int(time_s)))


def coupled_after_healthy(healthy_s: float, coupled_s: float) -> np.ndarray:
    return np.vstack([bogie_accel(healthy_s, seed=1), bogie_accel(coupled_s, seed=2, pitch_roll_coupling=1.0)])


def test_the_confirmed_snapshot_holds_the_fed_samples_from_the_lead_in_before_the_last_windows_to_the_alarm(tmp_path: Path) -> None:
    accel = coupled_after_healthy(20, 20)
    run = Run(tmp_path, recorder_config(tmp_path / "rec", lead_in_s=3.0))
    run.feed(as_blocks(accel, start_s=START_S))
    run.recorder.close()
    assert run.kinds() == ["SUSPECTED", "CONFIRMED"]
    assert run.monitor.counters.judged == run.monitor.counters.windows  # every window counts towards confirmation
    confirmed_s = run.event_time(EventKind.CONFIRMED)
    # The oldest of the last 3 windows starts 2 hops and a window before the alarm's end; the
    # lead-in of 3 s is rounded up to 2 hops (4 s).
    first_s = confirmed_s - 2 * HOP_S - WINDOW_S - 4.0
    rec = read_csv_recording(tmp_path / "rec" / f"{stamp(first_s)}_confirmed.csv.gz")
    first = round((first_s - START_S) * FS_HZ)
    n = round((confirmed_s - first_s) * FS_HZ)
    assert rec.n_samples == n == 1400
    np.testing.assert_allclose(rec.time_s, START_S + np.arange(first, first + n) / FS_HZ, rtol=0, atol=1e-6)
    np.testing.assert_allclose(rec.accel_mps2, accel[first : first + n], rtol=0, atol=ACCEL_TOLERANCE_MPS2)
    assert run.recorder.counters.snapshots_written == 2 and run.recorder.counters.dropped == 0


def test_each_alarm_is_one_file_named_by_its_utc_start_and_reason_and_no_temporary_file_stays(tmp_path: Path) -> None:
    run = Run(tmp_path, recorder_config(tmp_path / "rec"))
    run.feed(as_blocks(coupled_after_healthy(20, 20), start_s=START_S))
    run.recorder.close()
    names = recordings(tmp_path / "rec")
    assert [n.split("_")[1] for n in names] == ["suspected.csv.gz", "confirmed.csv.gz"]
    assert all(NAME_PATTERN.fullmatch(n) for n in names)  # nothing else, no '.'-file
    for name in names:
        assert (tmp_path / "rec" / name).read_bytes()[:2] == b"\x1f\x8b"
        first_s = read_csv_recording(tmp_path / "rec" / name).time_s[0]
        assert name.startswith(stamp(first_s) + "_")


def test_as_parquet_the_snapshots_hold_the_fed_samples_exactly_and_read_as_the_csv_ones_do(tmp_path: Path) -> None:
    accel = coupled_after_healthy(20, 20)
    runs = {}
    for form in ("csv.gz", "parquet"):
        run = Run(tmp_path / form, recorder_config(tmp_path / form / "rec", f'format = "{form}"\n'))
        run.feed(as_blocks(accel, start_s=START_S))
        run.recorder.close()
        runs[form] = run
    names = {form: recordings(tmp_path / form / "rec") for form in runs}
    assert [n.replace(".parquet", ".csv.gz") for n in names["parquet"]] == names["csv.gz"]
    assert all(NAME_PATTERN.fullmatch(n) and n.endswith(".parquet") for n in names["parquet"])
    for csv_name, parquet_name in zip(names["csv.gz"], names["parquet"], strict=True):
        exact = read_recording(tmp_path / "parquet" / "rec" / parquet_name)
        text = read_recording(tmp_path / "csv.gz" / "rec" / csv_name)
        first = round((exact.time_s[0] - START_S) * FS_HZ)
        # As the ring holds them (float32: a 16-bit converter's every value, exactly), bit for bit.
        np.testing.assert_array_equal(exact.accel_mps2, accel[first : first + exact.n_samples].astype(np.float32))
        np.testing.assert_allclose(text.accel_mps2, exact.accel_mps2, rtol=0, atol=ACCEL_TOLERANCE_MPS2)


def test_shortly_after_the_start_a_snapshot_holds_what_there_is_from_the_first_sample(tmp_path: Path) -> None:
    accel = bogie_accel(12, seed=2, pitch_roll_coupling=1.0)
    run = Run(tmp_path, recorder_config(tmp_path / "rec", lead_in_s=60.0))
    run.feed(as_blocks(accel, start_s=START_S))
    run.recorder.close()
    confirmed_s = run.event_time(EventKind.CONFIRMED)
    (name,) = [n for n in recordings(tmp_path / "rec") if "confirmed" in n]
    rec = read_csv_recording(tmp_path / "rec" / name)
    assert rec.time_s[0] == pytest.approx(START_S, abs=1e-6)
    assert rec.n_samples == round((confirmed_s - START_S) * FS_HZ)
    np.testing.assert_allclose(rec.accel_mps2, accel[: rec.n_samples], rtol=0, atol=ACCEL_TOLERANCE_MPS2)


def test_a_snapshot_never_reaches_back_across_a_gap(tmp_path: Path) -> None:
    healthy, coupled = bogie_accel(20, seed=1), bogie_accel(20, seed=2, pitch_roll_coupling=1.0)
    after_gap_s = START_S + 20 + 7.3  # 7.3 s of samples lost
    run = Run(tmp_path, recorder_config(tmp_path / "rec", lead_in_s=60.0))
    run.feed(as_blocks(healthy, start_s=START_S) + [
        Block(b.start_s, b.fs_hz, b.accel_mps2, gap_before=i == 0) for i, b in enumerate(as_blocks(coupled, start_s=after_gap_s))
    ])  # fmt: skip
    run.recorder.close()
    assert run.kinds() == ["SUSPECTED", "CONFIRMED"]
    (name,) = [n for n in recordings(tmp_path / "rec") if "confirmed" in n]
    rec = read_csv_recording(tmp_path / "rec" / name)
    assert rec.time_s[0] == pytest.approx(after_gap_s, abs=1e-6)
    np.testing.assert_allclose(rec.accel_mps2, coupled[: rec.n_samples], rtol=0, atol=ACCEL_TOLERANCE_MPS2)


def test_a_name_taken_by_an_older_file_gets_a_counter_and_the_old_file_is_kept(tmp_path: Path) -> None:
    accel = bogie_accel(12, seed=2, pitch_roll_coupling=1.0)
    directory = tmp_path / "rec"
    directory.mkdir()
    (directory / f"{stamp(START_S)}_confirmed.csv.gz").write_bytes(b"an earlier run's")
    run = Run(tmp_path, recorder_config(directory, lead_in_s=60.0))
    run.feed(as_blocks(accel, start_s=START_S))
    run.recorder.close()
    assert (directory / f"{stamp(START_S)}_confirmed.csv.gz").read_bytes() == b"an earlier run's"
    assert read_csv_recording(directory / f"{stamp(START_S)}_confirmed-2.csv.gz").time_s[0] == pytest.approx(START_S, abs=1e-6)


def test_over_the_cap_the_oldest_recordings_are_deleted_and_nothing_that_is_not_the_recorders(tmp_path: Path) -> None:
    directory = tmp_path / "rec"
    directory.mkdir()
    older = {"20200101T000000Z_periodic.csv.gz": 720_000, "20200102T000000Z_suspected.csv.gz": 300_000}
    foreign = ["events.sqlite3", "notes.txt", "20190101T000000Z_other.csv.gz", "old.csv.gz", ".20190101T000000Z_periodic.csv.gz.part"]
    for name, size in older.items():
        (directory / name).write_bytes(bytes(size))
    for name in foreign:
        (directory / name).write_bytes(bytes(2_000_000))
    (directory / "20180101T000000Z_confirmed.csv.gz").symlink_to(directory / "notes.txt")
    run = Run(tmp_path, recorder_config(directory, "max_total_bytes = 1048576\n"))
    run.feed(as_blocks(coupled_after_healthy(20, 20), start_s=START_S))
    run.recorder.close()
    names = recordings(directory)
    assert "20200101T000000Z_periodic.csv.gz" not in names  # the oldest: 720 kB + 300 kB + two snapshots of 23 kB > 1 MiB
    assert "20200102T000000Z_suspected.csv.gz" in names
    assert set(foreign) | {"20180101T000000Z_confirmed.csv.gz"} <= set(names)
    assert run.recorder.counters.files_deleted == 1 and run.recorder.counters.bytes_deleted == 720_000


def test_a_snapshot_larger_than_the_cap_is_written_and_then_is_the_only_recording(tmp_path: Path) -> None:
    directory = tmp_path / "rec"
    directory.mkdir()
    (directory / "20200101T000000Z_periodic.csv.gz").write_bytes(bytes(10))
    settings = RecorderSettings(directory, lead_in_s=3.0, max_total_bytes=1000, window_s=WINDOW_S, hop_s=HOP_S, confirm_n=CONFIRM_N, max_block_s=0.5)
    run = Run(tmp_path, recorder_config(directory), Recorder(settings))
    run.feed(as_blocks(coupled_after_healthy(20, 20), start_s=START_S))
    run.recorder.close()
    (name,) = recordings(directory)
    assert "confirmed" in name and (directory / name).stat().st_size > 1000


class HeldWriter:
    """The real writer, held until released; says when it has begun."""

    def __init__(self) -> None:
        self.began, self.release = threading.Event(), threading.Event()

    def __call__(self, path: Path, time_s: np.ndarray, accel_mps2: np.ndarray) -> None:
        self.began.set()
        assert self.release.wait(10)
        write_csv_recording(path, time_s, accel_mps2, fsync=True)


def test_with_the_writer_behind_a_full_queue_drops_and_counts_recordings_and_every_event_is_kept(tmp_path: Path) -> None:
    writer = HeldWriter()
    config = recorder_config(tmp_path / "rec")
    settings = config.recorder_settings()
    assert settings is not None
    run = Run(tmp_path, config, Recorder(settings, queue_size=1, write=writer))
    # Two alarms, each SUSPECTED then CONFIRMED: the first is being written, the second waits
    # in the queue of one, and the second alarm's two find it full.
    accel = np.vstack([bogie_accel(12, seed=2, pitch_roll_coupling=1.0), bogie_accel(30, seed=1), bogie_accel(12, seed=3, pitch_roll_coupling=1.0)])
    blocks = as_blocks(accel, start_s=START_S)
    with structlog.testing.capture_logs() as logs:
        for block in blocks:
            run.feed([block])
            if run.events and not writer.began.is_set():
                assert writer.began.wait(10)
        writer.release.set()
        run.recorder.close()
    assert run.kinds() == ["SUSPECTED", "CONFIRMED", "CLEARED", "SUSPECTED", "CONFIRMED"]
    assert run.recorder.counters.dropped == 2 and run.recorder.counters.snapshots_written == 2
    assert [e["reason"] for e in logs if e["event"] == "recording dropped: the writer is behind"] == ["suspected", "confirmed"]
    assert len(recordings(tmp_path / "rec")) == 2


def test_a_failing_disk_is_counted_and_logged_and_never_reaches_the_monitor(tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("not a folder")
    directory = tmp_path / "a-file" / "rec"  # every mkdir and write under it fails
    with structlog.testing.capture_logs() as logs:
        run = Run(tmp_path, recorder_config(directory))
        run.feed(as_blocks(coupled_after_healthy(20, 20), start_s=START_S))
        run.recorder.close()
    assert run.kinds() == ["SUSPECTED", "CONFIRMED"]
    assert run.recorder.counters.write_errors == 3  # the folder at start, and each snapshot
    assert run.recorder.counters.snapshots_written == 0
    errors = [e for e in logs if e["log_level"] == "error"]
    assert [e["event"] for e in errors] == ["cannot prepare the recordings folder"] + ["cannot write a recording, it is lost"] * 2
    assert all(e["path"].startswith(str(directory)) for e in errors)
    stopped = [e for e in logs if e["event"] == "recorder stopped"]
    assert stopped and stopped[0]["write_errors"] == 3


def test_periodic_recordings_hold_the_periodic_s_after_every_period_of_running(tmp_path: Path) -> None:
    accel = bogie_accel(20, seed=1)
    # Every 0.002 h (7.2 s) of running, the next 3 s.
    run = Run(tmp_path, recorder_config(tmp_path / "rec", "periodic_every_h = 0.002\nperiodic_s = 3.0\n"))
    run.feed(as_blocks(accel, start_s=START_S))
    run.recorder.close()
    names = recordings(tmp_path / "rec")
    assert [n.split("_")[1] for n in names] == ["periodic.csv.gz", "periodic.csv.gz"]
    assert run.recorder.counters.periodic_written == 2 and run.recorder.counters.snapshots_written == 0
    for k, name in enumerate(names, start=1):
        rec = read_csv_recording(tmp_path / "rec" / name)
        first = round(k * 7.2 * FS_HZ)
        assert rec.n_samples == 300
        np.testing.assert_allclose(rec.time_s, START_S + np.arange(first, first + 300) / FS_HZ, rtol=0, atol=1e-6)
        np.testing.assert_allclose(rec.accel_mps2, accel[first : first + 300], rtol=0, atol=ACCEL_TOLERANCE_MPS2)


def test_periodic_recordings_keep_their_period_when_a_block_holds_the_end_of_one_and_the_start_of_the_next(tmp_path: Path) -> None:
    # The fuzz finding (recorder-disk, seed 17 input 182): blocks of 2 s, a recording of 2.6 s every
    # 3.34 s. The next one started only in the block after the last one ended, later each time,
    # until a period passed without one: 13 written for 15 periods.
    accel = bogie_accel(51, seed=1)
    period_n = 333 + 0.618  # samples: never a sample's time exactly
    extra = f"periodic_every_h = {period_n / FS_HZ / 3600!r}\nperiodic_s = 2.6\n"
    run = Run(tmp_path, recorder_config(tmp_path / "rec", extra))
    for block in as_blocks(accel, start_s=START_S, block_n=200):
        run.feed([block])
        assert run.recorder.wait_written()  # a queue of 4 would drop some, as fast as they come here
    run.recorder.close()
    names = recordings(tmp_path / "rec")
    firsts = [int(np.ceil(k * period_n)) for k in range(1, 16)]  # the first sample after every period
    assert len(names) == run.recorder.counters.periodic_written == 15
    for first, name in zip(firsts, names, strict=True):
        rec = read_csv_recording(tmp_path / "rec" / name)
        n = min(260, accel.shape[0] - first)
        np.testing.assert_allclose(rec.time_s, START_S + np.arange(first, first + n) / FS_HZ, rtol=0, atol=1e-6)
        np.testing.assert_allclose(rec.accel_mps2, accel[first : first + n], rtol=0, atol=ACCEL_TOLERANCE_MPS2)


def test_a_periodic_recording_cut_by_a_gap_is_written_up_to_it(tmp_path: Path) -> None:
    accel = bogie_accel(10, seed=1)
    blocks = as_blocks(accel, start_s=START_S, gap_at={800})  # a gap at 8 s, inside the recording from 7.2 s
    run = Run(tmp_path, recorder_config(tmp_path / "rec", "periodic_every_h = 0.002\nperiodic_s = 3.0\n"))
    run.feed(blocks)
    run.recorder.close()
    (name,) = recordings(tmp_path / "rec")
    assert read_csv_recording(tmp_path / "rec" / name).n_samples == 80


def test_the_recorder_section_is_validated_with_its_field_named() -> None:
    with pytest.raises(ValueError, match=r"recorder.lead_in_s: Input should be less than or equal to 600"):
        parse_config("[recorder]\nlead_in_s = 601\n", "t")
    with pytest.raises(ValueError, match=r"recorder.max_total_bytes: Input should be greater than or equal to 1048576"):
        parse_config("[recorder]\nmax_total_bytes = 1000\n", "t")
    with pytest.raises(ValueError, match=r"recorder: periodic_s \(600\) must not exceed the period periodic_every_h \(0.1 h = 360 s\)"):
        parse_config("[recorder]\nperiodic_every_h = 0.1\nperiodic_s = 600\n", "t")
    assert BogiemonConfig().recorder_settings() is None  # off by default


# --- the service ------------------------------------------------------------------------------------


class FiniteMemorySource(MemorySource):
    finite = True


def test_the_service_records_the_alarms_when_enabled_and_logs_the_counters_at_stop(tmp_path: Path) -> None:
    path = tmp_path / "bogiemon.toml"
    path.write_text(short_windows_config(state_dir=tmp_path / "state") + f'[recorder]\nenabled = true\ndirectory = "{tmp_path / "rec"}"\n')
    blocks = as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0), start_s=START_S)
    service = Service(path, lambda config: FiniteMemorySource(blocks), sinks=[])
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    assert service.recorder is not None and service.recorder.counters.snapshots_written == 2
    assert sorted(n.split("_")[1] for n in recordings(tmp_path / "rec")) == ["confirmed.csv.gz", "suspected.csv.gz"]
    (stopped,) = [e for e in logs if e["event"] == "recorder stopped"]
    assert stopped["snapshots_written"] == 2 and stopped["dropped"] == 0


def test_the_service_records_nothing_when_the_recorder_is_not_enabled(tmp_path: Path, short_config: Path) -> None:
    blocks = as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0), start_s=START_S)
    service = Service(short_config, lambda config: FiniteMemorySource(blocks), sinks=[])
    assert service.run() == 0
    assert service.recorder is None


def test_a_reload_that_changes_the_recorder_section_records_into_the_new_folder(tmp_path: Path, own_signal_handlers: None) -> None:  # noqa: F811 - the fixture imported above
    path = tmp_path / "bogiemon.toml"
    base = short_windows_config(state_dir=tmp_path / "state") + "[recorder]\nenabled = true\n"
    path.write_text(base + f'directory = "{tmp_path / "old"}"\n')
    # SIGHUP at 5 s, before the first window ends: both alarms come under the new config.
    feed = Feed(as_blocks(bogie_accel(30, seed=2, pitch_roll_coupling=1.0), start_s=START_S), 10, path, base + f'directory = "{tmp_path / "new"}"\n')
    service = Service(path, lambda config: FeedSource(feed), sinks=[])
    service.install_signal_handlers()

    def release_once_reloaded() -> None:  # the feed holds at the SIGHUP until the new recorder runs
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and not (service.recorder and service.recorder.settings.directory == tmp_path / "new"):
            time.sleep(0.01)
        feed.released.set()

    releaser = threading.Thread(target=release_once_reloaded)
    releaser.start()
    with structlog.testing.capture_logs() as logs:
        assert service.run() == 0
    releaser.join()
    assert any(e["event"] == "reloaded" for e in logs)
    assert service.recorder is not None and service.recorder.settings.directory == tmp_path / "new"
    assert recordings(tmp_path / "old") == []
    assert sorted(n.split("_")[1] for n in recordings(tmp_path / "new")) == ["confirmed.csv.gz", "suspected.csv.gz"]
    assert [e["snapshots_written"] for e in logs if e["event"] == "recorder stopped"] == [0, 2]  # the old one, then the new


# --- THE KEY TEST: the recording of a fault replays into the same alarm ------------------------------

CALIBRATION = Path(str(resources.files("bogiemon.config").joinpath("demo_calibration.toml")))
# A snapshot reaches lead_in_s (60 s) + window_s (120 s) + (confirm_n - 1) hops (40 s) = 220 s back
# from the confirming window's end: a spring breaking later than that leaves a healthy start to cut.
SPRING_BREAKS_S, RUN_S = 240.0, 330.0


@pytest.mark.slow  # the simulator's kernel compiles on a machine's first run (~15 s); then about 3 s
def test_the_confirmed_snapshot_of_a_broken_spring_replayed_alone_from_a_fresh_state_confirms_it_at_the_same_corner(tmp_path: Path) -> None:
    from bogiemon.simulator import Scenario, parse_fault, simulate

    # The demo's commissioned wagon (config/demo.toml, demo_calibration.toml), full load at 80 km/h.
    config_path = tmp_path / "bogiemon.toml"
    config_path.write_text(
        f'allow_absolute_includes = true\ninclude = ["{CALIBRATION}"]\n[decision]\nload = "full"\n'
        f'[state]\ndirectory = "{tmp_path / "state"}"\n[recorder]\nenabled = true\ndirectory = "{tmp_path / "rec"}"\n'
    )
    config = load_config(config_path)
    # Healthy long enough that the snapshot starts after the run does: it holds its own lead-in.
    fault = parse_fault("type_a:rear_outer:0.0@leading-left")
    run_samples = simulate(Scenario(load="full", duration_s=RUN_S, seed=1, faults=(fault,), fault_onset_s=SPRING_BREAKS_S))
    start_s = 1.798e9  # 2026-12-23T...: Unix time, as a gateway stamps its samples
    fs_hz = run_samples.scenario.fs_hz
    blocks = [
        Block(start_s + i / fs_hz, fs_hz, run_samples.accel_mps2[i : i + 500], gap_before=i == 0)
        for i in range(0, run_samples.accel_mps2.shape[0], 500)
    ]
    run = Run(tmp_path, config)
    run.feed(blocks)
    run.recorder.close()
    (confirmed,) = [e for e in run.events if e.kind is EventKind.CONFIRMED]
    assert details_as(confirmed, ConfirmedDetails).trigger is Trigger.WINDOWS
    (snapshot,) = [tmp_path / "rec" / n for n in recordings(tmp_path / "rec") if n.endswith("_confirmed.csv.gz")]
    recording = read_csv_recording(snapshot)
    assert recording.time_s[0] > start_s + 1.0  # cut: the lead-in before the confirming windows, not the whole run
    assert recording.time_s[-1] < confirmed.time_s

    sink = MemorySink()
    replay([snapshot], config, sinks=[sink])  # a fresh event store of its own
    (replayed,) = [e for e in sink.events if e.kind is EventKind.CONFIRMED]
    assert replayed.time_s == pytest.approx(confirmed.time_s, abs=1e-3)  # at the same window
    # The same diagnosis offline as onboard; its corner the broken spring's, or "unknown" where the
    # three confirming windows' 4-8 Hz couplings do not single it out (judgement/diagnosis.py).
    onboard, offline = details_as(confirmed, ConfirmedDetails), details_as(replayed, ConfirmedDetails)
    assert offline.diagnosis == onboard.diagnosis and onboard.diagnosis is not None
    assert onboard.diagnosis.corners in ((Corner.LEADING_LEFT, Corner.TRAILING_RIGHT), ())
    said = "(leading-left if softer)" if onboard.diagnosis.corners else "no pair named"  # an unknown corner names no pair
    assert onboard.diagnosis.best_match.endswith(said)
    assert offline.alarm_windows == onboard.alarm_windows
