"""What the long commands (simulate, study, evaluate) share: a progress bar and the report folder check."""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path
from typing import TextIO


class ProgressBar:
    """A bar redrawn in place on a terminal; elsewhere a line every 10 %."""

    def __init__(self, stream: TextIO, label: str) -> None:
        self._stream, self._label, self._shown = stream, label, -1
        self._tty = stream.isatty()
        self._started = time.monotonic()

    def __call__(self, fraction: float) -> None:
        percent = int(fraction * 100)
        if percent == self._shown or (not self._tty and percent // 10 == self._shown // 10):
            return
        self._shown = percent
        elapsed_s = time.monotonic() - self._started
        eta = f", about {elapsed_s * (1 - fraction) / fraction / 60:.1f} min left" if fraction > 0.02 else ""
        if self._tty:
            filled = percent * 30 // 100
            self._stream.write(f"\r{self._label} [{'#' * filled}{'.' * (30 - filled)}] {percent:3d}%{eta}   ")
        else:
            self._stream.write(f"{self._label}: {percent}%{eta}\n")
        self._stream.flush()

    def close(self) -> None:
        if self._tty and self._shown >= 0:
            self._stream.write("\n")
            self._stream.flush()


def check_report_folder(out: Path, figures: bool, error: type[Exception]) -> None:
    """Raise `error` with one line saying what to do when a report cannot go to `out`."""
    if out.exists() and not out.is_dir():
        raise error(f"{out}: exists and is not a folder: choose a folder for the report with -o")
    if not out.resolve().parent.is_dir():
        raise error(f"{out}: its parent folder does not exist: create it or choose another -o")
    if figures and importlib.util.find_spec("matplotlib") is None:
        raise error("the figures need matplotlib: install bogiemon's 'report' extra (pip install 'bogiemon[report]') or pass --no-figures")
