"""The reading of a recording whatever its format: RecordingReader, the base of the CSV and the
Parquet readers (the survey's checks of the whole file, the chunks, the whole recording in memory),
and the checks of every row in file order (NaN, a time not plausible, not increasing or off the
file's step; a sample beyond the converter's range clipped and counted)."""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import NoReturn

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import MAX_TIME_S
from bogiemon.drivers.files import UntrustedFile
from bogiemon.drivers.recording_format import COLUMNS, MAX_ACCEL_MPS2, MIN_ACCEL_MPS2, Recording, RecordingError

# A time step may deviate this much (relative) from the file's step: enough for times printed
# with 6 decimals at 1 kHz, far less than the 100 % of one lost sample.
TIME_STEP_TOLERANCE = 0.01
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
    columns: tuple[str, ...] = COLUMNS  # its column set, found at the open: COLUMNS or a wagon's WAGON_COLUMNS
    n_samples: int
    start_s: float  # the time of the first sample
    last_s: float  # the time of the last sample
    fs_hz: float

    def __init__(self, file: UntrustedFile) -> None:
        self.file = file
        self.path = file.path
        self.clipped_samples = 0  # of the last pass of chunks(), so far

    def close(self) -> None:
        """Release the file (a pass still reading holds a descriptor of its own until it ends)."""
        self.file.close()

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.fs_hz

    @property
    def bogies(self) -> int:
        """The bogies it holds: 1, or 2 for a wagon's recording (time_s,a1,a2,a3,b1,b2,b3)."""
        return (len(self.columns) - 1) // 3

    @abstractmethod
    def open(self, min_samples: int) -> None:
        """Survey the file and refuse what concerns the whole of it (_check_whole)."""

    @abstractmethod
    def _raw_chunks(self) -> Iterator[tuple[NDArray[np.float64], NDArray[np.float64]]]:
        """The file's rows as arrays, unchecked, in order; RecordingError for what cannot be parsed."""

    @abstractmethod
    def where(self, row: int) -> str:
        """Where data row `row` (from 0) is in the file, for a message: 'line 1873', 'row 1872'."""

    def error(self, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {problem}")

    def row_error(self, row: int, problem: str) -> NoReturn:
        raise RecordingError(f"{self.path}: {self.where(row)}: {problem}")

    def chunks(self) -> Generator[tuple[NDArray[np.float64], NDArray[np.float64]], None, None]:
        checker = _RowChecker(self)
        self.clipped_samples = 0
        yield from checker.checked(self._raw_chunks())
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
            self.start_s, self.last_s, self.fs_hz = float(first_s), float(last_s), fs_hz  # type: ignore[arg-type]
            return
        # The rows are read through for a bad one; the survey's own values do not judge them.
        self.start_s = self.last_s = math.nan
        self.fs_hz = fs_hz
        checker = _RowChecker(self)
        for _ in checker.checked(self._raw_chunks()):
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

    def require_samples(self, min_samples: int) -> None:
        """Refuse a recording shorter than min_samples (e.g. one analysis window), after naming a bad row."""
        if self.n_samples < min_samples:
            self._check_whole(min_samples, self.start_s, self.last_s)


class _RowChecker:
    """The checks of every row, in file order, carried from chunk to chunk: NaN, a time that is
    not plausible, not increasing or off the file's step; and the clipping of the samples."""

    def __init__(self, reader: RecordingReader) -> None:
        self.reader = reader
        self.rows = 0  # rows checked
        self.last_s: float | None = None
        self.reference_step_s: float | None = None

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
        if self.reference_step_s is not None:
            step_s = self.reference_step_s
            with np.errstate(invalid="ignore"):
                off = np.abs(dt_s - step_s) > TIME_STEP_TOLERANCE * step_s
            first_bad = min(first_bad, _first(off))
            if not step_known and self._off_the_rate(step_s):
                # The rows' step is not the rate the reader was opened with (first to last time):
                # a gap further in. No row is given, as every one would be used at the wrong rate.
                if first_bad < m:
                    self._raise(first_bad, time_s, accel_mps2, dt_s, nan, far, back)
                self.reader.error(
                    f"its first time steps of {step_s:.6g} s ({1.0 / step_s:.6g} Hz) are not its rate from the first to the last "
                    f"time ({self.reader.fs_hz:.6g} Hz): a gap or a jump further in; recordings must be uniformly sampled: "
                    "split the file at the gap"
                )
        good_t, good_a = time_s[:first_bad], accel_mps2[:first_bad]
        if first_bad:
            beyond = (good_a < MIN_ACCEL_MPS2) | (good_a > MAX_ACCEL_MPS2)
            n_beyond = int(np.count_nonzero(beyond))
            if n_beyond:
                good_a = np.clip(good_a, MIN_ACCEL_MPS2, MAX_ACCEL_MPS2)
                self.reader.clipped_samples += n_beyond
            yield good_t, good_a  # the rows before a bad one are used: only the bad row stops the reading
        if first_bad < m:
            self._raise(first_bad, time_s, accel_mps2, dt_s, nan, far, back)
        self.rows += m
        self.last_s = float(time_s[-1])

    def _off_the_rate(self, step_s: float) -> bool:
        """Whether the file's step disagrees with the rate its reader announced (its survey's, when there was one)."""
        fs_hz = self.reader.fs_hz
        if math.isnan(self.reader.start_s) or not (math.isfinite(fs_hz) and fs_hz > 0):
            return False  # _check_whole reads the rows through for a bad one: no rate is announced
        return abs(1.0 / fs_hz - step_s) > TIME_STEP_TOLERANCE * step_s

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
            f"time step {float(dt_s[i]):.6g} s differs from the file's {step_s:.6g} s ({1.0 / step_s:.6g} Hz); "
            "recordings must be uniformly sampled: split the file at the gap",
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

