"""The slow tier: long property runs in full under `make test-slow`, a fast example of each in `make test`.

A test of the slow tier is marked `slow_tier` and takes its size from `sized(fast, full)`: `make
test` (and a plain pytest) runs the fast size, `make test-slow` runs only the marked tests, at the
full size (BOGIEMON_TEST_TIER=slow); `make test-all` runs both. The same test code runs in both:
only the count of generated examples (or the length of a run) differs, and each test says which
fast example stays in `make test`.
"""

from __future__ import annotations

import os
from typing import TypeVar

TIER_ENV = "BOGIEMON_TEST_TIER"
FULL = os.environ.get(TIER_ENV) == "slow"

T = TypeVar("T")


def sized(fast: T, full: T) -> T:
    """The full size under `make test-slow`, the fast one otherwise."""
    return full if FULL else fast
