"""Recordings (CSV and Parquet): a round trip, streaming reads, clipping, and one clear error naming
the line (or row) for every bad file."""

import csv
import gzip
import io
from importlib import resources
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bogiemon.drivers import recording_check, recording_csv, recording_parquet
from bogiemon.drivers.recording import (
    ACCEL_LSB_MPS2,
    HEADER,
    MAX_ACCEL_MPS2,
    MIN_ACCEL_MPS2,
    RecordingError,
    open_recording_reader,
    read_csv_recording,
    read_recording,
    write_csv_recording,
    write_parquet_recording,
    write_recording,
)


def write(tmp_path: Path, text: str, name: str = "rec.csv") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


GOOD_ROWS = "".join(f"{i * 0.002:.6f},0.1,0.2,9.81\n" for i in range(10))


def test_round_trip_keeps_values_to_the_written_precision(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    t = 1234.5 + np.arange(5000) / 500.0
    a = rng.standard_normal((5000, 3)) + 9.81
    write_csv_recording(tmp_path / "r.csv", t, a)
    rec = read_csv_recording(tmp_path / "r.csv")
    assert rec.fs_hz == pytest.approx(500.0, rel=1e-9)
    np.testing.assert_allclose(rec.time_s, t, atol=5e-7)
    np.testing.assert_allclose(rec.accel_mps2, a, atol=5e-7)
    assert rec.duration_s == pytest.approx(10.0)


def test_blocks_cover_the_recording_in_order(tmp_path: Path) -> None:
    rec = read_csv_recording(write(tmp_path, "time_s,a1,a2,a3\n" + GOOD_ROWS))
    blocks = rec.blocks(4)
    assert [b.n_samples for b in blocks] == [4, 4, 2]
    assert [b.start_s for b in blocks] == pytest.approx([0.0, 0.008, 0.016])
    np.testing.assert_array_equal(np.concatenate([b.accel_mps2 for b in blocks]), rec.accel_mps2)


def test_blank_lines_and_a_byte_order_mark_are_accepted(tmp_path: Path) -> None:
    rows = GOOD_ROWS.splitlines(keepends=True)
    rec = read_csv_recording(write(tmp_path, "\ufefftime_s,a1,a2,a3\n" + "".join(rows[:3]) + "\n" + "".join(rows[3:])))
    assert rec.n_samples == 10


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", r"line 1: expected the header 'time_s,a1,a2,a3' or the columns of a mapping, found 'an empty line': no time column"),
        ("x,y,z,w\n0,1,2,3\n", r"line 1: expected the header 'time_s,a1,a2,a3' or the columns of a mapping, found 'x,y,z,w': no time column, no column 'a1'.*--columns time=NAME"),
        ("time_s,a1,a2,a3\n", r"holds no samples after the header"),
        ("time_s,a1,a2,a3\n0,1,2,3\n", r"holds 1 sample\(s\)"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,x,3\n", r"line 3: a2 is not a number: 'x'"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,,3\n", r"line 3: a2 is not a number: ''"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2\n", r"line 3: expected 4 comma-separated values .* found 3"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3,4\n", r"line 3: expected 4 comma-separated values .* found 5"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,nan,2,3\n", r"line 4: a value is NaN \(no reading\); remove or repair the row"),
        ("time_s,a1,a2,a3\n0,1,2,3\nnan,1,2,3\n0.004,1,2,3\n", r"line 3: a value is NaN"),
        ("time_s,a1,a2,a3\n0,1,2,3\ninf,1,2,3\n0.004,1,2,3\n", r"line 3: time_s inf is no plausible time"),
        ("time_s,a1,a2,a3\n0,1,2,3\n   \n0.002,1,2,3\n", r"line 3: expected 4 comma-separated values .* found 1"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,\"2\",3\n", r"line 3: a2 is not a number: '\"2\"'"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,1_000,3\n", r"line 3: a2 is not a number: '1_000'"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.002,1,2,3\n", r"line 4: time_s 0.002 does not increase"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.001,1,2,3\n", r"line 4: time_s 0.001 does not increase"),
        (
            "time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,3\n0.0045,1,2,3\n0.006,1,2,3\n",
            r"line 5: time step 0.0005 s is shorter than the file's 0.002 s \(500 Hz\) by more than its jitter \(25%\)",
        ),
    ],
    ids=[
        "empty-file", "wrong-header", "header-only", "one-row", "non-numeric", "empty-cell", "too-few-columns",
        "too-many-columns", "nan", "nan-time", "inf-time", "white-space-line", "quoted", "underscore", "repeated-time",
        "time-goes-back", "dropped-sample",
    ],
)  # fmt: skip
def test_a_bad_file_is_one_error_naming_file_and_line(tmp_path: Path, text: str, message: str) -> None:
    path = write(tmp_path, text)
    with pytest.raises(RecordingError, match=message) as info:
        read_csv_recording(path)
    assert str(info.value).startswith(f"{path}: ")
    assert "\n" not in str(info.value)


def test_line_numbers_count_blank_lines(tmp_path: Path) -> None:
    path = write(tmp_path, "time_s,a1,a2,a3\n0,1,2,3\n\n\n0.002,1,2,nan\n")
    with pytest.raises(RecordingError, match="line 5: a value is NaN"):
        read_csv_recording(path)


def test_shorter_than_a_window_is_an_error_saying_what_to_do(tmp_path: Path) -> None:
    path = write(tmp_path, "time_s,a1,a2,a3\n" + GOOD_ROWS)
    with pytest.raises(RecordingError, match=r"10 samples \(0.0 s\) is shorter than one analysis window .* shorter window_s"):
        read_csv_recording(path, min_samples=11)


def test_a_missing_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"missing.csv: cannot read the recording: No such file"):
        read_csv_recording(tmp_path / "missing.csv")


def test_a_binary_file_is_not_a_recording(tmp_path: Path) -> None:
    path = tmp_path / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(RecordingError, match="not a text file"):
        read_csv_recording(path)


def test_a_file_cut_inside_a_utf8_character_is_an_error_naming_the_last_line(tmp_path: Path) -> None:
    path = tmp_path / "cut.csv"
    path.write_bytes(b"time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,\xc3")  # a logger killed mid-write
    with pytest.raises(RecordingError) as info:
        read_csv_recording(path)
    assert str(info.value) == (
        f"{path}: line 4: not UTF-8 text, byte 0xc3 at column 11 (cut in the middle of a character: "
        "the file is truncated); remove or repair the line"
    )


def test_a_byte_that_is_not_utf8_in_a_data_line_is_an_error_naming_its_line(tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_bytes(b"time_s,a1,a2,a3\n0,1,2,3\n0.002,1,\xff,3\n0.004,1,2,3\n")
    with pytest.raises(RecordingError, match=r"bad.csv: line 3: not UTF-8 text, byte 0xff at column 9; remove or repair"):
        read_csv_recording(path)


def test_a_time_step_of_the_smallest_double_is_no_sample_rate(tmp_path: Path) -> None:
    rows = "".join(f"{i * 4.9e-324!r},1,2,3\n" for i in range(10))  # 1 / 4.9e-324 overflows to inf
    path = write(tmp_path, "time_s,a1,a2,a3\n" + rows)
    with pytest.raises(RecordingError, match=r"time steps of 4.94066e-324 s give no finite sample rate: time_s must be in seconds"):
        read_csv_recording(path)


def test_a_time_beyond_the_year_2100_is_an_error_naming_its_line(tmp_path: Path) -> None:
    path = write(tmp_path, "time_s,a1,a2,a3\n0,1,2,3\n1e300,1,2,3\n")
    with pytest.raises(RecordingError, match=r"line 3: time_s 1e\+300 is no plausible time \(beyond \+/-4102444800 s"):
        read_csv_recording(path)


# --- Streaming reads (issue: recordings read in bounded memory, with the same rows and errors) -------


def reference_rows(raw: bytes) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a valid CSV recording as Python's csv module and float() read them."""
    text = raw.decode("utf-8-sig")
    rows = [row for row in csv.reader(io.StringIO(text, newline=""))][1:]
    values = np.array([[float(cell) for cell in row] for row in rows if row], dtype=np.float64).reshape(-1, 4)
    return values[:, 0], values[:, 1:]


def chunked(path: Path) -> tuple[np.ndarray, np.ndarray]:
    reader = open_recording_reader(path)
    parts = list(reader.chunks())
    return np.concatenate([t for t, _ in parts]), np.concatenate([a for _, a in parts])


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(2, 400),
    line_break=st.sampled_from(["\n", "\r\n", "\r"]),
    blank_every=st.integers(0, 7),
    bom=st.booleans(),
    last_break=st.booleans(),
    packed=st.booleans(),
    block_bytes=st.sampled_from([64, 100, 257, 1 << 20]),
    reference_steps=st.sampled_from([1, 3, 50, 4096]),
)
def test_the_streaming_reader_gives_the_csv_modules_rows_across_any_block_boundary(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, n: int, line_break: str, blank_every: int, bom: bool, last_break: bool,
    packed: bool, block_bytes: int, reference_steps: int,
) -> None:  # fmt: skip
    # Small blocks and a short reference put the block edges, the CR of a CRLF cut between two
    # reads, blank lines and the start of the step checks everywhere in a file of a few rows.
    monkeypatch.setattr(recording_csv, "MAX_LINE_BYTES", block_bytes)
    monkeypatch.setattr(recording_check, "REFERENCE_STEPS", reference_steps)
    rng = np.random.default_rng(n)
    lines = [HEADER] + [f"{1.7e9 + i / 500.0!r},{rng.normal():.6f},{rng.normal() * 1e-3!r},{9.81 + rng.normal():.9f}" for i in range(n)]
    if blank_every:
        lines = [line for i, line in enumerate(lines) for line in ((line, "") if i % blank_every == 0 else (line,))]
    raw = ("\ufeff" if bom else "").encode() + (line_break.join(lines) + (line_break if last_break else "")).encode()
    path = tmp_path / ("r.csv.gz" if packed else "r.csv")
    path.write_bytes(gzip.compress(raw) if packed else raw)
    time_s, accel = reference_rows(raw)
    reader = open_recording_reader(path)
    assert reader.n_samples == n and reader.fs_hz == 500.0  # the nominal rate of steps of 1/500 s
    got_t, got_a = chunked(path)
    np.testing.assert_array_equal(got_t, time_s)
    np.testing.assert_array_equal(got_a, accel)


def test_a_recording_is_read_a_block_at_a_time_not_whole(tmp_path: Path) -> None:
    t = np.arange(200_000) / 500.0
    write_csv_recording(tmp_path / "r.csv", t, np.full((t.size, 3), 9.81))
    sizes = [c[0].shape[0] for c in open_recording_reader(tmp_path / "r.csv").chunks()]
    assert sum(sizes) == 200_000 and len(sizes) > 4 and max(sizes) < 60_000  # a megabyte of text a chunk


def test_a_lost_sample_far_in_is_a_gap_and_a_new_segment_not_an_error(tmp_path: Path) -> None:
    t = np.arange(10_000) / 500.0
    t[9000:] += 0.002  # one lost sample, far after the first REFERENCE_STEPS steps
    write_csv_recording(tmp_path / "gap.csv", t, np.zeros((t.size, 3)))
    reader = open_recording_reader(tmp_path / "gap.csv")
    chunks = [time_s for time_s, _ in reader.chunks()]
    assert reader.fs_hz == 500.0 and reader.gap_count == 1
    assert reader.gaps[0].after_s == pytest.approx(8999 / 500.0) and reader.gaps[0].missing_s == pytest.approx(0.002)
    np.testing.assert_array_equal(np.concatenate(chunks), np.round(t, 6))  # as the CSV writes them
    assert not any(np.any(np.diff(c) > 0.003) for c in chunks)  # no chunk spans the gap


@pytest.mark.parametrize(
    ("bad_row", "expected"),
    [
        ("{t!r},1,x,3", r"line {line}: a2 is not a number: 'x'"),  # pyarrow refuses the block
        ("{t!r},1,nan,3", r"line {line}: a value is NaN"),  # the row checks refuse it
        ("{t3!r},1,2,3", r"line {line}: time step 0.0005 s is shorter"),
    ],
    ids=["not-a-number", "nan", "stray-row"],
)
def test_the_rows_before_a_bad_line_are_given_and_then_its_error(tmp_path: Path, bad_row: str, expected: str) -> None:
    k = 60_000  # more than a megabyte of text before it: the bad line is in a later block
    t = np.arange(100_000) / 500.0
    a = np.random.default_rng(0).normal(size=(t.size, 3))
    write_csv_recording(tmp_path / "good.csv", t, a)
    lines = (tmp_path / "good.csv").read_text().splitlines()
    lines[1 + k] = bad_row.format(t=float(t[k]), t3=round(float(t[k - 1]) + 0.0005, 6))
    (tmp_path / "bad.csv").write_text("\n".join(lines) + "\n")
    given: list[np.ndarray] = []
    with pytest.raises(RecordingError, match=f"bad.csv: {expected.format(line=k + 2)}"):
        for time_s, _ in open_recording_reader(tmp_path / "bad.csv").chunks():
            given.append(time_s)
    np.testing.assert_array_equal(np.concatenate(given), read_recording(tmp_path / "good.csv").time_s[:k])


def test_a_file_that_grows_while_it_is_read_is_an_error(tmp_path: Path) -> None:
    t = np.arange(100_000) / 500.0
    write_csv_recording(tmp_path / "r.csv", t, np.zeros((t.size, 3)))
    reader = open_recording_reader(tmp_path / "r.csv")
    with (tmp_path / "r.csv").open("a") as logger:  # a logger still writing
        logger.write("".join(f"{x:.6f},0,0,0\n" for x in t[-1] + (1 + np.arange(10)) / 500.0))
    with pytest.raises(RecordingError, match=r"r.csv: changed while it was read \(100010 rows, not 100000\): is a logger still writing it"):
        for _ in reader.chunks():
            pass


def test_a_compressed_line_of_many_megabytes_is_refused_after_the_first(tmp_path: Path) -> None:
    path = tmp_path / "probe.csv.gz"  # the probe's file: a few hundred kilobytes holding one huge line
    path.write_bytes(gzip.compress(b"time_s,a1,a2,a3\n" + b"1" * (64 << 20) + b",1,2,3\n", compresslevel=9))
    with pytest.raises(RecordingError) as info:
        open_recording_reader(path)
    assert str(info.value) == (
        f"{path}: line 2: longer than 1024 KiB; a recording is a CSV file (time_s,a1,a2,a3), plain or .csv.gz, "
        "or a .parquet file: is this the right file?"
    )


# --- Samples beyond the converter's range ----------------------------------------------------------


def test_samples_beyond_the_converters_range_are_clipped_to_its_full_scale_and_counted(tmp_path: Path) -> None:
    rows = ["0,1e308,-1e308,9.81", "0.002,inf,-inf,1e309", "0.004,156.9,-156.9,200", "0.006,1,2,3"]
    rec = read_recording(write(tmp_path, HEADER + "\n" + "\n".join(rows) + "\n"))
    np.testing.assert_array_equal(
        rec.accel_mps2,
        [[MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, 9.81], [MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, MAX_ACCEL_MPS2], [156.9, -156.9, MAX_ACCEL_MPS2], [1, 2, 3]],
    )
    assert rec.clipped_samples == 6


def test_the_converters_range_is_the_dbcs_int16_signal() -> None:
    import cantools

    dbc = cantools.database.load_file(str(resources.files("bogiemon.config").joinpath("bogiemon.dbc")))
    signal = dbc.get_message_by_name("SensorHub").get_signal_by_name("Accel1")
    assert (signal.length, signal.is_signed, signal.scale, signal.offset) == (16, True, ACCEL_LSB_MPS2, 0)
    assert (MIN_ACCEL_MPS2, MAX_ACCEL_MPS2) == (-(2**15) * signal.scale, (2**15 - 1) * signal.scale)
    assert (signal.minimum, signal.maximum) == (pytest.approx(MIN_ACCEL_MPS2, abs=1e-4), pytest.approx(MAX_ACCEL_MPS2, abs=1e-4))


# --- Parquet recordings ------------------------------------------------------------------------------


def six_decimal_samples(n: int = 20_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Samples a CSV holds exactly: the values its 6 decimals read back as."""
    rng = np.random.default_rng(seed)
    t = np.array([float(f"{x:.6f}") for x in 1.7e9 + np.arange(n) / 500.0])
    a = np.array([[float(f"{x:.6f}") for x in row] for row in rng.normal(9.81, 2.0, size=(n, 3))])
    return t, a


def test_a_parquet_recording_holds_the_samples_exactly(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    t, a = 1.7e9 + np.arange(70_000) / 500.0, rng.normal(size=(70_000, 3))  # two row groups
    write_parquet_recording(tmp_path / "r.parquet", t, a)
    rec = read_recording(tmp_path / "r.parquet")
    np.testing.assert_array_equal(rec.time_s, t)
    np.testing.assert_array_equal(rec.accel_mps2, a)
    assert rec.fs_hz == 500.0  # the nominal rate of its steps, snapped to the whole hertz


def test_the_same_samples_read_the_same_from_csv_and_parquet(tmp_path: Path) -> None:
    t, a = six_decimal_samples()
    write_recording(tmp_path / "r.csv", t, a)
    write_recording(tmp_path / "r.parquet", t, a)
    from_csv, from_parquet = read_recording(tmp_path / "r.csv"), read_recording(tmp_path / "r.parquet")
    assert from_csv.fs_hz == from_parquet.fs_hz
    np.testing.assert_array_equal(from_csv.time_s, from_parquet.time_s)
    np.testing.assert_array_equal(from_csv.accel_mps2, from_parquet.accel_mps2)


def test_the_same_samples_give_the_same_parquet_bytes(tmp_path: Path) -> None:
    t, a = six_decimal_samples(1000)
    write_parquet_recording(tmp_path / "a.parquet", t, a)
    write_parquet_recording(tmp_path / "b.parquet", t, a, fsync=True)
    assert (tmp_path / "a.parquet").read_bytes() == (tmp_path / "b.parquet").read_bytes()


def test_a_parquet_recording_is_known_by_its_magic_whatever_its_name(tmp_path: Path) -> None:
    t, a = six_decimal_samples(100)
    write_parquet_recording(tmp_path / "r.csv", t, a)
    np.testing.assert_array_equal(read_recording(tmp_path / "r.csv").accel_mps2, a)


def test_a_bad_row_of_a_parquet_recording_is_named_by_its_row(tmp_path: Path) -> None:
    t, a = six_decimal_samples(100)
    t[50] = t[49]
    write_parquet_recording(tmp_path / "r.parquet", t, a)
    with pytest.raises(RecordingError, match=r"r.parquet: row 51: time_s 1700000000.098 does not increase"):
        read_recording(tmp_path / "r.parquet")


def test_a_null_in_a_parquet_recording_is_named_by_its_row(tmp_path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    t, a = six_decimal_samples(100)
    a2 = pa.array(a[:, 1], mask=np.arange(100) == 7)
    pq.write_table(pa.table({"time_s": t, "a1": a[:, 0], "a2": a2, "a3": a[:, 2]}), tmp_path / "r.parquet")
    with pytest.raises(RecordingError, match=r"r.parquet: row 8: a value is missing \(null\); remove or repair the row$"):
        read_recording(tmp_path / "r.parquet")


@pytest.mark.parametrize(
    ("columns", "found"),
    [
        ({"time_s": [0.0, 1.0], "a1": [0.0, 1.0]}, r"found time_s, a1: no column 'a2', no column 'a3'"),
        ({"x": [0.0], "a1": [1], "a2": [1], "a3": [1]}, r"found x, a1, a2, a3: no time column"),
        ({"time_s": [0.0, 1.0], "a1": ["1", "2"], "a2": [1, 2], "a3": [1, 2]}, r"expected number columns .* found time_s double, a1 string"),
    ],
    ids=["too-few", "no-time", "text"],
)
def test_a_parquet_file_of_other_columns_is_no_recording(tmp_path: Path, columns: dict, found: str) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table(columns), tmp_path / "x.parquet")
    with pytest.raises(RecordingError, match=rf"x.parquet: .*{found}"):
        read_recording(tmp_path / "x.parquet")


def test_a_truncated_parquet_recording_is_one_error_naming_the_file(tmp_path: Path) -> None:
    t, a = six_decimal_samples(1000)
    write_parquet_recording(tmp_path / "whole.parquet", t, a)
    (tmp_path / "cut.parquet").write_bytes((tmp_path / "whole.parquet").read_bytes()[:-100])
    with pytest.raises(RecordingError, match=r"cut.parquet: not a readable Parquet file \(.+\); a recording is a CSV file"):
        read_recording(tmp_path / "cut.parquet")


def test_a_gzip_compressed_parquet_recording_is_refused_saying_what_to_do(tmp_path: Path) -> None:
    t, a = six_decimal_samples(100)
    write_parquet_recording(tmp_path / "r.parquet", t, a)
    (tmp_path / "r.parquet.gz").write_bytes(gzip.compress((tmp_path / "r.parquet").read_bytes()))
    (tmp_path / "r.parquet.gz").rename(tmp_path / "packed.parquet")
    with pytest.raises(RecordingError, match=r"packed.parquet: a Parquet recording compresses its own columns: store it as .parquet, not gzip-compressed"):
        read_recording(tmp_path / "packed.parquet")


def test_a_parquet_row_group_larger_than_the_bound_is_refused_before_it_is_read(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(recording_parquet, "MAX_PARQUET_GROUP_ROWS", 1000)
    t, a = six_decimal_samples(3000)
    write_parquet_recording(tmp_path / "r.parquet", t, a)  # one row group of 3000 rows
    with pytest.raises(RecordingError, match=r"r.parquet: row group 0 holds 3000 rows, more than 1000; write it in row groups"):
        open_recording_reader(tmp_path / "r.parquet")


def test_a_gap_that_puts_the_first_to_last_rate_off_its_steps_keeps_the_rate_of_its_steps(tmp_path: Path) -> None:
    # Found by make fuzz (recording-gz): a 40-row file missing one row was replayed at its
    # first-to-last rate, 2.6 % off the step of every row before the gap. Its rate is its steps'.
    t = np.delete(np.arange(41) / 10.0, 28)
    write_csv_recording(tmp_path / "gap.csv", t, np.zeros((t.size, 3)))
    reader = open_recording_reader(tmp_path / "gap.csv")
    chunks = [time_s for time_s, _ in reader.chunks()]
    assert reader.fs_hz == 10.0 and reader.gap_count == 1
    assert [c.shape[0] for c in chunks] == [28, 12]


def test_a_parquet_footer_that_claims_rows_its_pages_do_not_hold_is_one_error(tmp_path: Path) -> None:
    # Found by make fuzz (recording-parquet): a data page header that lies about its count (0 values
    # where the footer says 3) ended the open with an IndexError.
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({c: np.arange(3.0) / 500 for c in ("time_s", "a1", "a2", "a3")}), tmp_path / "good.parquet",
                   compression="none", use_dictionary=False, data_page_version="1.0", write_statistics=False)  # fmt: skip
    raw = (tmp_path / "good.parquet").read_bytes()
    # Each column's DataPageHeader (PageHeader field 5) opens with num_values = 3 (a zigzag varint 6).
    assert raw.count(b"\x2c\x15\x06") == 4
    (tmp_path / "lying.parquet").write_bytes(raw.replace(b"\x2c\x15\x06", b"\x2c\x15\x00"))
    with pytest.raises(RecordingError, match=r"lying.parquet: row group 0 holds 0 rows, its footer says 3: damaged; copy it again"):
        open_recording_reader(tmp_path / "lying.parquet")


def test_the_survey_counts_lines_as_the_byte_by_byte_reference_in_every_short_text() -> None:
    import itertools

    from bogiemon.drivers.recording_csv import _count_lines

    def reference(data: bytes) -> tuple[int, int]:
        # A line break is CRLF, CR or LF; a line holding anything starts after one (or at 0).
        lines = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").split(b"\n")
        return sum(1 for line in lines if line), len(lines) - 1

    for n in range(1, 9):
        for parts in itertools.product([b"7", b"\n", b"\r"], repeat=n):
            data = b"".join(parts)
            assert _count_lines(data) == reference(data), data


def test_a_parquet_footer_whose_histogram_would_abort_pyarrow_is_one_clear_error() -> None:
    # Found by make fuzz (recording-parquet, seed 17, input 534): a column chunk's statistics with a
    # definition-level histogram of the wrong size made pyarrow 26 abort the process (SIGABRT) when
    # the open read that column's metadata. Replayed in its own process: an abort would kill ours.
    import subprocess
    import sys

    repo = Path(__file__).resolve().parents[2]
    saved = Path(__file__).parent / "data" / "parquet-histogram-abort.json"
    done = subprocess.run([sys.executable, str(repo / "bench" / "fuzz.py"), "--replay", str(saved)], cwd=repo, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "clear RecordingError" in done.stdout and "not a readable Parquet file" in done.stdout
