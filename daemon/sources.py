"""The source the config asks for: `open_source(config)` builds the driver from [source].

The drivers take plain arguments; this is the one place that reads their settings from the
config tree (drivers/ never imports daemon/). The sample rate of the live sources is the
configured processing.fs_hz; a CSV replay brings its own.
"""

from __future__ import annotations

from bogiemon.daemon.config import (
    BogiemonConfig,
    CanSourceConfig,
    ReplaySourceConfig,
    SerialSourceConfig,
    SimulatedSourceConfig,
)
from bogiemon.drivers.base import Source
from bogiemon.drivers.can_source import BusPort, CanSource, SocketcanBusPort, VirtualBusPort
from bogiemon.drivers.candb import load_layout
from bogiemon.drivers.replay import open_replay
from bogiemon.drivers.serial_source import SerialSource


def open_source(config: BogiemonConfig) -> Source:
    """The configured source, its device opened if present (a live source retries if not).

    Raises DbcError or RecordingError (user errors) for a bad DBC or an unreadable recording.
    """
    src = config.source
    fs_hz = config.processing.fs_hz
    if isinstance(src, CanSourceConfig):
        port: BusPort
        if src.interface == "socketcan":
            port = SocketcanBusPort(src.channel, src.receive_buffer_bytes)
        else:
            port = VirtualBusPort(src.channel)
        return CanSource(
            port,
            load_layout(src.dbc_path or None, src.layout),
            fs_hz,
            max_block_s=src.max_block_s,
            backoff_min_s=src.reconnect_backoff_min_s,
            backoff_max_s=src.reconnect_backoff_max_s,
        )
    if isinstance(src, SerialSourceConfig):
        return SerialSource(
            src.port,
            src.baudrate,
            fs_hz,
            max_block_s=src.max_block_s,
            backoff_min_s=src.reconnect_backoff_min_s,
            backoff_max_s=src.reconnect_backoff_max_s,
        )
    if isinstance(src, SimulatedSourceConfig):
        from bogiemon.daemon.simsource import open_simulated  # the simulator, only for this kind

        return open_simulated(config)
    assert isinstance(src, ReplaySourceConfig)
    is_csv = src.path.lower().endswith(".csv")
    layout = None if is_csv else load_layout(src.dbc_path or None, src.layout)
    return open_replay(src.path, rate=1.0 if src.realtime else 0.0, layout=layout, fs_hz=fs_hz, max_block_s=src.max_block_s)
