"""Fuzz target of another writer's CSV recording read through a column mapping, as `replay --columns`
reads it (drivers/columns.py, drivers/recording_csv.py): ';', tab or ',' between the cells, the time
in s, ms or us (said by its name or not), the channels under other names among columns bogiemon
does not read (text, empty, a comment), in m/s^2, g or mm/s^2 with the mapping's unit, then damaged
line by line (cells, numbers, delimiters, garbage lines, cut) or byte by byte. Each input must end in
RecordingError or a correct read: a valid file's samples all delivered, each the file's value in
m/s^2 (within the rounding of its text); blocks at finite times; the peak RSS bounded.
"""

from __future__ import annotations

import csv
import io
import random

import numpy as np

import fuzz_core
from fuzz_memory import PeakRss, memory_verdict
from bogiemon.drivers.base import EndOfStream
from bogiemon.drivers.columns import AccelUnit, ChannelColumn, ColumnMap, TimeUnit
from bogiemon.drivers.recording_format import RecordingError
from bogiemon.drivers.replay import RecordingReplaySource

PEAK_RSS_BOUND_MIB = 64.0
UNITS = {AccelUnit.MPS2: 1.0, AccelUnit.G: 1 / 9.80665, AccelUnit.MMPS2: 1000.0}  # a value in m/s^2 written in each unit
TIME_NAMES = {"Zeit [ms]": 1e3, "t_us": 1e6, "Time": 1.0, "timestamp": 1.0, "zeit": 1.0}  # by name; the unit's factor from s


def generate(rng: random.Random) -> fuzz_core.Input:
    delimiter = rng.choice((";", ";", "\t", ",", "|"))
    time_name = rng.choice(list(TIME_NAMES))
    time_unit = TimeUnit.MS if time_name == "Zeit [ms]" else TimeUnit.US if time_name == "t_us" else TimeUnit.S
    unit = rng.choice(list(UNITS))
    channels = rng.sample(["acc_fl", "acc_fr", "acc_rl", "Beschl. VL", "az 1"], 3)
    extra = rng.sample(["Temp", "Kommentar", "speed_kmh", "leer"], rng.randint(0, 3))
    names = [time_name, *channels, *extra]
    rng.shuffle(names)
    n = rng.choice((2, 10, rng.randint(10, 2000)))
    fs_hz = rng.choice((500.0, 200.0, 1000.0))
    start_s = rng.choice((0.0, 12.5))
    accel = np.random.default_rng(rng.randrange(2**32)).normal(9.81, 2.0, (n, 3))
    lines = [delimiter.join(names)]
    for k in range(n):
        cells = {time_name: f"{(start_s + k / fs_hz) * TIME_NAMES[time_name]:.6f}", "Temp": "21.5", "Kommentar": "ok", "speed_kmh": "80", "leer": ""}
        cells.update({name: f"{accel[k, i] * UNITS[unit]:.6f}" for i, name in enumerate(channels)})
        lines.append(delimiter.join(cells[name] for name in names))
    text = "\n".join(lines) + "\n"
    valid = rng.random() < 0.25
    if not valid:
        m = fuzz_core.Mutator(rng)
        if rng.random() < 0.7:
            text = m.lines(text, tokens=lambda line: delimiter.join(m.number_text() if rng.random() < 0.3 else c for c in line.split(delimiter)))
        else:
            return {"file": m.bytes(text.encode()), "mapping": [time_name, *channels], "time_unit": str(time_unit), "unit": str(unit),
                    "n": None, "max_block_s": 1.0}  # fmt: skip
    return {"file": text.encode(), "mapping": [time_name, *channels], "time_unit": str(time_unit), "unit": str(unit),
            "n": n if valid else None, "max_block_s": rng.choice((1.0, 0.1)), "delimiter": delimiter}  # fmt: skip


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / "other.csv"
    path.write_bytes(data["file"])
    time_name, *channels = data["mapping"]
    columns = ColumnMap(time_name, TimeUnit(data["time_unit"]), tuple(ChannelColumn(f"a{i + 1}", c) for i, c in enumerate(channels)), AccelUnit(data["unit"]))
    samples: list[np.ndarray] = []
    with PeakRss() as peak:
        try:
            source = RecordingReplaySource(path, rate=0.0, max_block_s=data["max_block_s"], columns=columns)
        except RecordingError as exc:
            if data["n"] is not None:
                return f"rejected a valid recording: {exc}"
            raise
        try:
            for _ in range(100_000):
                try:
                    block = source.read(1.0)
                except EndOfStream:
                    break
                except RecordingError as exc:
                    if data["n"] is not None:
                        return f"rejected a valid recording after {sum(len(a) for a in samples)} samples: {exc}"
                    raise
                if block is not None:
                    if not np.isfinite(block.start_s):
                        return f"a block at {block.start_s!r}"
                    samples.append(block.accel_mps2)
            else:
                return "the replay never ends: 100 000 reads without EndOfStream"
        finally:
            source.close()
    if (beyond := memory_verdict(ctx, peak, PEAK_RSS_BOUND_MIB)) is not None:
        return beyond
    if data["n"] is None:
        return None
    got = np.concatenate(samples) if samples else np.empty((0, 3))
    if got.shape[0] != data["n"]:
        return f"delivered {got.shape[0]} samples of the {data['n']} written"
    return _check_values(data, columns, got)


def _check_values(data: fuzz_core.Input, columns: ColumnMap, got: np.ndarray) -> fuzz_core.Verdict:
    """The samples delivered are the file's cells of the mapped columns, in m/s^2 (the csv module's reading)."""
    rows = list(csv.reader(io.StringIO(data["file"].decode()), delimiter=data["delimiter"]))
    names = rows[0]
    picks = [names.index(c.column) for c in columns.channels]
    expected = np.array([[float(row[i]) for i in picks] for row in rows[1:] if row], dtype=np.float64) * columns.unit.to_mps2
    if not np.allclose(got, expected, rtol=1e-12, atol=0.0):
        return f"samples differ from the file's cells in m/s^2: first at row {int(np.flatnonzero(~np.isclose(got, expected, rtol=1e-12, atol=0.0).all(axis=1))[0])}"
    return None


TARGETS = [fuzz_core.Target("recording-mapped", generate, run)]
