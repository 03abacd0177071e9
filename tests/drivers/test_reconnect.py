"""The one reconnection backoff (drivers/reconnect.py): doubling, its ceiling, jitter, reset, on a fake clock."""

from __future__ import annotations

import random

import pytest

from bogiemon.drivers.reconnect import Backoff


class FakeClock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


def test_the_waits_double_from_the_minimum_up_to_the_maximum() -> None:
    backoff = Backoff(0.5, 3.0, FakeClock())
    assert [backoff.failed() for _ in range(6)] == [0.5, 1.0, 2.0, 3.0, 3.0, 3.0]


def test_the_first_attempt_is_due_at_once_and_each_failure_schedules_the_next_on_the_clock() -> None:
    clock = FakeClock()
    backoff = Backoff(1.0, 8.0, clock)
    assert backoff.due_in_s() == 0.0
    assert backoff.failed() == 1.0 and backoff.due_in_s() == 1.0
    clock.now_s += 0.75
    assert backoff.due_in_s() == 0.25
    clock.now_s += 1.0
    assert backoff.due_in_s() == 0.0  # overdue is due, never negative
    assert backoff.failed() == 2.0 and backoff.due_in_s() == 2.0 and backoff.wait_s == 4.0


def test_reset_starts_the_doubling_again_from_the_minimum() -> None:
    backoff = Backoff(1.0, 8.0, FakeClock())
    for _ in range(4):
        backoff.failed()
    backoff.reset()
    assert backoff.wait_s == 1.0 and backoff.failed() == 1.0


def test_with_jitter_each_wait_is_drawn_between_half_and_all_of_the_doubling_wait() -> None:
    rng, reference = random.Random("318045331234"), random.Random("318045331234")
    backoff = Backoff(1.0, 8.0, FakeClock(), rng=rng)
    waits = [backoff.failed() for _ in range(6)]
    expected = [ceiling_s * (0.5 + 0.5 * reference.random()) for ceiling_s in (1.0, 2.0, 4.0, 8.0, 8.0, 8.0)]
    assert waits == expected  # the generator's draws, in order: reproducible from the seed
    assert all(c / 2 <= w <= c for w, c in zip(waits, (1.0, 2.0, 4.0, 8.0, 8.0, 8.0), strict=True))


def test_the_same_seed_gives_the_same_waits_and_another_seed_others() -> None:
    def waits(seed: str) -> list[float]:
        backoff = Backoff(1.0, 60.0, FakeClock(), rng=random.Random(seed))
        return [backoff.failed() for _ in range(8)]

    assert waits("wagon-a") == waits("wagon-a")
    assert waits("wagon-a") != waits("wagon-b")  # a fleet does not reconnect in step


def test_a_jittered_wait_is_what_the_clock_schedules() -> None:
    clock = FakeClock()
    backoff = Backoff(1.0, 8.0, clock, rng=random.Random(7))
    wait_s = backoff.failed()
    assert 0.5 <= wait_s < 1.0 and backoff.due_in_s() == pytest.approx(wait_s, abs=1e-12)


@pytest.mark.parametrize(("min_s", "max_s"), [(0.0, 1.0), (-1.0, 1.0), (2.0, 1.0)])
def test_a_backoff_needs_a_positive_minimum_not_above_the_maximum(min_s: float, max_s: float) -> None:
    with pytest.raises(ValueError, match=rf"backoff needs 0 < min_s <= max_s, got {min_s} and {max_s}"):
        Backoff(min_s, max_s)
