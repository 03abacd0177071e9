"""CSV recordings: a round trip, and one clear error naming the line for every bad file."""

from pathlib import Path

import numpy as np
import pytest

from bogiemon.drivers.recording import RecordingError, read_csv_recording, write_csv_recording


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
        ("", r"line 1: expected the header 'time_s,a1,a2,a3', found 'an empty line'"),
        ("time,a1,a2,a3\n0,1,2,3\n", r"line 1: expected the header 'time_s,a1,a2,a3', found 'time,a1,a2,a3'"),
        ("time_s,a1,a2,a3\n", r"holds no samples after the header"),
        ("time_s,a1,a2,a3\n0,1,2,3\n", r"holds 1 sample\(s\)"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,x,3\n", r"line 3: a2 is not a number: 'x'"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,,3\n", r"line 3: a2 is not a number: ''"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2\n", r"line 3: expected 4 comma-separated values .* found 3"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3,4\n", r"line 3: expected 4 comma-separated values .* found 5"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,nan,2,3\n", r"line 4: a value is NaN or infinite"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,inf\n0.004,1,2,3\n", r"line 3: a value is NaN or infinite"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.002,1,2,3\n", r"line 4: time_s 0.002 does not increase"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.001,1,2,3\n", r"line 4: time_s 0.001 does not increase"),
        (
            "time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,3\n0.008,1,2,3\n0.010,1,2,3\n",
            r"line 5: time step 0.004 s differs from the file's 0.002 s \(500 Hz\)",
        ),
    ],
    ids=[
        "empty-file", "wrong-header", "header-only", "one-row", "non-numeric", "empty-cell", "too-few-columns",
        "too-many-columns", "nan", "inf", "repeated-time", "time-goes-back", "dropped-sample",
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
