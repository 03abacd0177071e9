"""The fuzz harness's progress slot: the watchdog reads an input's start whole, or not at all."""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

from fuzz_progress import SLOT_SIZE, STARTED, ProgressSlot, Running  # noqa: E402


class Interleaved(list[float]):
    """Shared cells where another process writes between two of the reader's reads: `between` runs
    once, right after the `after`-th read."""

    def __init__(self, values: list[float], after: int, between: Callable[[ProgressSlot], None]) -> None:
        super().__init__(values)
        self.reads, self.after, self.between = 0, after, between
        self.writer = ProgressSlot(self)

    def __getitem__(self, i: int) -> float:  # type: ignore[override]  # list's overloads take slices too; only ints here
        value = super().__getitem__(i)
        self.reads += 1
        if self.reads == self.after:
            self.between(self.writer)
        return value


def test_a_begun_input_reads_back_with_its_own_start() -> None:
    slot = ProgressSlot([0.0] * SLOT_SIZE)
    slot.begin(478)
    running = slot.running()
    assert running is not None and running.index == 478 and running.started_s > 0.0
    assert slot.last_index() == 478


def test_an_idle_worker_runs_nothing_and_keeps_its_last_index() -> None:
    slot = ProgressSlot([0.0] * SLOT_SIZE)
    slot.begin(5)
    slot.idle()
    assert slot.running() is None
    assert slot.running_s(1e9) == 0.0
    assert slot.last_index() == 5


@pytest.mark.parametrize("after", range(1, 8))
def test_an_input_ending_between_two_reads_is_never_read_as_running_since_boot(after: int) -> None:
    # The CI failure: the watchdog saw a start, the worker cleared it, and the watchdog computed
    # now - 0, the machine's uptime, and killed a worker "hung for 5359 s". Whichever read the
    # worker's write falls between, the reader sees the input before or after it, never a mix.
    cells = [0.0] * SLOT_SIZE
    ProgressSlot(cells).begin(478)
    started_s = cells[STARTED]
    interleaved = Interleaved(cells, after, lambda writer: writer.idle())
    now_s = started_s + 2.0
    assert interleaved.writer.running_s(now_s) in (0.0, pytest.approx(2.0))


@pytest.mark.parametrize("after", range(1, 8))
def test_a_new_input_begun_between_two_reads_is_read_with_its_own_index(after: int) -> None:
    cells = [0.0] * SLOT_SIZE
    ProgressSlot(cells).begin(10)
    old = Running(10, cells[STARTED])
    interleaved = Interleaved(cells, after, lambda writer: writer.begin(11))
    running = interleaved.writer.running()
    assert running is not None
    assert running == old or (running.index == 11 and running.started_s >= old.started_s)


def test_a_slot_of_the_wrong_size_is_refused() -> None:
    with pytest.raises(ValueError, match="3 doubles"):
        ProgressSlot([0.0, 0.0])
