"""Windows as Parquet rows and back, exactly: the detection core's records, flattened to columns.

A window's every field is a float64 column (triples as `<name>_0..2`, the band cross-spectra as
`power_<band>_<channel>`, `cross_re_<band>_<pair>`, `cross_im_<band>_<pair>`), so a row read back
is the same WindowIndicators, bit for bit, and the back office judges what the gateway judged.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np
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
# Per window, beside its fields: where it came from, and what the gateway's own checks saw.
CONTEXT_FIELDS: tuple[tuple[str, pa.DataType], ...] = (
    ("recording", pa.string()),
    ("segment", pa.int32()),
    ("status_0", pa.int32()),
    ("status_1", pa.int32()),
    ("status_2", pa.int32()),
    ("gate", pa.string()),
    ("problems", pa.string()),
    ("p_full", pa.float64()),
)
SCHEMA = pa.schema([*CONTEXT_FIELDS, *((name, pa.float64()) for name in WINDOW_COLUMNS)])


def window_values(window: WindowIndicators) -> list[float]:
    """The window's WINDOW_COLUMNS values, in that order."""
    if window.spectra is None:
        raise ValueError("a window without spectra cannot be stored: the fused score and the checks need them")
    if tuple(window.spectra.bands_hz) != BANDS_HZ:
        raise ValueError(f"a window of bands {window.spectra.bands_hz}: the dataset stores {BANDS_HZ}")
    out = [float(getattr(window, name)) for name in SCALARS]
    out += [float(v) for v in window.rms_mps2]
    for name in CHANNEL_TRIPLES:
        out += [float(v) for v in getattr(window.channels, name)]
    for name in SPECTRA:
        out += [float(v) for band in getattr(window.spectra, name) for v in band]
    return out


def to_table(windows: Sequence[WindowIndicators], context: Sequence[dict[str, Any]]) -> pa.Table:
    """A table of SCHEMA from windows and, per window, its CONTEXT_FIELDS."""
    if len(windows) != len(context):
        raise ValueError(f"{len(windows)} windows and {len(context)} contexts")
    values = np.array([window_values(w) for w in windows], dtype=np.float64).reshape(len(windows), len(WINDOW_COLUMNS))
    columns: dict[str, Any] = {name: [c[name] for c in context] for name, _ in CONTEXT_FIELDS}
    for i, name in enumerate(WINDOW_COLUMNS):
        columns[name] = values[:, i]
    return pa.Table.from_pydict(columns, schema=SCHEMA)


def _triple(row: Sequence[float]) -> tuple[float, float, float]:
    return (float(row[0]), float(row[1]), float(row[2]))


def from_table(table: pa.Table) -> list[WindowIndicators]:
    """The windows of a table written by to_table, in its row order."""
    missing = [name for name in WINDOW_COLUMNS if name not in table.column_names]
    if missing:
        raise ValueError(f"not a windows table: columns {missing[:5]} missing")
    values = np.column_stack([table.column(name).to_numpy(zero_copy_only=False) for name in WINDOW_COLUMNS]).astype(np.float64)
    n_scalar = len(SCALARS)
    out = []
    for row in values:
        scalars = dict(zip(SCALARS, (float(v) for v in row[:n_scalar]), strict=True))
        at = n_scalar
        rms = _triple(row[at : at + 3])
        at += 3
        stats = {}
        for name in CHANNEL_TRIPLES:
            stats[name] = _triple(row[at : at + 3])
            at += 3
        spectra = {}
        for name in SPECTRA:
            block = row[at : at + 3 * N_BANDS].reshape(N_BANDS, 3)
            spectra[name] = tuple(_triple(band) for band in block)
            at += 3 * N_BANDS
        out.append(
            WindowIndicators(
                **scalars, rms_mps2=rms, channels=ChannelStats(**stats), spectra=WindowSpectra(bands_hz=BANDS_HZ, **spectra)
            )
        )
    return out


def status_of(table: pa.Table) -> list[tuple[SensorStatus, SensorStatus, SensorStatus]]:
    """The sensors' status bits of each row."""
    cols = [table.column(f"status_{c}").to_pylist() for c in range(3)]
    return [(SensorStatus(a), SensorStatus(b), SensorStatus(c)) for a, b, c in zip(*cols, strict=True)]
