"""Offline analysis of a recording: the streaming core run over a whole file, window by window.

A recording of samples or a CAN log of any format is opened as `replay` opens it (the replay
source, unpaced) and read as it is analysed, so memory stays flat for files of any length; the
windowing is the monitor's (a gap restarts the core); a bad row found on the way ends the
analysis with a RecordingError after the windows before it were given.
"""

from __future__ import annotations

import dataclasses
import queue
import threading
from collections.abc import Generator, Iterator
from pathlib import Path
from typing import Any, TypeVar

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.sources import open_replay_source, recording_settings
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.base import Block, EndOfStream, Source
from bogiemon.drivers.recording import Recording, RecordingReader, follows_gap

__all__ = ["ANALYSIS_BLOCK_S", "analyze_recording", "describe_source", "indicators_as_dict", "open_recording", "read_ahead", "recording_settings"]
from bogiemon.judgement.windowing import BlockWindows


# Blocks handed to the analysis at a time: its windows do not depend on them, and fewer calls cost less.
ANALYSIS_BLOCK_S = 10.0


def open_recording(path: str | Path, config: BogiemonConfig) -> Source:
    """Open a recording or a CAN log for analysis, as `replay` and `run` open it ([source]'s
    layout, DBC, mapping and unit; unpaced), and check the config can analyse it: its rate, and at
    least one window of a recording of samples (a bad row in a file too short is named first)."""
    source = open_replay_source(path, config, max_block_s=ANALYSIS_BLOCK_S)
    try:
        settings = recording_settings(path, source.fs_hz, config)
        reader = getattr(source, "reader", None)
        if isinstance(reader, RecordingReader):
            reader.require_samples(settings.window_n)
    except BaseException:
        source.close()
        raise
    return source


def describe_source(source: Source) -> str:
    """What a replay source reads, for a header line: '90000 samples at 500 Hz (180.0 s)' for a
    recording of samples, 'a candump -L log, decoded at 500 Hz' for a CAN log."""
    reader = getattr(source, "reader", None)
    if isinstance(reader, RecordingReader):
        return f"{reader.n_samples} samples at {reader.fs_hz:.6g} Hz ({reader.duration_s:.1f} s)"
    log_format = getattr(source, "format", None)
    words = getattr(log_format, "words", "a CAN log")
    return f"{words}, decoded at {source.fs_hz:.6g} Hz"


def analyze_recording(
    recording: Source | RecordingReader | Recording, config: BogiemonConfig, clip_level_mps2: float | None = None
) -> Iterator[WindowIndicators]:
    """The indicators of every full window of the recording, in time order, by the monitor's
    windowing rules (judgement/windowing.py): the core starts afresh at every gap.

    Clipped samples are counted at clip_level_mps2 (default: the config's health.clip_level_mps2).
    A source or a reader raises RecordingError at a bad row, after the windows that end before it.
    """
    path = getattr(recording, "path", "recording")
    clip = config.health.clip_level_mps2 if clip_level_mps2 is None else clip_level_mps2
    windows = BlockWindows(lambda fs_hz: recording_settings(path, fs_hz, config), config.bogie_geometry(), clip)
    for block in read_ahead(_blocks(recording)):
        for windowed in windows.feed(block):
            yield windowed.window


def _blocks(recording: Source | RecordingReader | Recording) -> Generator[Block, None, None]:
    """The blocks of a recording: a source's as it reads them, a reader's or a whole recording's
    chunks (uniform by their checks; none spans a gap), the first after a gap saying so."""
    if isinstance(recording, RecordingReader | Recording):
        previous_s: float | None = None
        for time_s, accel_mps2 in recording.chunks():
            if accel_mps2.shape[0]:
                gap = follows_gap(previous_s, float(time_s[0]), recording.fs_hz)
                yield Block(start_s=float(time_s[0]), fs_hz=recording.fs_hz, accel_mps2=accel_mps2, gap_before=gap)
                previous_s = float(time_s[-1])
        return
    try:
        while True:
            block = recording.read(1.0)
            if block is not None and block.n_samples:
                yield block
    except EndOfStream:
        return


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
