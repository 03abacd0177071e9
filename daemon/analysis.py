"""Offline analysis of a recording: the streaming core run over a whole file, window by window."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import IndicatorStream, WindowIndicators
from bogiemon.drivers.recording import Recording, read_csv_recording

# Feed the core a minute at a time: memory stays flat for recordings of any length.
CHUNK_S = 60.0


def open_recording(path: str | Path, config: BogiemonConfig) -> Recording:
    """Read a recording and check it holds at least one window at its own sample rate."""
    probe = read_csv_recording(path)
    settings = config.processing_settings(fs_hz=probe.fs_hz)
    if probe.n_samples < settings.window_n:
        # Re-read through the checked path so the message is the recording module's own.
        return read_csv_recording(path, min_samples=settings.window_n)
    return probe


def analyze_recording(
    recording: Recording, config: BogiemonConfig, clip_level_mps2: float | None = None
) -> Iterator[WindowIndicators]:
    """The indicators of every full window of the recording, in time order.

    Clipped samples are counted at clip_level_mps2 (default: the config's health.clip_level_mps2).
    """
    settings = config.processing_settings(fs_hz=recording.fs_hz)
    clip = config.health.clip_level_mps2 if clip_level_mps2 is None else clip_level_mps2
    stream = IndicatorStream(settings, config.bogie_geometry(), float(recording.time_s[0]), clip)
    chunk_n = max(1, int(CHUNK_S * recording.fs_hz))
    for i in range(0, recording.n_samples, chunk_n):
        yield from stream.process(recording.accel_mps2[i : i + chunk_n])


def indicators_as_dict(ind: WindowIndicators) -> dict[str, Any]:
    """Every field of a window record (nested records as objects, tuples as lists), JSON-ready."""
    return dataclasses.asdict(ind)
