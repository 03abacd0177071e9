"""Windows stored as Parquet rows come back as the same WindowIndicators, bit for bit."""

from __future__ import annotations

import io

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from bogiemon.detection import BogieGeometry, IndicatorStream, ProcessingSettings
from bogiemon.drivers.base import SensorStatus
from bogiemon.fleet import rows


def _windows(seed: int, n: int = 6):
    settings = ProcessingSettings(fs_hz=200.0, window_s=8.0, hop_s=2.0, max_lag_s=1.0, lowpass_hz=10.0)
    rng = np.random.default_rng(seed)
    samples = rng.normal(0.0, 1.0, (int((8.0 + 2.0 * (n - 1)) * 200), 3)) + 9.81
    return IndicatorStream(settings, BogieGeometry(), 1.79e9).process(samples)


def _table(windows):
    n = len(windows)
    ok, fault = SensorStatus.OK, SensorStatus.SENSOR_FAULT
    return rows.to_table(windows, ["r.csv"] * n, [0] * n, [(ok, fault, ok)] * n)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_windows_survive_a_parquet_round_trip_exactly(seed: int) -> None:
    windows = _windows(seed)
    buffer = io.BytesIO()
    pq.write_table(_table(windows), buffer, compression="zstd")
    back = rows.from_table(pq.read_table(io.BytesIO(buffer.getvalue())))
    assert back == windows  # dataclass equality: every float identical


def test_status_bits_come_back_per_channel() -> None:
    windows = _windows(0, n=2)
    status = rows.status_of(_table(windows))
    assert [int(s) for s in status[0]] == [0, 2, 0]


def test_a_table_without_the_window_columns_is_refused() -> None:
    with pytest.raises(ValueError, match="not a windows table"):
        rows.from_table(pa.table({"start_s": [0.0]}))


def test_contexts_must_match_the_windows() -> None:
    windows = _windows(0, n=2)
    with pytest.raises(ValueError, match="2 windows, 1 recordings"):
        rows.to_table(windows, ["r.csv"], [0, 0], [(SensorStatus.OK,) * 3] * 2)
