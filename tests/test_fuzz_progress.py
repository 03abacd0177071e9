"""The fuzz harness's progress slot: the watchdog reads an input's start whole, or not at all."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "bench"))

import fuzz_core  # noqa: E402
from fuzz import run_input  # noqa: E402
from fuzz_progress import _TICK_S as TICK_S  # noqa: E402
from fuzz_progress import SLOT_SIZE, STARTED, STARTED_CPU, WALL_FACTOR, ProgressSlot, Running, cpu_time_s, install_alarms, stuck  # noqa: E402


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


@pytest.mark.parametrize("after", range(1, 10))
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


@pytest.mark.parametrize("after", range(1, 10))
def test_a_new_input_begun_between_two_reads_is_read_with_its_own_index(after: int) -> None:
    cells = [0.0] * SLOT_SIZE
    ProgressSlot(cells).begin(10)
    old = Running(10, cells[STARTED], cells[STARTED_CPU])
    interleaved = Interleaved(cells, after, lambda writer: writer.begin(11))
    running = interleaved.writer.running()
    assert running is not None
    assert running == old or (running.index == 11 and running.started_s >= old.started_s and running.started_cpu_s >= old.started_cpu_s)


def test_a_slot_of_the_wrong_size_is_refused() -> None:
    with pytest.raises(ValueError, match="4 doubles"):
        ProgressSlot([0.0, 0.0])


def test_the_slot_says_the_cpu_time_an_input_took_as_the_watchdog_reads_it_from_proc() -> None:
    slot = ProgressSlot([0.0] * SLOT_SIZE)
    slot.begin(7)
    began = time.process_time()
    while time.process_time() - began < 0.2:
        pass  # 0.2 s of this process's CPU
    wall_s, cpu_s = slot.took(time.monotonic(), cpu_time_s(os.getpid()))
    assert cpu_s is not None and 0.2 - 2 * TICK_S <= cpu_s <= wall_s + 2 * TICK_S
    slot.idle()
    assert slot.took(time.monotonic(), cpu_time_s(os.getpid())) == (0.0, 0.0)


def test_a_worker_slowed_by_a_busy_machine_is_not_stuck_whatever_its_wall_time() -> None:
    # Under `make test` the quick run's workers share two cores with a dozen other processes: an
    # input's wall time is many times its CPU time. Only its CPU time, or a wait on nothing for
    # WALL_FACTOR times the limit, makes it a hang.
    hard_limit_s = 14.0
    assert stuck(100.0, 1.5, hard_limit_s) is None
    assert stuck(100.0, 15.0, hard_limit_s) == "killed after 15 s of CPU in one input"
    assert stuck(WALL_FACTOR * hard_limit_s + 1, 0.0, hard_limit_s) == "killed after 141 s in one input, 0 s of CPU"
    assert stuck(hard_limit_s + 1, None, hard_limit_s) is not None  # no /proc: the wall clock alone


@pytest.fixture
def alarms() -> Iterator[None]:
    saved = {signum: signal.getsignal(signum) for signum in (signal.SIGALRM, signal.SIGPROF)}
    install_alarms()
    yield
    for signum, handler in saved.items():
        signal.signal(signum, handler)


def _target(run: Callable[[fuzz_core.Input, fuzz_core.Context], fuzz_core.Verdict]) -> fuzz_core.Target:
    return fuzz_core.Target("test", lambda rng: {}, run)


def test_an_input_that_waits_past_its_cpu_limit_without_using_the_cpu_is_no_hang(alarms: None, tmp_path: Path) -> None:
    def wait(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
        time.sleep(0.3)  # three times the CPU limit, a third of the wall clock's
        return None

    outcome = run_input(_target(wait), {}, fuzz_core.Context(tmp_path), (), limit_s=0.1)
    assert outcome.kind == "ok"


def spin(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    while True:
        pass


def test_an_input_that_spins_is_a_hang_at_its_site(alarms: None, tmp_path: Path) -> None:
    outcome = run_input(_target(spin), {}, fuzz_core.Context(tmp_path), (), limit_s=0.1)
    assert outcome.kind == "hang" and outcome.exception == "InputTimeout" and outcome.site.endswith("in spin")


def block(data: fuzz_core.Input, ctx: fuzz_core.Context) -> fuzz_core.Verdict:
    threading.Event().wait()  # for an event nobody sets: a deadlock
    return None


def test_an_input_blocked_on_nothing_is_a_hang_on_the_wall_clock(alarms: None, tmp_path: Path) -> None:
    outcome = run_input(_target(block), {}, fuzz_core.Context(tmp_path), (), limit_s=0.05)
    assert outcome.kind == "hang" and outcome.message == f"blocked past {WALL_FACTOR * 0.05:g} s of wall time"
