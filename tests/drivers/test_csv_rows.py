"""CSV recordings without pyarrow (drivers/csv_rows.py): the same rows to the bits and the same
errors as pyarrow's reader, and Parquet refused in one line saying what to install."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.drivers import recording_csv
from bogiemon.drivers.csv_rows import RowsError, parse_rows
from bogiemon.drivers.recording import HEADER, RecordingError, open_recording_reader, write_csv_recording, write_parquet_recording


@pytest.fixture
def without_pyarrow(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """pyarrow hidden, as on a gateway installed without it: `import pyarrow` fails."""
    for name in [m for m in sys.modules if m == "pyarrow" or m.startswith("pyarrow.")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    yield


def outcome(path: Path) -> tuple[list[list[float]], str | None]:
    """The rows a reader gives (NaN as a string, to compare) and its error, if any."""
    rows: list[list[float]] = []
    try:
        reader = open_recording_reader(path)
        for time_s, accel in reader.chunks():
            rows += np.column_stack([time_s, accel]).tolist()
    except RecordingError as exc:
        return rows, str(exc)
    return rows, None


def outcome_without_pyarrow(path: Path) -> tuple[list[list[float]], str | None]:
    with pytest.MonkeyPatch.context() as mp:
        for name in [m for m in sys.modules if m == "pyarrow" or m.startswith("pyarrow.")]:
            mp.delitem(sys.modules, name)
        mp.setitem(sys.modules, "pyarrow", None)
        return outcome(path)


NUMBERS = st.one_of(
    st.floats(-200, 200, allow_nan=False).map(repr),
    st.floats(-200, 200, allow_nan=False).map(lambda v: f"{v:.6f}"),
    st.floats(-1e6, 1e6, allow_nan=False).map(lambda v: f"{v:.3e}"),
    st.sampled_from(["0", "-0", "+1", ".5", "5.", "1e5", "1E-3", "nan", "NaN", "-inf", "Infinity", "nan(12)", "1_0", "0x10", "", " 2 ", "\t3", "1 2", "e", "--1", "1.2.3", "\u0663", "4\x0b"]),
)
ROW = st.lists(NUMBERS, min_size=3, max_size=5).map(",".join)
TIME_ROWS = st.integers(0, 50).map(lambda i: f"{i * 0.002:.6f},0.1,0.2,9.81")


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    lines=st.lists(st.one_of(ROW, st.just(""), TIME_ROWS), min_size=1, max_size=12),
    end=st.sampled_from(["\n", "\r\n", "\r"]),
)
def test_a_block_parses_to_pyarrows_rows_or_is_refused_as_pyarrow_refuses_it(lines: list[str], end: str) -> None:
    import pyarrow as pa

    block = "".join(line + end for line in lines).encode()
    parse_arrow, arrow_refuses = recording_csv._csv_parser()
    try:
        expected = np.concatenate([np.column_stack([t, a]) for t, a in parse_arrow(block)] or [np.zeros((0, 4))])
    except arrow_refuses:
        with pytest.raises(RowsError):
            parse_rows(block)
        return
    assert arrow_refuses is pa.ArrowInvalid
    got = parse_rows(block)
    assert got.shape == expected.shape
    assert np.array_equal(got, expected, equal_nan=True)
    assert got[~np.isnan(got)].view(np.uint64).tolist() == expected[~np.isnan(expected)].view(np.uint64).tolist()


def test_the_recorders_own_text_goes_through_numpys_parser_to_the_same_bits(tmp_path: Path) -> None:
    rng = np.random.default_rng(35)
    time_s = 1.7e9 + np.arange(20_000) / 500.0
    accel = rng.normal(0.0, 3.0, (20_000, 3)) + [0.0, 0.0, 9.81]
    path = tmp_path / "run.csv.gz"
    write_csv_recording(path, time_s, accel)
    with_arrow = open_recording_reader(path).read_all()
    without = outcome_without_pyarrow(path)
    assert without[1] is None
    assert np.array_equal(np.array(without[0]), np.column_stack([with_arrow.time_s, with_arrow.accel_mps2]))


BAD_FILES = {
    "a word in a row": "0.000,1,2,3\n0.002,1,x,3\n0.004,1,2,3\n",
    "three values": "0.000,1,2,3\n0.002,1,2\n",
    "a NaN with a payload": "0.000,1,2,3\n0.002,1,nan(7),3\n0.004,1,2,3\n",
    "blank lines and CRs": "0.000,1,2,3\r\n\r\n0.002,1,2,3\r0.004,1,2,3\r0.006,1,2,3\r\n",
    "a vertical tab": "0.000,1,2,3\n0.002,1,2,3\x0b\n0.004,1,2,3\n",
    "a step off the rate": "0.000,1,2,3\n0.002,1,2,3\n0.009,1,2,3\n",
    "not UTF-8": "0.000,1,2,3\n0.002,1,2,\xff3\n",
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_a_file_reads_alike_with_and_without_pyarrow(tmp_path: Path, name: str) -> None:
    path = tmp_path / "rec.csv"
    path.write_bytes((HEADER + "\n" + BAD_FILES[name]).encode("utf-8", "surrogateescape").replace(b"\xc3\xbf", b"\xff"))
    assert outcome_without_pyarrow(path) == outcome(path)


def test_a_parquet_recording_without_pyarrow_is_one_error_saying_what_to_install(tmp_path: Path) -> None:
    path = tmp_path / "run.parquet"
    write_parquet_recording(path, np.arange(10) / 500.0, np.zeros((10, 3)))
    with pytest.MonkeyPatch.context() as mp:
        mp.setitem(sys.modules, "pyarrow", None)
        with pytest.raises(RecordingError, match=r"run.parquet: a Parquet recording needs pyarrow.*pip install 'bogiemon\[recordings\]'"):
            open_recording_reader(path)
        with pytest.raises(RecordingError, match=r"writing a Parquet recording needs pyarrow"):
            write_parquet_recording(tmp_path / "new.parquet", np.arange(10) / 500.0, np.zeros((10, 3)))


def test_a_recorder_writing_parquet_is_refused_by_the_config_where_pyarrow_is_missing(without_pyarrow: None) -> None:
    with pytest.raises(ValueError, match=r"format = \"parquet\" needs pyarrow") as refused:
        BogiemonConfig.model_validate({"recorder": {"enabled": True, "format": "parquet"}})
    assert "pip install 'bogiemon[recordings]'" in str(refused.value)
    assert BogiemonConfig.model_validate({"recorder": {"enabled": True, "format": "csv.gz"}}).recorder.enabled
