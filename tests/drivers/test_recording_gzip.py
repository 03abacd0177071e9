"""Compressed recordings (.csv.gz, what the gateway's recorder writes): read as the plain ones are,
with the same messages, and a cut or damaged stream is one error naming the file."""

import gzip
import io
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from bogiemon.drivers.recording import RecordingError, read_csv_recording, write_csv_recording
from bogiemon.drivers.replay import CsvReplaySource, open_replay


def samples(n: int = 5000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return 1.7e9 + np.arange(n) / 500.0, rng.standard_normal((n, 3)) + 9.81


def write_gz(path: Path, text: str) -> Path:
    path.write_bytes(gzip.compress(text.encode("utf-8")))
    return path


def test_a_gz_recording_reads_exactly_as_the_same_samples_written_plain(tmp_path: Path) -> None:
    t, a = samples()
    write_csv_recording(tmp_path / "r.csv", t, a)
    write_csv_recording(tmp_path / "r.csv.gz", t, a)
    plain, packed = read_csv_recording(tmp_path / "r.csv"), read_csv_recording(tmp_path / "r.csv.gz")
    assert packed.fs_hz == plain.fs_hz
    np.testing.assert_array_equal(packed.time_s, plain.time_s)
    np.testing.assert_array_equal(packed.accel_mps2, plain.accel_mps2)


def test_the_gz_writer_compresses_the_plain_writers_text(tmp_path: Path) -> None:
    t, a = samples(100)
    write_csv_recording(tmp_path / "r.csv", t, a)
    write_csv_recording(tmp_path / "r.csv.gz", t, a, fsync=True)
    assert (tmp_path / "r.csv.gz").read_bytes()[:2] == b"\x1f\x8b"
    assert gzip.decompress((tmp_path / "r.csv.gz").read_bytes()) == (tmp_path / "r.csv").read_bytes()


@pytest.mark.parametrize(("level", "xfl"), [(1, 4), (9, 2)])  # gzip's header says fastest (4) or best (2)
def test_the_gz_writer_at_another_level_compresses_the_same_text_at_that_level(tmp_path: Path, level: int, xfl: int) -> None:
    t, a = samples(100)
    write_csv_recording(tmp_path / "r.csv", t, a)
    write_csv_recording(tmp_path / "r.csv.gz", t, a, gzip_level=level)
    packed = (tmp_path / "r.csv.gz").read_bytes()
    assert packed[8] == xfl
    assert gzip.decompress(packed) == (tmp_path / "r.csv").read_bytes()


def test_the_same_samples_give_the_same_gz_bytes(tmp_path: Path) -> None:
    t, a = samples(100)
    write_csv_recording(tmp_path / "a.csv.gz", t, a)
    write_csv_recording(tmp_path / "b.csv.gz", t, a)
    assert (tmp_path / "a.csv.gz").read_bytes() == (tmp_path / "b.csv.gz").read_bytes()


def test_gzip_is_recognised_by_its_magic_bytes_whatever_the_name(tmp_path: Path) -> None:
    t, a = samples(100)
    write_csv_recording(tmp_path / "plain.csv", t, a)
    write_csv_recording(tmp_path / "r.csv.gz", t, a)
    (tmp_path / "r.csv.gz").rename(tmp_path / "packed.csv")
    np.testing.assert_array_equal(read_csv_recording(tmp_path / "packed.csv").accel_mps2, read_csv_recording(tmp_path / "plain.csv").accel_mps2)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("x,a1,a2,a3\n0,1,2,3\n", r"line 1: expected the header 'time_s,a1,a2,a3' \(or 'time_s,a1,a2,a3,b1,b2,b3': both bogies\) or the columns of a mapping, found 'x,a1,a2,a3': no time column"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,x,3\n", r"line 3: a2 is not a number: 'x'"),
        ("time_s,a1,a2,a3\n0,1,2,3\n\n0.002,1,2,3\n0.004,nan,2,3\n", r"line 5: a value is NaN"),
        ("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,3\n0.0045,1,2,3\n", r"line 5: time step 0.0005 s is shorter"),
    ],
    ids=["wrong-header", "non-numeric", "nan-after-a-blank-line", "stray-row"],
)
def test_a_bad_row_in_a_gz_recording_is_the_plain_files_error_naming_its_line(tmp_path: Path, text: str, message: str) -> None:
    plain = tmp_path / "rec.csv"
    plain.write_text(text, encoding="utf-8")
    packed = write_gz(tmp_path / "rec.csv.gz", text)
    with pytest.raises(RecordingError, match=message) as plain_info:
        read_csv_recording(plain)
    with pytest.raises(RecordingError) as packed_info:
        read_csv_recording(packed)
    assert str(packed_info.value) == str(plain_info.value).replace(str(plain), str(packed), 1)


def test_a_gz_recording_cut_inside_a_utf8_character_names_the_last_line(tmp_path: Path) -> None:
    path = tmp_path / "cut.csv.gz"
    path.write_bytes(gzip.compress(b"time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n0.004,1,2,\xc3"))
    with pytest.raises(RecordingError, match=r"cut.csv.gz: line 4: not UTF-8 text, byte 0xc3 at column 11 \(cut in the middle"):
        read_csv_recording(path)


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.999], ids=["half", "most", "all-but-the-trailer"])
def test_a_truncated_gz_recording_is_one_error_naming_the_file(tmp_path: Path, keep: float) -> None:
    t, a = samples()
    whole = tmp_path / "whole.csv.gz"
    write_csv_recording(whole, t, a)
    data = whole.read_bytes()
    path = tmp_path / "cut.csv.gz"
    path.write_bytes(data[: int(len(data) * keep)])
    with pytest.raises(RecordingError) as info:
        read_csv_recording(path)
    assert str(info.value) == (
        f"{path}: the compressed recording is cut short (its gzip stream ends early: a partial copy or upload?); copy it again"
    )


def test_a_damaged_gz_recording_is_one_error_naming_the_file(tmp_path: Path) -> None:
    t, a = samples()
    path = tmp_path / "bad.csv.gz"
    write_csv_recording(path, t, a)
    data = bytearray(path.read_bytes())
    data[len(data) // 2 : len(data) // 2 + 64] = bytes(64)  # zeros over the middle of the deflate stream
    path.write_bytes(bytes(data))
    with pytest.raises(RecordingError, match=rf"^{path}: not a readable gzip file \(.+\); the compressed recording is damaged: copy it again$"):
        read_csv_recording(path)


def test_a_gz_name_over_plain_text_is_one_error_naming_the_file(tmp_path: Path) -> None:
    path = tmp_path / "plain.csv.gz"
    path.write_text("time_s,a1,a2,a3\n0,1,2,3\n0.002,1,2,3\n", encoding="utf-8")
    with pytest.raises(RecordingError, match=rf"^{path}: not a readable gzip file \(Not a gzipped file"):
        read_csv_recording(path)


def test_a_missing_gz_recording_is_named(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match=r"missing.csv.gz: cannot read the recording: No such file"):
        read_csv_recording(tmp_path / "missing.csv.gz")


def test_a_gz_recording_replays_through_the_csv_source_not_a_can_log_reader(tmp_path: Path) -> None:
    t, a = samples(1000)
    write_csv_recording(tmp_path / "run.csv.gz", t, a)
    source = open_replay(tmp_path / "run.csv.gz", rate=0, layout=None, fs_hz=500.0, max_block_s=1.0)
    assert isinstance(source, CsvReplaySource)
    block = source.read(0.1)
    assert block is not None and block.start_s == pytest.approx(t[0], abs=1e-6)
    np.testing.assert_allclose(block.accel_mps2, a[:500], atol=5e-7)


def test_a_gz_recording_is_decompressed_once_and_read_as_its_plain_text(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    time_s, accel = samples()
    write_csv_recording(tmp_path / "r.csv", time_s, accel)
    write_csv_recording(tmp_path / "r.csv.gz", time_s, accel)
    expected = read_csv_recording(tmp_path / "r.csv")
    inflated: list[int] = []
    real_read = gzip.GzipFile.read

    def counted(self: gzip.GzipFile, size: int | None = -1) -> bytes:
        data = real_read(self, size)
        inflated.append(len(data))
        return data

    monkeypatch.setattr(gzip.GzipFile, "read", counted)
    got = read_csv_recording(tmp_path / "r.csv.gz")
    assert sum(inflated) == (tmp_path / "r.csv").stat().st_size  # the survey's pass alone inflated it
    np.testing.assert_array_equal(got.time_s, expected.time_s)
    np.testing.assert_array_equal(got.accel_mps2, expected.accel_mps2)


@pytest.mark.parametrize("why", ["over-the-bound", "no-room"])
def test_a_gz_recording_whose_copy_cannot_be_kept_is_decompressed_again_and_reads_the_same(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, why: str
) -> None:
    # The copy is a speed-up, never a condition: past its bound, or with a temporary folder that
    # cannot take it (a full tmpfs), the passes decompress the file again, and no copy is left.
    from bogiemon.drivers import recording_csv

    time_s, accel = samples()
    write_csv_recording(tmp_path / "r.csv", time_s, accel)
    write_csv_recording(tmp_path / "r.csv.gz", time_s, accel)
    expected = read_csv_recording(tmp_path / "r.csv")
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))
    if why == "over-the-bound":
        monkeypatch.setattr(recording_csv, "MAX_COPY_BYTES", 1000)
    else:
        real_open = Path.open

        class Full(io.BytesIO):
            def write(self, data: bytes) -> int:  # type: ignore[override]
                raise OSError(28, "No space left on device")

        def opened(self: Path, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
            return Full() if self.name == "recording.csv" and "x" in mode else real_open(self, mode, *args, **kwargs)

        monkeypatch.setattr(Path, "open", opened)
    got = read_csv_recording(tmp_path / "r.csv.gz")
    np.testing.assert_array_equal(got.time_s, expected.time_s)
    np.testing.assert_array_equal(got.accel_mps2, expected.accel_mps2)
    assert list(temporary.iterdir()) == []  # nothing left behind
