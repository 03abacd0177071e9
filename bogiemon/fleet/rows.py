"""Windows as Parquet rows and back, exactly: the detection core's records, flattened to columns.

A window's every field is a float64 column (triples as `<name>_0..2`, the band cross-spectra as
`power_<band>_<channel>`, `cross_re_<band>_<pair>`, `cross_im_<band>_<pair>`), so a row read back
is the same WindowIndicators, bit for bit, and the back office judges what the gateway judged.
Beside them a row holds only where the window came from and what the source said of it (the
recording, its segment, the sensors' status bits): every conclusion about the window (its health,
gate, load state, judgement) is the daemon's to draw when `fleet judge` judges it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
import pyarrow as pa

from bogiemon.detection import WindowIndicators
from bogiemon.detection.channel_stats import ChannelStats
from bogiemon.detection.spectra import BANDS_HZ, N_BANDS, WindowSpectra
from bogiemon.drivers.base import SensorStatus

SCALARS = tuple(
    f.name for f in dataclasses.fields(WindowIndicators) if f.name not in ("rms_mps2", "channels", "spectra")
)  # start_s, end_s, i1 .. i4_norm, rms_bounce_mps2, rms_pitch_radps2, rms_roll_radps2
TRIPLES = ("rms_mps2",)
CHANNEL_TRIPLES = tuple(f.name for f in dataclasses.fields(ChannelStats))
SPECTRA = ("power", "cross_re", "cross_im")


def _triple_columns(name: str) -> list[str]:
    return [f"{name}_{c}" for c in range(3)]


def _spectra_columns(name: str) -> list[str]:
    return [f"{name}_{b}_{c}" for b in range(N_BANDS) for c in range(3)]


WINDOW_COLUMNS: tuple[str, ...] = (
    *SCALARS,
    *(col for name in (*TRIPLES, *CHANNEL_TRIPLES) for col in _triple_columns(name)),
    *(col for name in SPECTRA for col in _spectra_columns(name)),
)
STATUS_COLUMNS = ("status_0", "status_1", "status_2")
# Per window, beside its fields: where it came from and the sensors' status bits over it.
CONTEXT_FIELDS: tuple[tuple[str, pa.DataType], ...] = (
    ("recording", pa.string()),
    ("segment", pa.int32()),
    *((name, pa.int32()) for name in STATUS_COLUMNS),
)
SCHEMA = pa.schema([*CONTEXT_FIELDS, *((name, pa.float64()) for name in WINDOW_COLUMNS)])
Status = tuple[SensorStatus, SensorStatus, SensorStatus]


def window_values(window: WindowIndicators) -> NDArray:
    """The window's WINDOW_COLUMNS values, in that order."""
    spectra = window.spectra
    if spectra is None:
        raise ValueError("a window without spectra cannot be stored: the fused score and the checks need them")
    if tuple(spectra.bands_hz) != BANDS_HZ:
        raise ValueError(f"a window of bands {spectra.bands_hz}: the dataset stores {BANDS_HZ}")
    cross = spectra.cross
    return np.concatenate([
        [float(getattr(window, name)) for name in SCALARS],
        window.rms_mps2,
        *(getattr(window.channels, name) for name in CHANNEL_TRIPLES),
        spectra.power.ravel(), cross.real.ravel(), cross.imag.ravel(),
    ]).astype(np.float64)  # fmt: skip


def to_table(windows: Sequence[WindowIndicators], recordings: Sequence[str], segments: Sequence[int], status: Sequence[Status]) -> pa.Table:
    """A table of SCHEMA: the windows with, per window, its recording, segment and status bits."""
    if not len(windows) == len(recordings) == len(segments) == len(status):
        raise ValueError(f"{len(windows)} windows, {len(recordings)} recordings, {len(segments)} segments and {len(status)} status bits")
    values = np.array([window_values(w) for w in windows], dtype=np.float64).reshape(len(windows), len(WINDOW_COLUMNS))
    bits = np.array([[int(s) for s in st] for st in status], dtype=np.int32).reshape(len(windows), 3)
    columns: dict[str, Any] = {"recording": list(recordings), "segment": np.asarray(segments, dtype=np.int32)}
    for c, name in enumerate(STATUS_COLUMNS):
        columns[name] = bits[:, c]
    for i, name in enumerate(WINDOW_COLUMNS):
        columns[name] = values[:, i]
    return pa.Table.from_pydict(columns, schema=SCHEMA)


def _triple(row: NDArray) -> tuple[float, float, float]:
    return (float(row[0]), float(row[1]), float(row[2]))


def from_table(table: pa.Table) -> list[WindowIndicators]:
    """The windows of a table written by to_table, in its row order."""
    missing = [name for name in WINDOW_COLUMNS if name not in table.column_names]
    if missing:
        raise ValueError(f"not a windows table: columns {missing[:5]} missing")
    values = np.column_stack([table.column(name).to_numpy(zero_copy_only=False) for name in WINDOW_COLUMNS]).astype(np.float64)
    values = values.reshape(table.num_rows, len(WINDOW_COLUMNS))
    n_scalar = len(SCALARS)
    at = n_scalar + 3 * (len(TRIPLES) + len(CHANNEL_TRIPLES))
    spectra = values[:, at:].reshape(table.num_rows, 3, N_BANDS, 3)  # power, cross_re, cross_im
    out = []
    for row, (power, cross_re, cross_im) in zip(values, spectra, strict=True):
        scalars = dict(zip(SCALARS, (float(v) for v in row[:n_scalar]), strict=True))
        rms = _triple(row[n_scalar : n_scalar + 3])
        stats = {name: _triple(row[n_scalar + 3 * (k + 1) : n_scalar + 3 * (k + 2)]) for k, name in enumerate(CHANNEL_TRIPLES)}
        out.append(
            WindowIndicators(
                **scalars, rms_mps2=rms, channels=ChannelStats(**stats),
                spectra=WindowSpectra.from_parts(power, cross_re + 1j * cross_im, BANDS_HZ),
            )  # fmt: skip
        )
    return out


def status_of(table: pa.Table) -> list[Status]:
    """The sensors' status bits of each row."""
    missing = [name for name in STATUS_COLUMNS if name not in table.column_names]
    if missing:
        raise ValueError(f"not a windows table: columns {missing} missing")
    cols = [table.column(name).to_pylist() for name in STATUS_COLUMNS]
    return [(SensorStatus(a), SensorStatus(b), SensorStatus(c)) for a, b, c in zip(*cols, strict=True)]
