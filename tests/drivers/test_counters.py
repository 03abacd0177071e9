"""The drivers' counters come from one table (drivers/counters.py): every name a driver keeps is in
it, and every row of it is kept by some driver."""

from __future__ import annotations

import pytest

from bogiemon.drivers.can_decode import CAN_COUNTERS
from bogiemon.drivers.counters import COUNTERS, counters
from bogiemon.drivers.live import LIVE_COUNTERS
from bogiemon.drivers.replay import RECORDING_COUNTERS
from bogiemon.drivers.replay_can import REPLAY_COUNTERS
from bogiemon.drivers.segments import TIMESTAMP_COUNTERS
from bogiemon.drivers.serial_source import SERIAL_COUNTERS

KEPT = (CAN_COUNTERS, LIVE_COUNTERS, RECORDING_COUNTERS, REPLAY_COUNTERS, TIMESTAMP_COUNTERS, SERIAL_COUNTERS)


def test_every_row_of_the_table_is_kept_by_a_driver_and_every_kept_name_is_a_row() -> None:
    kept = {name for names in KEPT for name in names}
    assert kept == set(COUNTERS)
    assert all(COUNTERS[name] for name in kept)


def test_a_counter_missing_from_the_table_is_refused() -> None:
    with pytest.raises(KeyError, match="not in drivers/counters.py's table"):
        counters("disconnects", "frames_eaten_by_gremlins")
