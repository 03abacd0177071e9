"""daemon/analysis.py's read-ahead: a recording's chunks produced in a thread of their own, in order,
errors raised where they fall, the producer stopped and closed when the consumer stops."""

from __future__ import annotations

import threading
from collections.abc import Generator

import pytest

from bogiemon.daemon.analysis import read_ahead


def numbers(n: int, fail_at: int | None = None, closed: list[bool] | None = None) -> Generator[int, None, None]:
    try:
        for i in range(n):
            if i == fail_at:
                raise ValueError(f"bad item {i}")
            yield i
    finally:
        if closed is not None:
            closed.append(True)


@pytest.mark.parametrize("depth", [1, 3])
def test_the_items_come_in_order_all_of_them(depth: int) -> None:
    assert list(read_ahead(numbers(1000), depth)) == list(range(1000))


def test_an_error_of_the_producer_is_raised_after_the_items_before_it() -> None:
    got: list[int] = []
    with pytest.raises(ValueError, match="bad item 7"):
        for item in read_ahead(numbers(100, fail_at=7)):
            got.append(item)
    assert got == list(range(7))


def test_a_consumer_stopping_early_stops_and_closes_the_producer() -> None:
    closed: list[bool] = []
    before = threading.active_count()
    items = read_ahead(numbers(10_000, closed=closed))
    assert [next(items) for _ in range(3)] == [0, 1, 2]
    items.close()
    assert closed == [True]
    assert threading.active_count() == before
