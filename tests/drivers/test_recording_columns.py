"""Recordings as other people write them: a wrong unit refused in the user's words, columns
mapped by name, delimiters sniffed, times in ms or as Parquet timestamps, jitter resampled onto
the nominal grid and counted, a gap called a gap."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from bogiemon.drivers.base import EndOfStream
from bogiemon.drivers.columns import STANDARD_GRAVITY_MPS2, AccelUnit, ColumnMap, parse_columns, unit_problem, with_gains
from bogiemon.drivers.recording import RecordingError, open_recording_reader, read_recording, write_csv_recording
from bogiemon.drivers.replay import RecordingReplaySource

FS_HZ = 500.0


def bogie(n: int, level: float, seed: int = 0) -> np.ndarray:
    """(n, 3) vertical accelerations around a static level (1 g in the unit asked for)."""
    rng = np.random.default_rng(seed)
    return level + 0.05 * level * rng.normal(size=(n, 3))


def write_text(path: Path, header: str, rows: np.ndarray, delimiter: str = ",") -> Path:
    lines = [header] + [delimiter.join(repr(float(v)) for v in row) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


# --- Units ----------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("level", "said"),
    [(1.0, r"these values look like g \(1 g: static levels 1, 1, 1\), not m/s\^2"), (9806.65, r"these values look like mm/s\^2 \(1 g: static levels 9807, 9807, 9807\)")],
    ids=["g", "mm/s^2"],
)
def test_a_csv_recording_in_another_unit_is_refused_naming_the_unit_it_looks_like(tmp_path: Path, level: float, said: str) -> None:
    t = np.arange(5000) / FS_HZ
    a = np.full((t.size, 3), level)
    write_csv_recording(tmp_path / "r.csv", t, a)
    with pytest.raises(RecordingError, match=rf"r.csv: {said}.*set the unit: --unit "):
        open_recording_reader(tmp_path / "r.csv")


def test_a_parquet_recording_in_g_is_refused_and_read_in_m_per_s2_once_its_unit_is_set(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    t = np.arange(5000) / FS_HZ
    a = bogie(t.size, 1.0)
    pq.write_table(pa.table({"time_s": t, "a1": a[:, 0], "a2": a[:, 1], "a3": a[:, 2]}), tmp_path / "g.parquet")
    with pytest.raises(RecordingError, match=r"g.parquet: these values look like g"):
        read_recording(tmp_path / "g.parquet")
    rec = read_recording(tmp_path / "g.parquet", columns=ColumnMap(unit=AccelUnit.G))
    np.testing.assert_array_equal(rec.accel_mps2, a * STANDARD_GRAVITY_MPS2)


def test_levels_near_zero_say_nothing_about_the_unit() -> None:
    # gravity removed by the logger: judged in the unit stated
    assert unit_problem(bogie(1000, 0.0) + np.random.default_rng(1).normal(size=(1000, 3)) * 0.1, AccelUnit.MPS2) is None
    assert unit_problem(bogie(1000, STANDARD_GRAVITY_MPS2), AccelUnit.MPS2) is None


# --- Column mapping -------------------------------------------------------------------------------


def test_semicolons_other_names_an_extra_column_and_times_in_ms_are_read_by_the_mapping(tmp_path: Path) -> None:
    t = np.arange(3000) / FS_HZ
    a = bogie(t.size, STANDARD_GRAVITY_MPS2)
    speed = np.full(t.size, 80.0)
    rows = np.column_stack([speed, t * 1000.0, a[:, 2], a[:, 0], a[:, 1]])
    path = write_text(tmp_path / "logger.csv", "speed_kmh;Time [ms];acc_rl;acc_fl;acc_fr", rows, delimiter=";")
    columns = parse_columns("a1=acc_fl,a2=acc_fr,a3=acc_rl")
    rec = read_recording(path, columns=columns)
    assert rec.fs_hz == FS_HZ
    np.testing.assert_allclose(rec.time_s, t, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(rec.accel_mps2, a)


def test_a_channels_gain_and_offset_are_applied_before_the_unit(tmp_path: Path) -> None:
    t = np.arange(3000) / FS_HZ
    a = bogie(t.size, 1.0)
    write_csv_recording(tmp_path / "r.csv", t, a)
    columns = with_gains(ColumnMap(unit=AccelUnit.G), {"a2": 2.0}, {"a3": 0.5})
    rec = read_recording(tmp_path / "r.csv", columns=columns)
    raw = np.round(a, 6)  # as the CSV holds them
    expected = np.column_stack([raw[:, 0], raw[:, 1] * 2.0, raw[:, 2] + 0.5]) * STANDARD_GRAVITY_MPS2
    np.testing.assert_allclose(rec.accel_mps2, expected, rtol=1e-15)


def test_a_mapping_naming_a_column_the_file_lacks_says_which_and_how_to_map(tmp_path: Path) -> None:
    t = np.arange(100) / FS_HZ
    path = write_text(tmp_path / "r.csv", "ts,x,y,z", np.column_stack([t, bogie(t.size, 9.81)]))
    with pytest.raises(RecordingError, match=r"r.csv: line 1: .*found 'ts,x,y,z': no column 'a1', no column 'a2', no column 'a3' .*--columns time=NAME"):
        open_recording_reader(path)
    assert read_recording(path, columns=parse_columns("a1=x,a2=y,a3=z")).n_samples == 100


def test_a_mapping_text_that_names_no_channel_is_refused() -> None:
    with pytest.raises(ValueError, match=r"'b1' is no channel: use time or a1, a2, a3"):
        parse_columns("b1=x")


def test_parquet_float32_int_and_timestamp_columns_are_read_as_seconds_and_float64(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    start_ns = 1_764_756_000_000_000_000  # 2025-12-03T10:00:00Z
    n = 2000
    stamps = pa.array(start_ns + np.arange(n) * 2_000_000, pa.timestamp("ns", tz="UTC"))
    a = bogie(n, STANDARD_GRAVITY_MPS2)
    counts = np.round(a[:, 2] * 1000).astype(np.int32)  # a logger's integer counts, in mm/s^2
    table = pa.table({"timestamp": stamps, "a1": a[:, 0].astype(np.float32), "a2": a[:, 1], "z_mm": counts})
    pq.write_table(table, tmp_path / "r.parquet")
    columns = with_gains(parse_columns("a3=z_mm"), {"a3": 1e-3}, {})
    rec = read_recording(tmp_path / "r.parquet", columns=columns)
    assert rec.fs_hz == FS_HZ and rec.start_s == start_ns / 1e9
    np.testing.assert_array_equal(rec.accel_mps2[:, 0], a[:, 0].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(rec.accel_mps2[:, 2], counts * 1e-3)


# --- Jitter and gaps ------------------------------------------------------------------------------


def test_jitter_within_the_tolerance_is_resampled_onto_the_nominal_grid_and_counted(tmp_path: Path) -> None:
    n = 20_000
    nominal_s = np.arange(n) / FS_HZ
    t = nominal_s + np.random.default_rng(3).uniform(-0.0002, 0.0002, n)  # +-0.2 ms, as loggers stamp
    t[0] = 0.0
    a = bogie(n, STANDARD_GRAVITY_MPS2)
    path = write_text(tmp_path / "jitter.csv", "time_s,a1,a2,a3", np.column_stack([t, a]))
    reader = open_recording_reader(path)
    parts = list(reader.chunks())
    got_t, got_a = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    assert reader.fs_hz == FS_HZ and reader.gap_count == 0
    # the reference: the whole file's rows interpolated at once onto the grid they span
    grid_s = t[0] + np.arange(int(np.floor(t[-1] * FS_HZ)) + 1) * (1.0 / FS_HZ)
    np.testing.assert_allclose(got_t, grid_s, rtol=0, atol=1e-12)
    expected = np.column_stack([np.interp(grid_s, t, a[:, c]) for c in range(3)])
    np.testing.assert_allclose(got_a, expected, rtol=0, atol=1e-12)
    assert reader.resampled_samples == got_t.size
    assert 0.0003 < reader.max_jitter_s <= 0.0004


def test_twenty_seconds_missing_at_500_hz_is_a_gap_not_a_rate_and_the_replay_starts_a_segment_after_it(tmp_path: Path) -> None:
    t = np.concatenate([np.arange(30_000), np.arange(40_000, 70_000)]) / FS_HZ
    write_csv_recording(tmp_path / "gap.csv", t, bogie(t.size, STANDARD_GRAVITY_MPS2))
    source = RecordingReplaySource(tmp_path / "gap.csv", rate=0, max_block_s=1.0)
    assert source.fs_hz == FS_HZ
    blocks = []
    try:
        while True:
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    except EndOfStream:
        pass
    finally:
        source.close()
    gaps = [b.start_s for b in blocks if b.gap_before]
    assert gaps == [0.0, 80.0]
    assert source.counters.extra["recording_gaps"] == 1 and source.counters.extra["resampled_samples"] == 0
    assert all(b.start_s + b.n_samples / FS_HZ <= 60.0 + 1e-9 or b.start_s >= 80.0 for b in blocks)  # none spans it
    assert sum(b.n_samples for b in blocks) == t.size
    assert source.reader.gaps[0].after_s == pytest.approx(59.998) and source.reader.gaps[0].missing_s == pytest.approx(20.0)


def test_a_row_closer_than_the_jitter_allows_is_an_error_naming_its_line(tmp_path: Path) -> None:
    t = np.arange(5000) / FS_HZ
    t = np.insert(t, 3000, t[2999] + 0.0004)  # a stray row 0.4 ms after the one before: 80 % short
    write_csv_recording(tmp_path / "stray.csv", t, bogie(t.size, STANDARD_GRAVITY_MPS2))
    with pytest.raises(RecordingError, match=r"stray.csv: line 3002: time step 0.0004 s is shorter than the file's 0.002 s \(500 Hz\)"):
        read_recording(tmp_path / "stray.csv")


# --- MF4 of signals -------------------------------------------------------------------------------


def write_mf4_signals(path: Path, time_s: np.ndarray, values: np.ndarray, names: tuple[str, ...]) -> None:
    """An MF4 of signals as a bench writes it with asammdf: one group, its time master and channels."""
    from asammdf import MDF, Signal

    mdf = MDF(version="4.10")
    mdf.append([Signal(values[:, i], time_s, name=name, unit="") for i, name in enumerate(names)])
    mdf.save(path, overwrite=True)
    mdf.close()


def test_an_mf4_of_signals_in_g_is_refused_and_read_with_its_unit_and_channel_names(tmp_path: Path) -> None:
    pytest.importorskip("asammdf", reason="the mf4 extra is installed in the test venv")
    t = np.arange(3000) / FS_HZ
    a = bogie(t.size, 1.0)
    path = tmp_path / "bench.mf4"
    write_mf4_signals(path, t, a, ("acc_fl", "acc_fr", "acc_rl"))
    with pytest.raises(RecordingError, match=r"bench.mf4: no channel a1, a2, a3 \(its channels: .*acc_fl.*--columns time=NAME"):
        open_recording_reader(path)
    columns = parse_columns("a1=acc_fl,a2=acc_fr,a3=acc_rl")
    with pytest.raises(RecordingError, match=r"bench.mf4: these values look like g"):
        open_recording_reader(path, columns=columns)
    reader = open_recording_reader(path, columns=ColumnMap(columns.time, columns.time_unit, columns.channels, AccelUnit.G))
    try:
        parts = list(reader.chunks())
        start_s = reader.start_s
    finally:
        reader.close()
    assert reader.format == "mf4" and reader.fs_hz == FS_HZ
    # absolute times (the file's start, about 1.76e9 s): float64 holds them to 2.4e-7 s
    np.testing.assert_allclose(np.concatenate([p[0] for p in parts]) - start_s, t, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), a * STANDARD_GRAVITY_MPS2)


def test_jitter_after_a_long_clean_stretch_of_a_clock_off_the_whole_hertz_loses_no_time(tmp_path: Path) -> None:
    # 500.2 Hz is taken as 500 (within 0.05 %); after 60 s, 0.024 % off, the logger's stamps jitter.
    n = 40_000
    t = np.arange(n) / 500.2
    t[30_000:] += np.random.default_rng(5).uniform(-0.0002, 0.0002, n - 30_000)
    write_csv_recording(tmp_path / "drift.csv", t, bogie(n, STANDARD_GRAVITY_MPS2))
    reader = open_recording_reader(tmp_path / "drift.csv")
    got_t = np.concatenate([p[0] for p in reader.chunks()])
    assert reader.fs_hz == FS_HZ and reader.gap_count == 0 and reader.resampled_samples > 0
    assert float(np.max(np.diff(got_t))) < 1.01 / FS_HZ  # no time skipped where the resampling starts
    assert got_t[-1] == pytest.approx(t[-1], abs=1.0 / FS_HZ)


def test_another_writers_csv_on_an_install_without_pyarrow_is_one_line_saying_so(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from bogiemon.drivers import recording_csv

    monkeypatch.setattr(recording_csv, "parquet_available", lambda: False)  # a gateway's install
    t = np.arange(100) / FS_HZ
    path = write_text(tmp_path / "r.csv", "time;a1;a2;a3", np.column_stack([t, bogie(t.size, 9.81)]), delimiter=";")
    with pytest.raises(RecordingError, match=r"r.csv: a CSV of other columns than time_s,a1,a2,a3 is read with pyarrow, which this install leaves out"):
        open_recording_reader(path)
    write_csv_recording(tmp_path / "own.csv", t, bogie(t.size, 9.81))  # bogiemon's own four columns need no mapping
    assert read_recording(tmp_path / "own.csv").n_samples == 100
