"""The source the config asks for: `open_source(config)` builds the driver from [source];
`open_service_source(config)` reads it on the [duty] cycle (daemon/duty.py), as `run` does.

The drivers take plain arguments; this is the one place that reads their settings from the
config tree (drivers/ never imports daemon/). Each [source] kind (a model of daemon/config.py)
has one opener in OPENERS. The sample rate of the live sources is the configured
processing.fs_hz; a CSV replay brings its own.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bogiemon.daemon.config import (
    BogiemonConfig,
    CanSourceConfig,
    ReplaySourceConfig,
    SerialSourceConfig,
    SimulatedSourceConfig,
)
from bogiemon.detection import ProcessingSettings
from bogiemon.drivers.base import Source
from bogiemon.drivers.recording import RecordingError
from bogiemon.drivers.replay import RecordingReplaySource, open_replay
from bogiemon.drivers.serial_source import SerialSource

def recording_settings(path: str | Path, fs_hz: float, config: BogiemonConfig) -> ProcessingSettings:
    """The detection core's settings at a recording's own rate.

    RecordingError, naming the file, its rate and what of [processing] does not fit, where the
    core cannot run the config at that rate (a 10 Hz recording and the 10 Hz low-pass, windows
    that are no whole number of hops at 333.33 Hz, a rate of 0.01 Hz).
    """
    try:
        return config.processing_settings(fs_hz=fs_hz)
    except ValueError as exc:  # ConfigError, or the core's own check (ProcessingSettings)
        raise RecordingError(
            f"{path}: recorded at {fs_hz:.6g} Hz, a rate the config's [processing] cannot run at: {exc}; "
            f"resample the recording, or use a config whose [processing] suits {fs_hz:.6g} Hz"
        ) from None


if TYPE_CHECKING:  # cantools and python-can load with a CAN source or log only
    from bogiemon.drivers.candb import CanLayout


# An opener takes its own [source] model (the first argument) and the whole config.
Opener = Callable[[Any, BogiemonConfig], Source]


def _open_can(src: CanSourceConfig, config: BogiemonConfig) -> Source:
    from bogiemon.drivers.can_source import CanBusPort, CanSource  # python-can, for a CAN source only
    from bogiemon.drivers.candb import load_layout

    return CanSource(
        CanBusPort(src.interface, src.channel, src.receive_buffer_bytes),
        load_layout(src.dbc_path or None, src.layout),
        config.processing.fs_hz,
        max_block_s=src.max_block_s,
        backoff_min_s=src.reconnect_backoff_min_s,
        backoff_max_s=src.reconnect_backoff_max_s,
    )


def _open_serial(src: SerialSourceConfig, config: BogiemonConfig) -> Source:
    return SerialSource(
        src.port,
        src.baudrate,
        config.processing.fs_hz,
        max_block_s=src.max_block_s,
        backoff_min_s=src.reconnect_backoff_min_s,
        backoff_max_s=src.reconnect_backoff_max_s,
    )


def _open_simulated(src: SimulatedSourceConfig, config: BogiemonConfig) -> Source:
    from bogiemon.daemon.simsource import open_simulated  # the simulator, only for this kind

    return open_simulated(config)


def _open_replay(src: ReplaySourceConfig, config: BogiemonConfig) -> Source:
    def layout() -> CanLayout:  # read only for a CAN log
        from bogiemon.drivers.candb import load_layout

        return load_layout(src.dbc_path or None, src.layout)

    source = open_replay(
        src.path, rate=1.0 if src.realtime else 0.0, layout=layout, fs_hz=config.processing.fs_hz, max_block_s=src.max_block_s,
        columns=src.column_map(),
    )  # fmt: skip
    if isinstance(source, RecordingReplaySource):  # a recording brings its own rate: one the config cannot run at is refused here, in one line
        try:
            recording_settings(src.path, source.fs_hz, config)
        except RecordingError:
            source.close()
            raise
    return source


OPENERS: Mapping[type, Opener] = {
    CanSourceConfig: _open_can,
    SerialSourceConfig: _open_serial,
    SimulatedSourceConfig: _open_simulated,
    ReplaySourceConfig: _open_replay,
}


def replay_source_config(path: str | Path, config: BogiemonConfig, realtime: bool = False, max_block_s: float | None = None) -> ReplaySourceConfig:
    """The [source] of a replay of path: the config's layout, DBC and block length (or max_block_s),
    whatever its kind. What `run` would use if [source] named this file; a serial source has no CAN
    settings and leaves the defaults (the hub layout, the shipped DBC)."""
    src = config.source
    settings: dict[str, Any] = {"max_block_s": src.max_block_s if max_block_s is None else max_block_s}
    if isinstance(src, CanSourceConfig | ReplaySourceConfig | SimulatedSourceConfig):
        settings.update(layout=src.layout, dbc_path=src.dbc_path)
    if isinstance(src, ReplaySourceConfig):
        settings.update(unit=src.unit, columns=src.columns)
    return ReplaySourceConfig(kind="replay", path=str(path), realtime=realtime, **settings)


def open_replay_source(path: str | Path, config: BogiemonConfig, realtime: bool = False, max_block_s: float | None = None) -> Source:
    """A recording opened as the daemon opens `[source] kind = "replay"` of it (replay_source_config):
    `bogiemon replay` and `fleet analyze` read recordings this way."""
    return open_source(config.model_copy(update={"source": replay_source_config(path, config, realtime, max_block_s)}))


def open_source(config: BogiemonConfig) -> Source:
    """The configured source, its device opened if present (a live source retries if not).

    Raises DbcError or RecordingError (user errors) for a bad DBC or an unreadable recording.
    """
    src = config.source
    opener = OPENERS.get(type(src))
    if opener is None:  # the config accepted a kind this table lacks: a bug, not a user error
        raise TypeError(f"[source] kind {getattr(src, 'kind', '?')!r} ({type(src).__name__}) has no opener in daemon/sources.py OPENERS")
    return opener(src, config)


def duty_cycled(source: Source, config: BogiemonConfig) -> Source:
    """source read on the config's [duty] cycle (daemon/duty.py); source itself when [duty] is off."""
    settings = config.duty_settings()
    if settings is None:
        return source
    from bogiemon.daemon.duty import DutySource  # only with a duty cycle

    return DutySource(source, settings)


def open_service_source(config: BogiemonConfig) -> Source:
    """What `bogiemon run` reads: the configured source (open_source), on the [duty] cycle."""
    return duty_cycled(open_source(config), config)
