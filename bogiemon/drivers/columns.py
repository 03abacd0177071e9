"""How a recording someone else wrote maps onto bogiemon's samples: which column is the time and
in what unit, which columns are the channels (with a gain and an offset each), and the unit of
the accelerations; and the check that the levels a file holds agree with the unit it is said to
be in, before anything of it is judged.

The channels are named: a1, a2, a3 for the bogie's three sensors. A second bogie is one more set
of names (b1, b2, b3) in the same mapping, not another reader.

This module imports only the standard library and numpy.
"""

from __future__ import annotations

import enum
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

STANDARD_GRAVITY_MPS2 = 9.80665
# How a user maps another writer's columns (said by every error about them).
MAPPING_HINT = "map them: --columns time=NAME,a1=NAME,a2=NAME,a3=NAME, or [source] columns in the config"
CHANNELS: tuple[str, ...] = ("a1", "a2", "a3")  # one bogie; a second bogie adds ("b1", "b2", "b3")


class AccelUnit(enum.StrEnum):
    """The unit a file's accelerations are in; bogiemon works in m/s^2."""

    MPS2 = "m/s^2"
    G = "g"
    MMPS2 = "mm/s^2"

    @property
    def to_mps2(self) -> float:
        return {AccelUnit.MPS2: 1.0, AccelUnit.G: STANDARD_GRAVITY_MPS2, AccelUnit.MMPS2: 1e-3}[self]


class TimeUnit(enum.StrEnum):
    """The unit of a file's time column. auto: the column's name where it says (time_ms,
    "t [us]"), else by magnitude where the times are Unix times (seconds about 1.7e9, milliseconds
    1.7e12, ...), else seconds. (A Parquet timestamp column states its own.)"""

    AUTO = "auto"
    S = "s"
    MS = "ms"
    US = "us"
    NS = "ns"

    @property
    def to_s(self) -> float:
        return {TimeUnit.S: 1.0, TimeUnit.MS: 1e-3, TimeUnit.US: 1e-6, TimeUnit.NS: 1e-9}.get(self, 1.0)


_NAME_UNIT = re.compile(r"(?:^|[_\s\[(])(s|sec|ms|us|µs|ns)[\])]?$", re.IGNORECASE)
# A Unix time in these units lies between 2001 and 2100 (1e9 .. 4.1e9 seconds).
_EPOCH_RANGES = ((TimeUnit.S, 1e9, 4.2e9), (TimeUnit.MS, 1e12, 4.2e12), (TimeUnit.US, 1e15, 4.2e15), (TimeUnit.NS, 1e18, 4.2e18))
TIME_NAMES = ("time_s", "time", "timestamp", "t", "ts", "datetime", "date_time", "time_ms", "timestamp_ms", "time_us", "time_ns")


def unit_of_name(name: str) -> TimeUnit | None:
    """The time unit a column's name states ('time_ms', 't [us]'), or None."""
    found = _NAME_UNIT.search(name.strip())
    if not found:
        return None
    word = found.group(1).lower()
    return {"s": TimeUnit.S, "sec": TimeUnit.S, "ms": TimeUnit.MS, "us": TimeUnit.US, "µs": TimeUnit.US, "ns": TimeUnit.NS}[word]


def unit_of_values(first: float) -> TimeUnit | None:
    """The unit a Unix time of this magnitude is in, or None for a time that is no Unix time."""
    for unit, low, high in _EPOCH_RANGES:
        if low <= abs(first) < high:
            return unit
    return None


@dataclass(frozen=True)
class ChannelColumn:
    """One channel: the column it is read from, and value * gain + offset (in the file's unit)."""

    channel: str
    column: str
    gain: float = 1.0
    offset: float = 0.0


@dataclass(frozen=True)
class ColumnMap:
    """Which columns of a file are the time and the channels, and their units.

    time: the time column's name; None: the first of TIME_NAMES the file has.
    channels: one ChannelColumn per channel, in channel order (a1, a2, a3).
    """

    time: str | None = None
    time_unit: TimeUnit = TimeUnit.AUTO
    channels: tuple[ChannelColumn, ...] = field(default_factory=lambda: tuple(ChannelColumn(c, c) for c in CHANNELS))
    unit: AccelUnit = AccelUnit.MPS2

    @property
    def is_default(self) -> bool:
        return self == ColumnMap()

    @property
    def gains(self) -> NDArray[np.float64]:
        """(channels,) what a file's value is multiplied by to give m/s^2 (the gain and the unit)."""
        return np.array([c.gain * self.unit.to_mps2 for c in self.channels])

    @property
    def offsets_mps2(self) -> NDArray[np.float64]:
        return np.array([c.offset * self.unit.to_mps2 for c in self.channels])

    def to_mps2(self, values: NDArray[np.float64]) -> NDArray[np.float64]:
        """(n, channels) values of the file -> m/s^2 (a no-op for the default mapping)."""
        if self.unit is AccelUnit.MPS2 and all(c.gain == 1.0 and c.offset == 0.0 for c in self.channels):
            return values
        return values * self.gains + self.offsets_mps2

    def time_column(self, names: list[str]) -> str | None:
        """The time column among a file's column names (the configured one, else the first known name)."""
        if self.time is not None:
            return self.time if self.time in names else None
        lowered = {n.strip().lower(): n for n in names}
        for candidate in TIME_NAMES:
            if candidate in lowered:
                return lowered[candidate]
        return next((n for n in names if n.strip().lower().startswith(("time", "timestamp"))), None)

    def select(self, names: list[str]) -> list[str]:
        """The columns read among a file's names: the time's, then each channel's in channel order;
        ValueError naming those missing (and how to map them) or a column read twice."""
        time = self.time_column(names)
        wanted = [c.column for c in self.channels]
        missing = ([] if time is not None else ["time column" if self.time is None else f"column '{self.time}'"]) + [
            f"column '{c}'" for c in wanted if c not in names
        ]
        if missing:
            raise ValueError(f"no {', no '.join(missing)} ({self.describe()}); {MAPPING_HINT}")
        assert time is not None
        if len({time, *wanted}) != 1 + len(wanted):
            raise ValueError(f"the mapping {self.describe()} reads one column twice; {MAPPING_HINT}")
        return [time, *wanted]

    def resolved_time_unit(self, column: str, first_value: float | None) -> TimeUnit:
        """The time unit of the time column: the configured one, else its name's, else by magnitude."""
        if self.time_unit is not TimeUnit.AUTO:
            return self.time_unit
        return unit_of_name(column) or (unit_of_values(first_value) if first_value is not None else None) or TimeUnit.S

    def describe(self) -> str:
        """The mapping in the words of --columns: 'time=ts,a1=acc_fl,...'."""
        parts = [f"time={self.time or 'auto'}"] + [f"{c.channel}={c.column}" for c in self.channels]
        return ",".join(parts)


def parse_columns(text: str, base: ColumnMap | None = None) -> ColumnMap:
    """A ColumnMap from --columns text: 'time=Timestamp,a1=acc_z_fl,a2=acc_z_fr,a3=acc_z_rl'
    (pairs left out keep base's); ValueError naming what is wrong."""
    base = base or ColumnMap()
    time = base.time
    channels = {c.channel: c for c in base.channels}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = part.partition("=")
        key, value = key.strip(), value.strip()
        if not sep or not value:
            raise ValueError(f"'{part}': write NAME=COLUMN (time=..., {'=..., '.join(CHANNELS)}=...)")
        if key == "time":
            time = value
        elif key in channels:
            channels[key] = ChannelColumn(key, value, channels[key].gain, channels[key].offset)
        else:
            raise ValueError(f"'{key}' is no channel: use time or {', '.join(CHANNELS)}")
    return ColumnMap(time, base.time_unit, tuple(channels[c] for c in CHANNELS), base.unit)


def with_gains(columns: ColumnMap, gains: Mapping[str, float], offsets: Mapping[str, float]) -> ColumnMap:
    """columns with the gains and offsets of some channels replaced; ValueError for a name that is no channel."""
    unknown = sorted((set(gains) | set(offsets)) - {c.channel for c in columns.channels})
    if unknown:
        raise ValueError(f"no channel {', '.join(unknown)}: use {', '.join(CHANNELS)}")
    return ColumnMap(
        columns.time, columns.time_unit,
        tuple(ChannelColumn(c.channel, c.column, gains.get(c.channel, c.gain), offsets.get(c.channel, c.offset)) for c in columns.channels),
        columns.unit,
    )  # fmt: skip


# -- the unit's check -----------------------------------------------------------------------------

# A vertical accelerometer's static level with gravity, in m/s^2: 1 g with a sensor's offset and
# mounting tilt. Without gravity (removed by the logger) the level is near 0 in any unit.
GRAVITY_BAND_MPS2 = (7.0, 12.6)
# The converter's full scale: a level beyond it is no acceleration of a bogie in the stated unit.
FULL_SCALE_MPS2 = 16 * STANDARD_GRAVITY_MPS2


def unit_problem(accel_mps2: NDArray[np.float64], unit: AccelUnit) -> str | None:
    """What the levels of some seconds of samples (n, channels) in m/s^2 (as converted from
    `unit`) say about that unit, or None when they agree with it or say nothing.

    The channels' median levels decide: where they all lie in the gravity band once converted
    back to each other unit, the file is in that one (a static level near 1 read as m/s^2 is in
    g; near 9810, in mm/s^2). A level beyond the converter's full scale in the stated unit says
    the unit is too small (mm/s^2 read as m/s^2). Levels near 0 (gravity removed) say nothing:
    such a file is judged in the unit stated.
    """
    finite = accel_mps2[np.all(np.isfinite(accel_mps2), axis=1)]
    if finite.shape[0] < 2:
        return None
    level = _median0(finite)  # (channels,) the static level of each channel
    spread = _median0(np.abs(finite - level))
    low, high = GRAVITY_BAND_MPS2
    if bool(np.all((low <= np.abs(level)) & (np.abs(level) <= high))):
        return None
    raw = level / unit.to_mps2  # the levels as the file writes them
    for other in AccelUnit:
        if other is unit:
            continue
        converted = np.abs(raw * other.to_mps2)
        if bool(np.all((low <= converted) & (converted <= high))):
            return _looks_like(raw, unit, other)
    scale = np.maximum(np.abs(level), spread)
    if bool(np.all(scale > FULL_SCALE_MPS2)) and unit is not AccelUnit.MMPS2:
        return _looks_like(raw, unit, AccelUnit.MMPS2, beyond=True)
    return None


def _median0(values: NDArray[np.float64]) -> NDArray[np.float64]:
    """np.median(values, axis=0) of finite values, without the numpy.ma np.median imports (a
    command that reads a recording loads no more than it uses)."""
    ordered = np.sort(values, axis=0)
    middle = ordered.shape[0] // 2
    return ordered[middle] if ordered.shape[0] % 2 else (ordered[middle - 1] + ordered[middle]) / 2.0


def _looks_like(raw: NDArray[np.float64], unit: AccelUnit, other: AccelUnit, beyond: bool = False) -> str:
    levels = ", ".join(f"{v:.4g}" for v in raw)
    why = "beyond a sensor's full scale" if beyond else "1 g"
    factor = other.to_mps2 / unit.to_mps2
    return (
        f"these values look like {other} ({why}: static levels {levels}), not {unit}, and nothing is judged in a wrong unit: "
        f"set the unit: --unit {other}, or [source] unit = \"{other}\" in the config (or convert them to {unit}: x {factor:.6g})"
    )


def nominal_rate_hz(step_s: float) -> float:
    """A rate from a mean time step, snapped to the whole hertz it is within 0.05 % of (a logger's
    nominal rate, seen through its clock's drift and jitter)."""
    fs_hz = 1.0 / step_s
    whole = round(fs_hz)
    return float(whole) if whole >= 1 and math.isclose(fs_hz, whole, rel_tol=5e-4) else fs_hz
