"""Fuzz target of CSV recordings: read_csv_recording on files, and the start of `analyze` on them.

Valid files follow the documented format (header `time_s,a1,a2,a3`, rows of four numbers at a
uniform step) in the spellings a logger may use (shortest repr or fixed decimals, LF or CRLF, a
byte-order mark, a missing last newline) at rates from 0.01 Hz to 20 kHz; mutations damage bytes,
lines and single numbers (NaN, infinities, 1e309, 4.9e-324, a truncated UTF-8 character, ...).
The reference is Python's csv module with float(): an accepted file must hold exactly what it
reads, and a valid file must be accepted. One input in ten also starts the analysis the way
`bogiemon analyze` does at the recording's own rate (as for a file holding a whole window).
"""

from __future__ import annotations

import codecs
import functools
import csv
import io
import math
import random

import numpy as np

import fuzz_core
from bogiemon.daemon.analysis import analyze_recording
from bogiemon.daemon.config import BogiemonConfig, load_config
from bogiemon.drivers.columns import ColumnMap, TimeUnit
from bogiemon.drivers.recording import MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, RecordingError, read_csv_recording

HEADER = "time_s,a1,a2,a3"
RATES_HZ = (500.0, 500.0, 1000.0, 200.0, 100.0, 50.0, 2000.0, 20_000.0, 10.0, 333.33, 1.0, 0.01)
TOLERANCE = 0.01  # the documented step tolerance: a valid file keeps far inside it


def generate(rng: random.Random) -> fuzz_core.Input:
    m = fuzz_core.Mutator(rng)
    n = rng.choice((2, 3, rng.randint(2, 20), rng.randint(2, 50), rng.randint(50, 200)))
    fs_hz = rng.choice(RATES_HZ) if rng.random() < 0.8 else 10 ** rng.uniform(-2, 4.3)
    start_s = rng.choice((0.0, 100.0, 1.7e9, -50.0, 1e-3, rng.uniform(-1e4, 1e4)))
    step_s = 1.0 / fs_hz
    fmt = rng.choice(("repr", "repr", "fixed", "exp"))
    accel = [[rng.gauss(9.81, 3.0) for _ in range(3)] for _ in range(n)]

    def number(x: float) -> str:
        if fmt == "repr":
            return repr(x)
        if fmt == "fixed":
            return f"{x:.9f}"
        return f"{x:.15e}"

    # Shortest repr reads back exactly; fixed decimals only where they keep the step uniform.
    time_text = repr if fmt != "fixed" or step_s < 1e-4 or abs(start_s) > 1e6 else (lambda x: f"{x:.9f}")
    rows = [",".join([time_text(start_s + i * step_s), *(number(a) for a in accel[i])]) for i in range(n)]
    end = rng.choice(("\n", "\n", "\r\n"))
    text = HEADER + end + end.join(rows) + (end if rng.random() < 0.9 else "")
    raw = (codecs.BOM_UTF8 if rng.random() < 0.05 else b"") + text.encode("utf-8")
    valid = rng.random() < 0.25
    if not valid:
        kind = rng.random()
        if kind < 0.5:
            text = m.lines(text, tokens=lambda line: m.replace_field(line, ","))
            raw = text.encode("utf-8", "surrogatepass")
        elif kind < 0.8:
            raw = m.bytes(raw)
        elif kind < 0.9:
            raw = raw + rng.choice((b"\xc3", b"\xe2\x82", b"\xf0\x9f\x98", b"\xff"))  # a character cut by a full disk
        else:
            tiny = rng.choice((5e-324, 1e-320, 1e-300))  # steps so small the rate overflows
            raw = (HEADER + "\n" + "\n".join(f"{i * tiny!r},1,2,3" for i in range(n)) + "\n").encode()
    return {"file": raw, "valid": valid, "analyze": rng.random() < 0.1}


def reference(raw: bytes) -> tuple[list[float], list[list[float]]] | str:
    """What Python's csv module and float() read from the file, or why they cannot."""
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        return "not UTF-8"
    rows = list(csv.reader(io.StringIO(text, newline="")))
    if not rows:
        return "no header"
    # The header names the columns: bogiemon's own, or those the default mapping finds by name
    # (drivers/columns.py: the time as time_s, time, timestamp, ...; a1, a2, a3).
    names = [cell.strip().strip('"').strip() for cell in rows[0]]
    if ",".join(rows[0]).strip() == HEADER:
        picks = [0, 1, 2, 3]
    else:
        if any(d in ",".join(rows[0]) for d in ";\t|"):
            return "a header the sniffer may split otherwise"
        try:
            picks = [names.index(name) for name in ColumnMap().select(names)]
        except ValueError:
            return "no header"
        if ColumnMap().resolved_time_unit(names[picks[0]], None) is not TimeUnit.S:
            return "a time column not in seconds"
    times, accel = [], []
    for row in rows[1:]:
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(names):
            return f"a row of {len(row)} cells"
        try:
            # Padding is whatever str.strip() removes (Unicode white space, as numpy's reader counts
            # it: \x1c-\x1f too), float() alone only ASCII white space; the number is the same.
            values = [float(row[i].strip()) for i in picks]
        except ValueError:
            return f"not numbers: {row}"
        # NaN is no reading and a time must be finite; an acceleration beyond the converter's
        # range (infinite too) is clipped to its full scale (drivers/recording.py).
        if any(math.isnan(v) for v in values) or not math.isfinite(values[0]):
            return "a value not finite"
        times.append(values[0])
        accel.append([min(max(v, MIN_ACCEL_MPS2), MAX_ACCEL_MPS2) for v in values[1:]])
    return times, accel


def run(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    path = ctx.fresh_dir() / "run.csv"
    path.write_bytes(data["file"])
    if data["valid"]:
        try:
            recording = read_csv_recording(path)
        except RecordingError as exc:  # the documented error, but for a file that follows the format
            return f"rejected a valid recording: {exc}"
    else:
        recording = read_csv_recording(path)
    ref = reference(data["file"])
    if isinstance(ref, str):
        return f"accepted a file the csv module cannot read ({ref}): {recording.n_samples} samples at {recording.fs_hz!r} Hz"
    times, accel = ref
    if recording.resampled_samples:  # jittered times on the grid: interpolated, never beyond the rows' range
        low, high = np.min(accel, axis=0), np.max(accel, axis=0)
        if not np.all((recording.accel_mps2 >= low) & (recording.accel_mps2 <= high)):
            return f"resampled values beyond the range of the csv module's: {recording.n_samples} samples read, {len(times)} rows"
    elif not np.array_equal(recording.time_s, np.array(times)) or not np.array_equal(recording.accel_mps2, np.array(accel).reshape(-1, 3)):
        return f"values differ from the csv module's: {recording.n_samples} samples read, {len(times)} rows"
    if not (math.isfinite(recording.fs_hz) and recording.fs_hz > 0):
        return f"absurd sample rate: {recording.fs_hz!r} Hz from {recording.n_samples} samples"
    if data["analyze"]:
        next(iter(analyze_recording(recording, _default_config())), None)
    return None


@functools.cache
def _default_config() -> BogiemonConfig:
    return load_config(None)


TARGETS = [fuzz_core.Target("csv", generate, run)]
