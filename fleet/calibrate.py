"""`bogiemon fleet calibrate WAGON`: commission a wagon from its own uploaded days.

The windows of the chosen days (default: the wagon's first analysed day) go through the same
calibration as `bogiemon calibrate` (daemon/calibrate.py: only windows the daemon would judge,
per load state as estimated, at least its minimum of windows per load); the fragment is written
as the wagon's calibration.toml, which the fleet merges over its config (docs/fleet-formats.md).
The days must be healthy running: a fault present then becomes the wagon's normal. The
fleet-relative evidence (fleet/evidence.py) is what catches such a wagon: its baseline stands
out of its sisters'.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from bogiemon.daemon.calibrate import CalibrationResult, calibrate_windows, fragment
from bogiemon.daemon.config import load_config
from bogiemon.detection import WindowIndicators
from bogiemon.drivers.atomic import write_text_atomically
from bogiemon.fleet import rows
from bogiemon.fleet.analyze import read_partition, wagon_partitions
from bogiemon.fleet.layout import CALIBRATION, FleetError, scan_fleet


@dataclass(frozen=True)
class FleetCalibration:
    wagon_id: str
    path: Path
    days: tuple[str, ...]
    result: CalibrationResult


def calibrate_wagon(
    fleet_root: str | Path,
    windows_dir: str | Path,
    wagon_id: str,
    days: Sequence[str] = (),
    first_days: int = 1,
    force: bool = False,
    load: str = "auto",
) -> FleetCalibration:
    """Write FLEET/<wagon>/calibration.toml from the wagon's analysed days; CalibrationError if too few windows."""
    fleet = scan_fleet(fleet_root)
    wagon = fleet.wagon(wagon_id)
    target = wagon.folder / CALIBRATION
    if target.exists() and not force:
        raise FleetError(f"{target}: the wagon is commissioned already; pass --force to replace its calibration")
    partitions = wagon_partitions(windows_dir, wagon)
    if days:
        unknown = sorted(set(days) - {d.date for d, _ in partitions})
        if unknown:
            raise FleetError(f"{wagon_id}: no analysed windows for {', '.join(unknown)} (run `bogiemon fleet analyze` first)")
        chosen = [(d, p) for d, p in partitions if d.date in set(days)]
    else:
        chosen = partitions[: max(1, first_days)]
    if not chosen:
        raise FleetError(f"{wagon_id}: no analysed days in {windows_dir} (run `bogiemon fleet analyze` first)")
    windows: list[WindowIndicators] = []
    for _, path in chosen:
        try:
            table, _ = read_partition(path)
        except ValueError as exc:
            raise FleetError(f"{path}: {exc}") from None
        windows += rows.from_table(table)
    config = load_config(wagon.config_path, log_warnings=False)  # the wagon's own config, without the old calibration
    files = tuple(str(p) for _, p in chosen)
    result = calibrate_windows(windows, config, load, files=files)
    write_text_atomically(target, fragment(result))
    return FleetCalibration(wagon_id, target, tuple(d.date for d, _ in chosen), result)
