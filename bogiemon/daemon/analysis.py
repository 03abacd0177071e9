"""Offline analysis of a recording: the streaming core run over a whole file, window by window.

The recording is read as it is analysed (drivers/recording.py: a chunk of rows at a time), so
memory stays flat for recordings of any length; a bad row found on the way ends the analysis
with a RecordingError after the windows before it were given.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any, TypeVar

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.drivers.recording import Recording, RecordingError, RecordingReader, open_recording_reader, refuse_wagon


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


def open_recording(path: str | Path, config: BogiemonConfig, command: str = "analyze") -> RecordingReader:
    """Open a recording (CSV, .csv.gz, Parquet) and check the config can analyse it: one bogie's
    (a wagon's is refused, naming the command), its rate, and at least one window of it (a bad row
    in a file too short is named first)."""
    reader = open_recording_reader(path)
    refuse_wagon(path, reader.bogies, command)
    settings = recording_settings(path, reader.fs_hz, config)
    reader.require_samples(settings.window_n)
    return reader


def analyze_recording(
    recording: RecordingReader | Recording, config: BogiemonConfig, clip_level_mps2: float | None = None
) -> Iterator[WindowIndicators]:
    """The indicators of every full window of the recording, in time order.

    Clipped samples are counted at clip_level_mps2 (default: the config's health.clip_level_mps2).
    A RecordingReader raises RecordingError at a bad row, after the windows that end before it.
    """
    refuse_wagon(recording.path, recording.bogies, "analyze")  # the core takes one bogie's (n, 3)
    settings = recording_settings(recording.path, recording.fs_hz, config)
    clip = config.health.clip_level_mps2 if clip_level_mps2 is None else clip_level_mps2
    stream = IndicatorStream(settings, config.bogie_geometry(), recording.start_s, clip)
    for _, accel_mps2 in read_ahead(recording.chunks()):
        yield from stream.process(accel_mps2)


T = TypeVar("T")


def read_ahead(items: Generator[T, None, None], depth: int = 1) -> Generator[T, None, None]:
    """items, produced in a thread of their own up to `depth` ahead of the consumer: a recording's
    next chunk is read and parsed (pyarrow, without the GIL) while the core works on this one.
    What the producer raises is raised here, in order; stopping early stops and closes it."""
    ready: queue.Queue[tuple[T | None, BaseException | None, bool]] = queue.Queue(maxsize=depth)
    stop = threading.Event()

    def put(entry: tuple[T | None, BaseException | None, bool]) -> bool:
        while not stop.is_set():
            try:
                ready.put(entry, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def produce() -> None:
        try:
            for item in items:
                if not put((item, None, False)):
                    return
            put((None, None, True))
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, raised there
            put((None, exc, True))

    producer = threading.Thread(target=produce, name="bogiemon-read-ahead", daemon=True)
    producer.start()
    try:
        while True:
            item, error, done = ready.get()
            if error is not None:
                raise error
            if done:
                return
            yield item  # type: ignore[misc]
    finally:
        stop.set()
        producer.join()
        items.close()


def indicators_as_dict(ind: WindowIndicators) -> dict[str, Any]:
    """Every field of a window record (nested records as objects, tuples as lists), JSON-ready: the
    band spectra as their bands, powers and the real and imaginary parts of the cross-spectra."""
    out = dataclasses.asdict(dataclasses.replace(ind, spectra=None))
    if ind.spectra is not None:
        cross = ind.spectra.cross
        out["spectra"] = {
            "bands_hz": list(ind.spectra.bands_hz), "power": ind.spectra.power.tolist(),
            "cross_re": cross.real.tolist(), "cross_im": cross.imag.tolist(),
        }  # fmt: skip
    return out
