"""Offline analysis of a recording: the streaming core run over a whole file, window by window."""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.detection import IndicatorStream, ProcessingSettings, WindowIndicators
from bogiemon.drivers.recording import Recording, RecordingError, read_csv_recording

# Feed the core a minute at a time: memory stays flat for recordings of any length.
CHUNK_S = 60.0


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


def open_recording(path: str | Path, config: BogiemonConfig) -> Recording:
    """Read a recording and check it holds at least one window at its own sample rate."""
    probe = read_csv_recording(path)
    settings = recording_settings(path, probe.fs_hz, config)
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
    settings = recording_settings(recording.path, recording.fs_hz, config)
    clip = config.health.clip_level_mps2 if clip_level_mps2 is None else clip_level_mps2
    stream = IndicatorStream(settings, config.bogie_geometry(), float(recording.time_s[0]), clip)
    chunk_n = max(1, int(CHUNK_S * recording.fs_hz))
    for i in range(0, recording.n_samples, chunk_n):
        yield from stream.process(recording.accel_mps2[i : i + chunk_n])


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
