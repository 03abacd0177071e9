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
from bogiemon.fleet.layout import CALIBRATION, FleetError, scan_fleet
from bogiemon.fleet.paths import place_of, shown
from bogiemon.fleet.windows_files import partition_path, partition_place, read_partition


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
    if fleet.url:
        raise FleetError(
            f"{fleet.url}: calibrate writes the wagon's calibration.toml beside its config, in a local FLEET: copy the "
            f"wagon's folder from the store, calibrate it there, and upload its calibration.toml"
        )
    wagon = fleet.wagon(wagon_id)
    target = wagon.folder / CALIBRATION
    place = place_of(target)
    if place not in ("missing", None):
        raise FleetError(f"{shown(target)}: {place} in the place of the calibration; remove it, then calibrate the wagon")
    if place is None and not force:
        raise FleetError(f"{shown(target)}: the wagon is commissioned already; pass --force to replace its calibration")
    if not Path(windows_dir).is_dir():
        raise FleetError(f"{shown(windows_dir)}: no such windows dataset (run `bogiemon fleet analyze` first)")
    # The days analysed: a partition file there (read and checked below; a damaged one is named).
    out_root = Path(windows_dir).resolve()
    partitions = [(d, p) for d in wagon.days if partition_place(p := partition_path(windows_dir, wagon.wagon_id, d.date), out_root) is None]
    if days:
        unknown = sorted(set(days) - {d.date for d, _ in partitions})
        if unknown:
            raise FleetError(f"{wagon_id}: no analysed windows for {shown(', '.join(unknown), 200)} (run `bogiemon fleet analyze` first)")
        chosen = [(d, p) for d, p in partitions if d.date in set(days)]
    else:
        chosen = partitions[: max(1, first_days)]
    if not chosen:
        raise FleetError(f"{wagon_id}: no analysed days in {shown(windows_dir)} (run `bogiemon fleet analyze` first)")
    windows: list[WindowIndicators] = []
    for day, path in chosen:
        windows += read_partition(path, day.midnight_s).windows()  # PartitionError: a FleetError naming it
    config = load_config(wagon.config_path, log_warnings=False)  # the wagon's own config, without the old calibration
    files = tuple(str(p) for _, p in chosen)
    result = calibrate_windows(windows, config, load, files=files)
    try:
        write_text_atomically(target, fragment(result))
    except OSError as exc:
        raise FleetError(f"{shown(target)}: cannot be written ({exc.strerror or exc})") from None
    return FleetCalibration(wagon_id, target, tuple(d.date for d, _ in chosen), result)
