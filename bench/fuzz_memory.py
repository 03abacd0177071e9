"""The fuzz targets' peak resident memory: how much one input adds while it is read (PeakRss), its
figure kept for the report (record_figure), and the verdict on an input past a target's bound."""

from __future__ import annotations

import ctypes
import functools
import gc
import re
from pathlib import Path
from typing import Any

import pyarrow as pa

import fuzz_core


def _status_kib(name: str) -> int:
    text = Path("/proc/self/status").read_text()
    found = re.search(rf"^{name}:\s+(\d+) kB", text, re.M)
    return int(found.group(1)) if found else 0


class PeakRss:
    """The peak resident memory a stretch of code adds (VmHWM reset through /proc/self/clear_refs),
    after what the allocators keep was given back; `mib` is None where the kernel cannot reset it."""

    def __enter__(self) -> PeakRss:
        gc.collect()
        pa.default_memory_pool().release_unused()
        _trim()
        self.before_kib = _status_kib("VmRSS")
        try:
            Path("/proc/self/clear_refs").write_text("5")
            self.resettable = True
        except OSError:
            self.resettable = False
        self.mib: float | None = None
        return self

    def __exit__(self, *_exc: object) -> None:
        if self.resettable:
            self.mib = max(0, _status_kib("VmHWM") - self.before_kib) / 1024


@functools.cache
def _libc() -> Any:
    try:
        return ctypes.CDLL("libc.so.6")
    except OSError:
        return None


def _trim() -> None:
    libc = _libc()
    if libc is not None and hasattr(libc, "malloc_trim"):
        libc.malloc_trim(0)


def record_figure(ctx: fuzz_core.Context, name: str, value: float) -> None:
    """A figure of this input for the report (bench/fuzz.py keeps each one's largest and its input)."""
    figures = getattr(ctx, "figures", None)
    if figures is not None:
        figures[name] = value


def memory_verdict(ctx: fuzz_core.Context, peak: PeakRss, bound_mib: float) -> str | None:
    """The input's peak kept as a figure, and why it is a finding when it passed bound_mib (None: not)."""
    if peak.mib is None:
        return None
    record_figure(ctx, "peak RSS MiB", peak.mib)
    if peak.mib > bound_mib:
        return f"memory beyond the bound: reading it took {peak.mib:.0f} MiB at its peak, more than {bound_mib:g} MiB"
    return None
