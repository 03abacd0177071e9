"""The reading of a recording whatever its format: RecordingReader, the base of the CSV, Parquet and
MF4 readers (the survey's checks of the whole file, its nominal rate and the unit its levels say,
the chunks, the whole recording in memory), and the checks of every row in file order (NaN, a time
not plausible or not increasing; a sample beyond the converter's range clipped and counted).

Time stamps as loggers write them: a step within TIME_STEP_TOLERANCE of the file's step is the
step (times printed to a few decimals); within JITTER_TOLERANCE it is jitter, and the segment's
samples are interpolated onto its nominal grid (counted: resampled_samples); longer is a gap,
where a new segment starts (a chunk never spans one; the reader lists them); shorter is a row
off the rate, an error naming it. The nominal rate is the whole file's where its steps agree with
it, else that of the first stretch without a gap (snapped to a whole hertz within 0.05 %)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Generator, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S
from bogiemon.drivers.columns import ColumnMap, nominal_rate_hz, unit_problem
from bogiemon.drivers.files import UntrustedFile
from bogiemon.drivers.recording_format import JITTER_TOLERANCE, MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, Recording, RecordingError

# A time step may deviate this much (relative) from the file's step and be taken as it is: enough
# for times printed with 6 decimals at 1 kHz.
TIME_STEP_TOLERANCE = 0.01
# The gaps a reader lists for its summary (all are counted).
MAX_LISTED_GAPS = 100
# The file's step is the median of its first steps (of all of them in a file this short): a
# streaming reader cannot wait for the whole file's median before it checks the first rows.
REFERENCE_STEPS = 4096


class RecordingReader(ABC):
    """A recording opened for reading: its rate and length known, its samples read chunk by chunk.

    Opened by open_recording_reader (which refuses what concerns the whole file); chunks() gives
    (time_s (m,), accel_mps2 (m, 3)) float64 in order, every row checked and clipped, and raises
    RecordingError at the first bad row. It may be iterated again (each pass reads the file anew).
    """

    path: Path
    file: UntrustedFile  # the checked descriptor: every pass reads through it, never the name
    format: str  # "csv" or "parquet"
    n_samples: int
    start_s: float  # the time of the first sample
    last_s: float  # the time of the last sample
    fs_hz: float

    def __init__(self, file: UntrustedFile, columns: ColumnMap | None = None) -> None:
        self.file = file
        self.path = file.path
        self.columns = columns or ColumnMap()
        self.time_to_s = 1.0  # the time column's unit in seconds (its reader's open sets it)
        self.clipped_samples = 0  # of the last pass of chunks(), so far
        self.resampled_samples = 0  # of the last pass: samples interpolated onto the grid
        self.max_jitter_s = 0.0  # of the last pass: the largest deviation of a step from the grid's
        self.gaps: list[Gap] = []  # of the last pass, the first MAX_LISTED_GAPS
        self.gap_count = 0

    def close(self) -> None:
        """Release the file (a pass still reading holds a descriptor of its own until it ends)."""
        self.file.close()

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    @abstractmethod
    def open(self, min_samples: int) -> None:
        """Survey the file and refuse what concerns the whole of it (_check_whole)."""

    @abstractmethod
    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The file's rows as arrays, unchecked, in order; RecordingError for what cannot be parsed."""

    def _mapped_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """_raw_chunks in seconds and m/s^2: the time column's unit, each channel's gain and
        offset and the file's unit applied (the default mapping passes the file's arrays)."""
        time_to_s = self.time_to_s
        raw = self._raw_chunks()
        try:
            for time_s, values in raw:
                yield (time_s * time_to_s if time_to_s != 1.0 else time_s), self.columns.to_mps2(values)
        finally:
            close = getattr(raw, "close", None)
            if close is not None:
                close()  # the file's pass ends with this one's, also at a bad row

    @abstractmethod
    def where(self, row: int) -> str:
        """Where data row `row` (from 0) is in the file, for a message: 'line 1873', 'row 1872'."""

    def error(self, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {problem}")

    def row_error(self, row: int, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {self.where(row)}: {problem}")

    def chunks(self) -> Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None]:
        """(time_s (m,), accel_mps2 (m, 3)) in order, checked; a chunk never spans a gap (its times
        jump from the last chunk's: a new segment)."""
        checker = _RowChecker(self)
        self.clipped_samples = self.resampled_samples = self.gap_count = 0
        self.max_jitter_s = 0.0
        self.gaps = []
        yield from checker.checked(self._mapped_chunks())
        if checker.rows != self.n_samples or checker.last_s != self.last_s:
            self.error(
                f"changed while it was read ({checker.rows} rows, not {self.n_samples}): is a logger still writing it? "
                "Use the recording once it is complete"
            )

    def read_all(self) -> Recording:
        """The whole recording in memory."""
        times, accels = [], []
        for time_s, accel_mps2 in self.chunks():
            times.append(time_s)
            accels.append(accel_mps2)
        return Recording(
            path=self.path,
            time_s=np.concatenate(times),
            accel_mps2=np.ascontiguousarray(np.concatenate(accels)),
            fs_hz=self.fs_hz,
            clipped_samples=self.clipped_samples,
            resampled_samples=self.resampled_samples,
        )

    # -- what the open checks ----------------------------------------------------------------------

    def _check_whole(self, min_samples: int, first_s: float | None, last_s: float | None) -> None:
        """Set the rate from the survey; refuse what concerns the whole file, after naming any bad row.

        A file whose rows cannot give a rate (fewer than two, times not increasing from the first
        to the last) or too short for min_samples is read through first: a bad row in it is the
        error, as it is what the user must repair.
        """
        n = self.n_samples
        with np.errstate(over="ignore", divide="ignore", invalid="ignore"):
            fs_hz = float((n - 1) / (np.float64(last_s) - np.float64(first_s))) if n >= 2 and None not in (first_s, last_s) else math.nan
        usable = n >= 2 and math.isfinite(fs_hz) and fs_hz > 0
        if usable and n >= min_samples:
            self.start_s, self.last_s = float(first_s), float(last_s)  # type: ignore[arg-type]
            self.fs_hz = self._nominal_rate(fs_hz)
            return
        # The rows are read through for a bad one; the survey's own values do not judge them.
        self.start_s = self.last_s = math.nan
        self.fs_hz = fs_hz
        checker = _RowChecker(self)
        for _ in checker.checked(self._mapped_chunks()):
            pass
        if checker.rows == 0:
            self.error("holds no samples after the header" if self.format == "csv" else "holds no samples")
        if checker.rows < 2:
            self.error(f"holds {checker.rows} sample(s); a recording needs at least two rows" + (" after the header" if self.format == "csv" else ""))
        if not usable:
            if checker.rows == n and checker.reference_step_s is not None:
                self.error(f"time steps of {checker.reference_step_s:.6g} s give no finite sample rate: time_s must be in seconds")
            self.error(f"changed while it was read ({checker.rows} rows, not {n}): is a logger still writing it? Use the recording once it is complete")
        self.error(
            f"{n} samples ({n / fs_hz:.1f} s) is shorter than one analysis window "
            f"({min_samples} samples, {min_samples / fs_hz:.1f} s): use a longer recording or a shorter window_s"
        )

    def _head(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The file's first rows (up to REFERENCE_STEPS + 1), unchecked."""
        times, accels, n = [], [], 0
        raw = self._mapped_chunks()
        try:
            for time_s, accel_mps2 in raw:
                times.append(time_s)
                accels.append(accel_mps2)
                n += time_s.shape[0]
                if n > REFERENCE_STEPS:
                    break
        except RecordingError:
            pass  # a bad row among the first: named when the reading reaches it
        finally:
            close = getattr(raw, "close", None)
            if close is not None:
                close()
        if not times:
            return np.empty(0), np.empty((0, 3))
        return np.concatenate(times)[: REFERENCE_STEPS + 1], np.concatenate(accels)[: REFERENCE_STEPS + 1]

    def _nominal_rate(self, whole_fs_hz: float) -> float:
        """The file's rate: the whole file's (first to last time) where its first steps agree with
        it; else the first stretch's without a gap. Refuses a file whose levels say another unit."""
        head_t, head_a = self._head()
        problem = unit_problem(head_a, self.columns.unit)
        if problem is not None:
            self.error(problem)
        with np.errstate(invalid="ignore"):
            steps = np.diff(head_t)
            steps = steps[np.isfinite(steps) & (steps > 0)]
        if steps.size == 0:
            return nominal_rate_hz(1.0 / whole_fs_hz)
        reference = _median(steps)
        if abs(1.0 / whole_fs_hz - reference) <= TIME_STEP_TOLERANCE * reference:
            return nominal_rate_hz(1.0 / whole_fs_hz)
        off = np.flatnonzero(np.abs(steps - reference) > JITTER_TOLERANCE * reference)
        run = steps[: off[0]] if off.size else steps
        return nominal_rate_hz(float(run.mean()) if run.size else reference)

    def require_samples(self, min_samples: int) -> None:
        """Refuse a recording shorter than min_samples (e.g. one analysis window), after naming a bad row."""
        if self.n_samples < min_samples:
            self._check_whole(min_samples, self.start_s, self.last_s)


@dataclass(frozen=True)
class Gap:
    """Samples missing in a recording: after the sample at after_s, none for missing_s."""

    after_s: float
    missing_s: float


class _RowChecker:
    """The checks of every row, in file order, carried from chunk to chunk: NaN, a time that is
    not plausible, not increasing or off the file's step; and the clipping of the samples."""

    def __init__(self, reader: RecordingReader) -> None:
        self.reader = reader
        self.rows = 0  # rows checked
        self.last_s: float | None = None
        # The grid's step: the reader's rate where it has one (its open set it), else the median
        # of the first steps (a file read through for its bad row).
        announced = not math.isnan(getattr(reader, "start_s", math.nan)) and math.isfinite(reader.fs_hz) and reader.fs_hz > 0
        self.reference_step_s: float | None = 1.0 / reader.fs_hz if announced else None
        # The current segment: its first time, the grid points given, its last row (interpolation
        # across chunks), whether its samples are being resampled.
        self._segment_s = math.nan
        self._given = 0
        self._last_row: tuple[float, NDArray[np.float64]] | None = None
        self._resampling = False

    def checked(
        self, raw: Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]
    ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The rows of raw, checked and clipped; at a bad row, the rows before it, then RecordingError."""
        # Rows held until the file's step is known (its first REFERENCE_STEPS steps).
        held_t: list[NDArray[np.float64]] = []
        held_a: list[NDArray[np.float64]] = []
        try:
            yield from self._checked(raw, held_t, held_a)
        except RecordingError:
            if held_t:  # the rows before a bad line are used, also before the file's step is known
                yield from self._check(np.concatenate(held_t), np.concatenate(held_a))
            raise

    def _checked(
        self, raw: Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]], held_t: list[NDArray[np.float64]], held_a: list[NDArray[np.float64]]
    ) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        held_n = 0
        for time_s, accel_mps2 in raw:
            if self.reference_step_s is None and held_n + time_s.shape[0] <= REFERENCE_STEPS:
                held_t.append(time_s)  # the file's step is not known yet: wait for its first steps
                held_a.append(accel_mps2)
                held_n += time_s.shape[0]
                continue
            if held_n:
                time_s, accel_mps2 = np.concatenate([*held_t, time_s]), np.concatenate([*held_a, accel_mps2])
                held_t.clear()
                held_a.clear()
                held_n = 0
            yield from self._check(time_s, accel_mps2)
        if held_n:
            time_s, accel_mps2 = np.concatenate(held_t), np.concatenate(held_a)
            held_t.clear()
            held_a.clear()
            yield from self._check(time_s, accel_mps2)

    def _check(self, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64]) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        m = time_s.shape[0]
        nan = np.isnan(time_s) | np.isnan(accel_mps2).any(axis=1)
        far = ~(np.abs(time_s) <= MAX_TIME_S)
        # Steps into each row: from the previous chunk's last time into row 0.
        previous = np.float64(self.last_s) if self.last_s is not None else np.float64(math.nan)
        with np.errstate(invalid="ignore"):
            dt_s = np.diff(time_s, prepend=previous)
            back = dt_s <= 0.0  # False where a time is NaN, and for the very first row
        first_bad = _first(nan | far | back)
        step_known = self.reference_step_s is not None
        if not step_known:
            steps = dt_s[1:first_bad] if self.last_s is None else dt_s[:first_bad]
            if steps.size:
                self.reference_step_s = _median(steps[:REFERENCE_STEPS])
        gap_rows = np.zeros(0, np.intp)
        if self.reference_step_s is not None:
            step_s = self.reference_step_s
            with np.errstate(invalid="ignore"):
                short = dt_s < (1.0 - JITTER_TOLERANCE) * step_s  # False for NaN and the first row
                gap = dt_s > (1.0 + JITTER_TOLERANCE) * step_s
            first_bad = min(first_bad, _first(short & ~back))
            gap_rows = np.flatnonzero(gap[:first_bad])
        good_t, good_a = time_s[:first_bad], accel_mps2[:first_bad]
        if first_bad:
            beyond = (good_a < MIN_ACCEL_MPS2) | (good_a > MAX_ACCEL_MPS2)
            n_beyond = int(np.count_nonzero(beyond))
            if n_beyond:
                good_a = np.clip(good_a, MIN_ACCEL_MPS2, MAX_ACCEL_MPS2)
                self.reader.clipped_samples += n_beyond
            # The rows before a bad one are used: only the bad row stops the reading. A chunk
            # never spans a gap: each stretch between two is given on its own.
            gaps = set(gap_rows.tolist())
            bounds = [0, *sorted(gaps - {0}), first_bad]
            for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
                starts = lo in gaps or (self.last_s is None and lo == 0)
                if starts:
                    previous_s = float(time_s[lo - 1]) if lo else self.last_s
                    if previous_s is not None:
                        self._gap(previous_s, float(time_s[lo]))
                    self._new_segment(float(time_s[lo]))
                yield from self._on_grid(good_t[lo:hi], good_a[lo:hi], dt_s[lo:hi], continues=not starts)
        if first_bad < m:
            self._raise(first_bad, time_s, accel_mps2, dt_s, nan, far, back)
        self.rows += m
        self.last_s = float(time_s[-1])

    def _gap(self, before_s: float, after_s: float) -> None:
        reader = self.reader
        reader.gap_count += 1
        if len(reader.gaps) < MAX_LISTED_GAPS:
            step_s = self.reference_step_s or 0.0
            reader.gaps.append(Gap(before_s, after_s - before_s - step_s))

    def _new_segment(self, first_s: float) -> None:
        self._segment_s, self._given, self._last_row, self._resampling = first_s, 0, None, False

    def _on_grid(self, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], dt_s: NDArray[np.float64],
                 continues: bool) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:  # fmt: skip
        """A stretch of rows of one segment, as they are while their steps are the grid's (within
        TIME_STEP_TOLERANCE); from the first jittered step on, the segment's samples interpolated
        onto its grid (the rows before stand for its first grid points)."""
        step_s = self.reference_step_s
        if step_s is None:  # read through for a bad row: no grid
            yield time_s, accel_mps2
            return
        steps = dt_s if continues else dt_s[1:]  # a segment's first step is from before it
        with np.errstate(invalid="ignore"):
            deviation = float(np.max(np.abs(steps - step_s))) if steps.size else 0.0
        self.reader.max_jitter_s = max(self.reader.max_jitter_s, deviation)
        if not self._resampling and deviation <= TIME_STEP_TOLERANCE * step_s:
            self._given += time_s.shape[0]
            self._last_row = (float(time_s[-1]), accel_mps2[-1])
            yield time_s, accel_mps2
            return
        if not self._resampling and self._last_row is not None:
            # The grid continues from the last row given as it was: a logger's clock off the
            # whole hertz (up to 0.05 %) moves the rows a second an hour from the first row's grid.
            self._segment_s = self._last_row[0] - (self._given - 1) * step_s
        self._resampling = True
        if self._last_row is not None and continues:
            known_t = np.concatenate([[self._last_row[0]], time_s])
            known_a = np.concatenate([self._last_row[1][None, :], accel_mps2])
        else:
            known_t, known_a = time_s, accel_mps2
        # The grid points up to the last row (a point that rounding puts a hair past it included).
        last_k = int(np.floor((known_t[-1] - self._segment_s) / step_s + 1e-9))
        grid_t: NDArray[np.float64] = self._segment_s + np.arange(self._given, last_k + 1, dtype=np.float64) * step_s
        self._last_row = (float(time_s[-1]), accel_mps2[-1])
        if grid_t.size == 0:
            return
        grid_a: NDArray[np.float64] = np.column_stack([np.interp(grid_t, known_t, known_a[:, c]) for c in range(known_a.shape[1])])
        self._given += grid_t.size
        self.reader.resampled_samples += grid_t.size
        yield grid_t, grid_a

    def _raise(self, i: int, time_s: NDArray[np.float64], accel_mps2: NDArray[np.float64], dt_s: NDArray[np.float64],
               nan: NDArray[np.bool_], far: NDArray[np.bool_], back: NDArray[np.bool_]) -> NoReturn:  # fmt: skip
        reader, row = self.reader, self.rows + i
        if nan[i]:
            reader.row_error(row, "a value is NaN (no reading); remove or repair the row")
        if far[i]:
            reader.row_error(
                row,
                f"time_s {float(time_s[i])!r} is no plausible time (beyond +/-{MAX_TIME_S:.0f} s, the year 2100 as "
                "Unix time): time_s must be in seconds",
            )
        previous_s = float(time_s[i - 1]) if i > 0 else self.last_s
        if back[i]:
            reader.row_error(
                row, f"time_s {float(time_s[i])!r} does not increase (previous {previous_s!r}); rows must be in strictly increasing time"
            )
        step_s = self.reference_step_s
        assert step_s is not None
        reader.row_error(
            row,
            f"time step {float(dt_s[i]):.6g} s is shorter than the file's {step_s:.6g} s ({1.0 / step_s:.6g} Hz) by more "
            f"than its jitter ({JITTER_TOLERANCE:.0%}): a repeated or stray row, or samples at another rate; remove the row, "
            "or resample the recording to one rate",
        )


def _median(values: NDArray[np.float64]) -> float:
    """np.median of finite values, the same bits (the middle one, or the mean of the two middle
    ones), without the numpy.ma that np.median imports to check for masked arrays."""
    ordered = np.sort(values)
    middle = ordered.size // 2
    return float(ordered[middle] if ordered.size % 2 else (ordered[middle - 1] + ordered[middle]) / 2.0)


def _first(mask: NDArray[np.bool_]) -> int:
    """The index of the first True, or len(mask) if none."""
    i = int(np.argmax(mask)) if mask.size else 0
    return i if mask.size and mask[i] else mask.shape[0]

