"""Tiny fleets for the hostile-input tests: seconds of seeded noise, windows of 20 s, no simulator.

What these tests check is what the back office does with the files, not what it finds in them:
a wagon judged by thresholds on 20-s windows analyses a 45-s recording in a few milliseconds.
"""

from __future__ import annotations

import datetime as dt
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from bogiemon.drivers.recording import write_csv_recording
from bogiemon.fleet.analyze import AnalyzeSummary, analyze_fleet
from bogiemon.fleet.cluster import InProcess

CONFIG = """\
[decision]
load = "full"
method = "thresholds"
[processing]
window_s = 20.0
hop_s = 10.0
max_lag_s = 2.0
"""
FS_HZ = 200.0
DAYS = ("2026-11-02", "2026-11-03")


def recording(path: Path, date: str | None, hhmm: str = "06:00", duration_s: float = 45.0, seed: int = 0) -> Path:
    """Seeded noise from date hhmm UTC, as the recorder writes it (Unix times); from the
    recording's own origin (0 s, as a simulator writes it) when date is None."""
    start_s = 0.0 if date is None else dt.datetime.strptime(f"{date} {hhmm}", "%Y-%m-%d %H:%M").replace(tzinfo=dt.UTC).timestamp()
    n = int(duration_s * FS_HZ)
    rng = np.random.default_rng(seed)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_csv_recording(path, start_s + np.arange(n) / FS_HZ, rng.normal(0.0, 1.0, (n, 3)))
    return path


def fleet(root: Path, wagons: tuple[str, ...] = ("W1", "W2"), days: tuple[str, ...] = DAYS) -> Path:
    """Wagons of one 45-s recording a day each; returns root."""
    for w, wagon in enumerate(wagons):
        (root / wagon).mkdir(parents=True, exist_ok=True)
        (root / wagon / "bogiemon.toml").write_text(CONFIG, encoding="utf-8")
        for d, day in enumerate(days):
            recording(root / wagon / day / "060000_run.csv.gz", day, "06:00", seed=10 * w + d)
    return root


def analyze(root: Path, out: Path, **kwargs: object) -> AnalyzeSummary:
    """`fleet analyze` with its tasks in this process (no Dask: the files are what is tested)."""
    return analyze_fleet(root, out, runner=InProcess(), **kwargs)  # type: ignore[arg-type]


def without_blocking(call: Callable[[], object], limit_s: float = 20.0) -> BaseException | None:
    """What call raised (None if nothing), failing the test if it is still running after limit_s."""
    outcome: list[BaseException | None] = []

    def run() -> None:
        try:
            call()
        except BaseException as exc:  # noqa: BLE001 - handed to the test
            outcome.append(exc)
        else:
            outcome.append(None)

    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(limit_s)
    assert not worker.is_alive(), f"still running after {limit_s:g} s: it blocks"
    return outcome[0]
