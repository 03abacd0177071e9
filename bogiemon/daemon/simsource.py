"""The simulated source: the bundled simulator driving the daemon over a virtual CAN bus.

For the demo and the end-to-end tests, where there is no bogie: at open it simulates the
scenario of [source] kind = "simulated", starts a player thread that puts the samples on a
python-can virtual channel as the sensor hub would (encoded with the DBC, `rate` times real
time), and reads them back with the real CanSource. The frames take the same decode path as on
the wagon; only the bus is in-process (python-can's virtual bus does not cross processes). The
frames carry the simulated hub's own clock (started at the wall clock when the player starts,
at `rate` times real time), as a real hub's frames carry the kernel's receive times: a player
thread that a busy machine stalls sends late, never with a silence in its stamps that the source
would read as a new segment. It ends (EndOfStream) once the player has sent the last frame and
the reader has drained the bus.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from bogiemon.drivers.base import Block, EndOfStream, HealthCounters, Source
from bogiemon.drivers.can_source import CanBusPort, CanSource
from bogiemon.drivers.candb import CanLayout, load_layout
from bogiemon.drivers.player import open_player_bus, play

if TYPE_CHECKING:
    from bogiemon.daemon.config import BogiemonConfig
    from bogiemon.simulator import Scenario


class SimulatedSource(Source):
    finite = False  # a live bus: the ring drops rather than waits, as on the wagon

    def __init__(
        self, scenario: Scenario, rate: float, channel: str, layout: str, dbc_path: str | None, max_block_s: float
    ) -> None:
        from bogiemon.simulator import simulate  # only this source needs the simulator

        result = simulate(scenario)
        self.scenario = scenario
        self.fs_hz = scenario.fs_hz
        can_layout = load_layout(dbc_path, layout)
        # The reader's bus must exist before the first frame: a virtual bus only delivers to
        # the buses open at sending time.
        self._reader = CanSource(CanBusPort("virtual", channel), can_layout, self.fs_hz, max_block_s=max_block_s)
        self.counters: HealthCounters = self._reader.counters
        self.player_error: BaseException | None = None
        self._stop = threading.Event()
        self._player_bus = open_player_bus("virtual", channel, stamped=True)
        self._player = threading.Thread(
            target=self._play, args=(can_layout, result.accel_mps2, rate), name="bogiemon-sim-player", daemon=True
        )
        self._player.start()

    def _play(self, layout: CanLayout, accel_mps2: NDArray[np.float64], rate: float) -> None:
        try:
            play(self._player_bus, layout, accel_mps2, self.fs_hz, rate=rate, stop=self._stop, stamp_start_s=time.time())
        except BaseException as exc:  # surfaced by read(): the daemon logs it and ends
            self.player_error = exc
        finally:
            self._player_bus.shutdown()

    # Read-only, the reader's passed on: Source declares a plain attribute, which only a source sets.
    @property
    def last_error(self) -> str | None:  # type: ignore[override]
        return self._reader.last_error

    def behind_s(self) -> float:
        return self._reader.behind_s()

    def read(self, timeout_s: float) -> Block | None:
        sent_all = not self._player.is_alive()  # checked first: nothing can arrive after it
        block = self._reader.read(timeout_s)
        if block is None and sent_all:
            if self.player_error is not None:
                raise RuntimeError(f"the simulated sensor hub failed: {self.player_error!r}")
            raise EndOfStream
        return block

    def close(self) -> None:
        self._stop.set()
        self._player.join(timeout=5)
        self._reader.close()


def open_simulated(config: BogiemonConfig) -> SimulatedSource:
    """The source for [source] kind = "simulated"; the sensors' corners and rate come from the config."""
    from bogiemon.daemon.config import SimulatedSourceConfig
    from bogiemon.simulator import Scenario, SpeedProfile, parse_fault

    src = config.source
    assert isinstance(src, SimulatedSourceConfig)
    scenario = Scenario(
        load=src.load,
        speed=SpeedProfile.constant(src.speed_kmh),
        track=src.track,
        duration_s=src.duration_s,
        seed=src.seed,
        faults=tuple(parse_fault(f) for f in src.faults),
        fault_onset_s=src.fault_at_s,
        fs_hz=config.processing.fs_hz,
        geometry=config.bogie_geometry(),
    )
    return SimulatedSource(scenario, src.rate, src.channel, src.layout, src.dbc_path or None, src.max_block_s)
