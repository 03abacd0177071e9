"""A wagon's recording (time_s,a1,a2,a3,b1,b2,b3: both bogies on one time axis) in CSV, .csv.gz and
Parquet: written and read back bit for bit, a one-bogie recording unchanged beside it, any other
header refused naming both, and its replay giving each bogie's blocks as a stream of its own."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.drivers.recording import (
    HEADER,
    WAGON_HEADER,
    RecordingError,
    open_recording_reader,
    read_recording,
    refuse_wagon,
    write_recording,
)
from bogiemon.drivers.replay import RecordingReplaySource, open_replay

NAMES = ("wagon.csv", "wagon.csv.gz", "wagon.parquet")
FS_HZ = 500.0


def six_decimal_samples(n: int, channels: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Samples a CSV holds exactly (the values its 6 decimals read back as), on Unix time."""
    rng = np.random.default_rng(seed)
    time_s = np.array([float(f"{x:.6f}") for x in 1.7e9 + np.arange(n) / FS_HZ])
    accel = np.array([[float(f"{x:.6f}") for x in row] for row in rng.normal(9.81, 2.0, size=(n, channels))])
    return time_s, accel


def drain(source: Source) -> list[Block]:
    blocks = []
    with pytest.raises(EndOfStream):
        for _ in range(10_000):
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    return blocks


@pytest.mark.parametrize("name", NAMES)
def test_a_wagons_recording_round_trips_bit_for_bit(tmp_path: Path, name: str) -> None:
    time_s, accel = six_decimal_samples(3000, 6)
    write_recording(tmp_path / name, time_s, accel)
    rec = read_recording(tmp_path / name)
    assert rec.bogies == 2 and rec.accel_mps2.shape == (3000, 6)
    np.testing.assert_array_equal(rec.time_s, time_s)
    np.testing.assert_array_equal(rec.accel_mps2, accel)
    assert rec.fs_hz == 500.0  # the steps' rate snapped to the whole hertz (recording_check.py)
    # What is read writes the same bytes again: nothing lost or added on the way.
    write_recording(tmp_path / f"again-{name}", rec.time_s, rec.accel_mps2)
    assert (tmp_path / f"again-{name}").read_bytes() == (tmp_path / name).read_bytes()


def test_a_wagons_csv_has_the_wagon_header_and_seven_values_a_row(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(3, 6)
    write_recording(tmp_path / "wagon.csv.gz", time_s, accel)
    lines = gzip.decompress((tmp_path / "wagon.csv.gz").read_bytes()).decode().splitlines()
    assert lines[0] == WAGON_HEADER == "time_s,a1,a2,a3,b1,b2,b3"
    assert lines[1] == ",".join(f"{v:.6f}" for v in (time_s[0], *accel[0]))


def test_a_wagons_parquet_has_the_seven_float64_columns(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    time_s, accel = six_decimal_samples(10, 6)
    write_recording(tmp_path / "wagon.parquet", time_s, accel)
    schema = pq.read_schema(tmp_path / "wagon.parquet")
    assert schema.names == WAGON_HEADER.split(",")
    assert set(schema.types) == {pa.float64()}


@pytest.mark.parametrize("name", NAMES)
def test_bogie_1_is_a_columns_and_bogie_2_the_b_columns_of_a_file_written_by_another_tool(tmp_path: Path, name: str) -> None:
    # Written column by column by name, not by our writer: the columns are read by their names' order.
    time_s, accel = six_decimal_samples(50, 6, seed=3)
    columns = dict(zip(WAGON_HEADER.split(","), [time_s, *accel.T], strict=True))
    path = tmp_path / name
    if name.endswith(".parquet"):
        import pyarrow as pa
        import pyarrow.parquet as pq

        pq.write_table(pa.table(columns), path)
    else:
        text = WAGON_HEADER + "\n" + "".join(",".join(repr(float(columns[c][i])) for c in columns) + "\n" for i in range(50))
        path.write_bytes(gzip.compress(text.encode()) if name.endswith(".gz") else text.encode())
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.bogie_accel(0), np.column_stack([columns["a1"], columns["a2"], columns["a3"]]))
    np.testing.assert_array_equal(rec.bogie_accel(1), np.column_stack([columns["b1"], columns["b2"], columns["b3"]]))


@pytest.mark.parametrize("name", NAMES)
def test_a_one_bogie_recording_is_written_and_read_as_before(tmp_path: Path, name: str) -> None:
    time_s, accel = six_decimal_samples(200, 3)
    write_recording(tmp_path / name, time_s, accel)
    reader = open_recording_reader(tmp_path / name)
    assert reader.column_set == tuple(HEADER.split(",")) and reader.bogies == 1
    rec = reader.read_all()
    assert rec.bogies == 1
    np.testing.assert_array_equal(rec.accel_mps2, accel)
    if name == "wagon.csv":
        assert (tmp_path / name).read_text().splitlines()[:2] == [HEADER, ",".join(f"{v:.6f}" for v in (time_s[0], *accel[0]))]


@pytest.mark.parametrize(
    ("header", "why"),
    [
        ("time_s,a1,a2,a3,b1,b2", "': bogie 2's b1, b2 without the rest of b1, b2, b3"),
        ("time_s,a1,a2,a3,b1,b2,b3,c1", None),
        ("time_s,a1,a2,a3,b1,b2,b3,", None),
    ],
    ids=["five-channels", "seven-channels", "trailing-comma"],
)
def test_a_header_that_is_neither_set_is_refused_in_one_line_naming_both(tmp_path: Path, header: str, why: str | None) -> None:
    # Part of bogie 2 is never read as bogie 1 with the rest dropped unsaid; a wagon's columns
    # among others are read by name, and a row that does not fill the header is named by its line.
    path = tmp_path / "odd.csv"
    path.write_text(header + "\n0,1,2,3,4,5,6\n0.002,1,2,3,4,5,6\n")
    with pytest.raises(RecordingError) as info:
        read_recording(path)
    if why is not None:
        assert str(info.value) == (
            f"{path}: line 1: expected the header 'time_s,a1,a2,a3' (or 'time_s,a1,a2,a3,b1,b2,b3': both bogies) or the columns of "
            f"a mapping, found '{header}{why}"
        )
    else:
        assert str(info.value).startswith(f"{path}: line 2: expected 8 comma-separated values")


def test_a_wagons_columns_in_another_order_are_read_by_their_names(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(50, 6, seed=5)
    path = tmp_path / "swapped.csv"
    rows = "".join(",".join(f"{v:.6f}" for v in (t, *a[3:], *a[:3])) + "\n" for t, a in zip(time_s, accel, strict=True))
    path.write_text("time_s,b1,b2,b3,a1,a2,a3\n" + rows)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.accel_mps2, accel)


def test_parquet_columns_that_are_neither_set_are_refused_in_one_line_naming_both(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({name: [0.0, 0.002] for name in ("time_s", "a1", "a2", "a3", "b1", "b2")}), tmp_path / "odd.parquet")
    with pytest.raises(RecordingError) as info:
        read_recording(tmp_path / "odd.parquet")
    assert str(info.value).startswith(
        f"{tmp_path / 'odd.parquet'}: expected the columns time_s, a1, a2, a3 (or time_s, a1, a2, a3, b1, b2, b3: both bogies) or those "
        "of a mapping, found time_s, a1, a2, a3, b1, b2: "
    )


def test_a_wagons_row_of_a_one_bogie_count_is_named_by_its_line(tmp_path: Path) -> None:
    path = tmp_path / "wagon.csv"
    path.write_text(WAGON_HEADER + "\n0,1,2,3,4,5,6\n0.002,1,2,3\n0.004,1,2,3,4,5,6\n")
    with pytest.raises(RecordingError, match=r"wagon.csv: line 3: expected 7 comma-separated values \(time_s,a1,a2,a3,b1,b2,b3\), found 4$"):
        read_recording(path)


def test_a_bad_b_column_is_named(tmp_path: Path) -> None:
    path = tmp_path / "wagon.csv"
    path.write_text(WAGON_HEADER + "\n0,1,2,3,4,5,6\n0.002,1,2,3,4,x,6\n0.004,1,2,3,4,5,6\n")
    with pytest.raises(RecordingError, match=r"wagon.csv: line 3: b2 is not a number: 'x'$"):
        read_recording(path)


def test_a_sample_of_bogie_2_beyond_the_converters_range_is_clipped_and_counted(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(100, 6)
    accel[7, 4] = 1e6
    write_recording(tmp_path / "wagon.parquet", time_s, accel)
    rec = read_recording(tmp_path / "wagon.parquet")
    assert rec.clipped_samples == 1
    assert rec.accel_mps2[7, 4] < 1e6 and rec.accel_mps2[7, 3] == accel[7, 3]


@pytest.mark.parametrize("name", NAMES)
def test_the_replay_of_a_wagons_recording_gives_each_bogies_blocks_as_a_stream_of_its_own(tmp_path: Path, name: str) -> None:
    time_s, accel = six_decimal_samples(1234, 6)
    write_recording(tmp_path / name, time_s, accel)
    source = open_replay(tmp_path / name, rate=0, layout=None, fs_hz=FS_HZ, max_block_s=1.0)
    assert source.bogies == 2
    blocks = drain(source)
    assert [b.bogie for b in blocks] == [0, 1] * 3
    for bogie, columns in ((0, slice(0, 3)), (1, slice(3, 6))):
        own = [b for b in blocks if b.bogie == bogie]
        assert [b.n_samples for b in own] == [500, 500, 234]
        assert [b.gap_before for b in own] == [True, False, False]
        assert [b.start_s for b in own] == [time_s[0], time_s[500], time_s[1000]]
        np.testing.assert_array_equal(np.concatenate([b.accel_mps2 for b in own]), accel[:, columns])
    assert source.counters.frames == 1234  # sampling instants, not blocks times bogies


def test_a_one_bogie_replay_gives_only_bogie_0(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(700, 3)
    write_recording(tmp_path / "one.csv", time_s, accel)
    source = RecordingReplaySource(tmp_path / "one.csv", rate=0)
    blocks = drain(source)
    assert source.bogies == 1 and [b.bogie for b in blocks] == [0, 0]
    np.testing.assert_array_equal(np.concatenate([b.accel_mps2 for b in blocks]), accel)


def test_a_paced_wagon_replay_gives_bogie_2_with_bogie_1_without_waiting_again(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(1000, 6)
    write_recording(tmp_path / "wagon.csv", time_s, accel)
    now_s = [0.0]
    sleeps: list[float] = []

    def sleep(seconds: float) -> None:
        sleeps.append(seconds)
        now_s[0] += seconds

    source = RecordingReplaySource(tmp_path / "wagon.csv", rate=1.0, clock=lambda: now_s[0], sleep=sleep)
    first = source.read(5.0)
    waited = len(sleeps)
    second = source.read(5.0)
    assert first is not None and second is not None and (first.bogie, second.bogie) == (0, 1)
    assert len(sleeps) == waited and first.start_s == second.start_s and first.n_samples == second.n_samples == 500


def test_a_bad_row_ends_a_wagon_replay_after_both_bogies_of_the_rows_before_it(tmp_path: Path) -> None:
    rows = "".join(f"{i / FS_HZ:.6f},1,2,3,4,5,6\n" for i in range(600))
    after = "".join(f"{i / FS_HZ:.6f},1,2,3,4,5,6\n" for i in range(601, 604))
    (tmp_path / "wagon.csv").write_text(WAGON_HEADER + "\n" + rows + "1.200000,1,2,3,4,nan,6\n" + after)
    source = RecordingReplaySource(tmp_path / "wagon.csv", rate=0)
    blocks = []
    with pytest.raises(RecordingError, match=r"wagon.csv: line 602: a value is NaN"):
        for _ in range(100):
            block = source.read(1.0)
            if block is not None:
                blocks.append(block)
    assert [(b.bogie, b.n_samples) for b in blocks] == [(0, 500), (1, 500), (0, 100), (1, 100)]


def test_a_block_of_a_negative_bogie_is_a_bug() -> None:
    with pytest.raises(ValueError, match="bogies count from 0"):
        Block(start_s=0.0, fs_hz=FS_HZ, accel_mps2=np.zeros((1, 3)), bogie=-1)


def test_recording_blocks_of_a_wagon_alternate_the_bogies_over_the_same_stretches(tmp_path: Path) -> None:
    time_s, accel = six_decimal_samples(10, 6)
    write_recording(tmp_path / "wagon.csv", time_s, accel)
    blocks = read_recording(tmp_path / "wagon.csv").blocks(4)
    assert [(b.bogie, b.n_samples, b.start_s) for b in blocks] == [
        (0, 4, time_s[0]), (1, 4, time_s[0]), (0, 4, time_s[4]), (1, 4, time_s[4]), (0, 2, time_s[8]), (1, 2, time_s[8]),
    ]  # fmt: skip
    np.testing.assert_array_equal(np.concatenate([b.accel_mps2 for b in blocks if b.bogie == 1]), accel[:, 3:])


def test_refuse_wagon_names_the_file_and_the_command_in_one_line() -> None:
    refuse_wagon("one.csv", 1, "analyze")  # one bogie: nothing to refuse
    with pytest.raises(RecordingError) as info:
        refuse_wagon("w.csv", 2, "analyze")
    assert str(info.value) == "w.csv: a wagon's recording (both bogies): analyze reads one bogie today; give it one bogie's recording (time_s,a1,a2,a3)"
