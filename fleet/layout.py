"""The recordings tree of a fleet (docs/fleet-formats.md, section 1): wagons, their configs, their days.

Scanning only lists and stats files and loads each wagon's config: what a recording holds is read
by the analysis. What cannot be used is an Issue (named, counted, skipped), never a stop: one
wagon's broken config or a stray file must not hold up a thousand other wagons. Only a fleet.toml
that does not parse is a FleetError, since it describes the whole fleet.
"""

from __future__ import annotations

import datetime as dt
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig, ConfigError, load_config
from bogiemon.drivers.recording import is_sample_recording_name

FLEET_FILE = "fleet.toml"
WAGON_CONFIG = "bogiemon.toml"
CALIBRATION = "calibration.toml"
DEFAULT_TYPE = "unspecified"
WAGON_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
DAY = re.compile(r"^\d{4}-\d{2}-\d{2}$")
CAN_LOG_SUFFIXES = (".asc", ".blf", ".log", ".trc")
IGNORED_SUFFIXES = (".json",)  # the simulator's sidecars and truth: what was simulated, not recordings


class FleetError(ValueError):
    """The fleet as a whole cannot be used (no such folder, a fleet.toml that does not parse)."""


@dataclass(frozen=True)
class Issue:
    """Something in the tree that is skipped: what and why, in one line."""

    path: str
    reason: str

    def as_dict(self) -> dict[str, str]:
        return {"path": self.path, "reason": self.reason}


@dataclass(frozen=True)
class InputFile:
    """A recording as found: its name, size and modification time identify its contents."""

    path: Path
    size_bytes: int
    mtime_ns: int

    @property
    def key(self) -> tuple[str, int, int]:
        return (self.path.name, self.size_bytes, self.mtime_ns)

    @property
    def is_samples(self) -> bool:
        """A recording of samples (CSV or Parquet), not a CAN log."""
        return recording_kind(self.path.name) == "samples"


@dataclass(frozen=True)
class Day:
    date: str  # YYYY-MM-DD, UTC
    files: tuple[InputFile, ...]

    @property
    def midnight_s(self) -> float:
        return day_start_s(self.date)


@dataclass(frozen=True)
class Wagon:
    wagon_id: str
    wagon_type: str
    folder: Path
    config_path: Path
    calibration_path: Path | None  # calibration.toml beside the config, merged over it
    config: BogiemonConfig
    days: tuple[Day, ...]  # in date order

    @property
    def commissioned(self) -> tuple[str, ...]:
        """The load states this wagon has its own fused baseline for."""
        return tuple(ld for ld in ("full", "tare") if ld in self.config.decision.fused)


@dataclass(frozen=True)
class Fleet:
    root: Path
    name: str
    wagons: tuple[Wagon, ...]
    issues: tuple[Issue, ...] = field(default=())

    def wagon(self, wagon_id: str) -> Wagon:
        for w in self.wagons:
            if w.wagon_id == wagon_id:
                return w
        known = ", ".join(w.wagon_id for w in self.wagons[:10]) or "none"
        raise FleetError(f"{self.root}: no usable wagon '{wagon_id}' (usable wagons: {known})")

    @property
    def recordings(self) -> int:
        return sum(len(d.files) for w in self.wagons for d in w.days)


def recording_kind(name: str) -> str | None:
    """'samples' (CSV, .csv.gz, Parquet), 'can' (a CAN log) or None (not a recording) from a file name."""
    lower = name.lower()
    if is_sample_recording_name(lower):
        return "samples"
    if lower.endswith(CAN_LOG_SUFFIXES):
        return "can"
    return None


def day_start_s(date: str) -> float:
    """Midnight UTC of a YYYY-MM-DD day, in Unix seconds."""
    return dt.datetime.strptime(date, "%Y-%m-%d").replace(tzinfo=dt.timezone.utc).timestamp()


def _read_fleet_file(root: Path) -> dict[str, Any]:
    path = root / FLEET_FILE
    if not path.exists():
        return {}
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise FleetError(f"{path}: cannot be read as TOML: {exc}") from None
    for key in data:
        if key not in ("fleet", "wagons"):
            raise FleetError(f"{path}: unknown table [{key}]; expected [fleet] and [wagons.\"<id>\"]")
    fleet, wagons = data.get("fleet", {}), data.get("wagons", {})
    if not isinstance(fleet, dict) or not isinstance(wagons, dict) or not all(isinstance(v, dict) for v in wagons.values()):
        raise FleetError(f"{path}: [fleet] must be a table and each [wagons.\"<id>\"] a table")
    for key in fleet:
        if key not in ("name", "default_type"):
            raise FleetError(f"{path}: [fleet] {key}: unknown key; expected name, default_type")
    for wagon_id, entry in wagons.items():
        for key, value in entry.items():
            if key not in ("type", "config") or not isinstance(value, str):
                raise FleetError(f"{path}: [wagons.\"{wagon_id}\"] {key}: expected type = \"...\" or config = \"...\" (strings)")
    return data


def scan_fleet(root: str | Path) -> Fleet:
    """The fleet under root; FleetError only when root or its fleet.toml cannot be used."""
    root = Path(root).resolve()
    if not root.is_dir():
        raise FleetError(f"{root}: no such fleet folder (expected FLEET/<wagon-id>/<YYYY-MM-DD>/ recordings)")
    data = _read_fleet_file(root)
    meta, listed = data.get("fleet", {}), data.get("wagons", {})
    default_type = str(meta.get("default_type", DEFAULT_TYPE))
    issues: list[Issue] = []
    ids: list[str] = []
    # A folder holding the configs fleet.toml names (e.g. FLEET/configs/) is no wagon.
    config_homes = {Path(e["config"]).parts[0] for e in listed.values() if "config" in e and len(Path(e["config"]).parts) > 1}
    for entry in sorted(root.iterdir()):
        if entry.name.startswith(".") or entry.name == FLEET_FILE or entry.name in config_homes:
            continue
        if not entry.is_dir():
            if not entry.name.lower().endswith(IGNORED_SUFFIXES):  # e.g. a simulated fleet's truth.json
                issues.append(Issue(str(entry), "not a wagon folder (a file at the top of the fleet)"))
        elif not WAGON_ID.match(entry.name):
            issues.append(Issue(str(entry), "not a wagon id (letters, digits, '-', '_', '.'; at most 64 characters)"))
        else:
            ids.append(entry.name)
    for wagon_id in listed:
        if wagon_id not in ids:
            issues.append(Issue(str(root / wagon_id), f"listed in {FLEET_FILE} but has no folder of recordings"))
    wagons = []
    for wagon_id in ids:
        entry = listed.get(wagon_id, {})
        wagon = _scan_wagon(root, wagon_id, str(entry.get("type", default_type)), entry.get("config"), issues)
        if wagon is not None:
            wagons.append(wagon)
    return Fleet(root, str(meta.get("name", root.name)), tuple(wagons), tuple(issues))


def _scan_wagon(root: Path, wagon_id: str, wagon_type: str, config_name: str | None, issues: list[Issue]) -> Wagon | None:
    folder = root / wagon_id
    config_path = root / config_name if config_name else folder / WAGON_CONFIG
    calibration = folder / CALIBRATION
    calibration_path = calibration if calibration.is_file() else None
    if not config_path.is_file():
        issues.append(Issue(str(folder), f"no config: expected {config_path} (the wagon's sensor corners and settings); wagon skipped"))
        return None
    try:
        extra = (calibration_path,) if calibration_path is not None else ()
        config = load_config(config_path, log_warnings=False, extra_includes=extra)
        config.check_models()
    except ConfigError as exc:
        first = " ".join(str(exc).split())[:300]
        issues.append(Issue(str(config_path), f"config does not validate, wagon skipped: {first}"))
        return None
    days = []
    for entry in sorted(folder.iterdir()):
        if entry.name.startswith(".") or entry in (config_path, calibration):
            continue
        if not entry.is_dir():
            if entry.suffix != ".toml":
                issues.append(Issue(str(entry), "not a day folder (YYYY-MM-DD) nor the wagon's config; skipped"))
            continue
        if not DAY.match(entry.name) or not _is_date(entry.name):
            issues.append(Issue(str(entry), "a folder whose name is no date (YYYY-MM-DD); skipped"))
            continue
        files = []
        for f in sorted(entry.iterdir()):
            if f.name.startswith("."):
                continue  # an upload in progress, or the recorder's temporary file
            if not f.is_file() or recording_kind(f.name) is None:
                if not f.name.lower().endswith(IGNORED_SUFFIXES):
                    issues.append(Issue(str(f), "not a recording (.csv, .csv.gz or a CAN log: .asc, .blf, .log, .trc); skipped"))
                continue
            st = f.stat()
            files.append(InputFile(f, st.st_size, st.st_mtime_ns))
        if not files:
            issues.append(Issue(str(entry), "an empty day: no recordings"))
            continue
        days.append(Day(entry.name, tuple(files)))
    if not days:
        issues.append(Issue(str(folder), "no day with recordings yet"))
    return Wagon(wagon_id, wagon_type, folder, config_path, calibration_path, config, tuple(days))


def _is_date(text: str) -> bool:
    try:
        dt.datetime.strptime(text, "%Y-%m-%d")
    except ValueError:
        return False
    return True
