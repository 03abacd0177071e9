"""The recordings tree of a fleet (docs/fleet-formats.md, section 1): wagons, their configs, their days.

Scanning only lists and stats files and loads each wagon's config: what a recording holds is read
by the analysis. What cannot be used is an Issue (named, counted, skipped), never a stop: one
wagon's broken config or a stray file must not hold up a thousand other wagons. Only a fleet.toml
that does not parse is a FleetError, since it describes the whole fleet.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import os
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bogiemon.daemon.config import BogiemonConfig, ConfigError, load_config
from bogiemon.drivers.files import FileKind, read_untrusted
from bogiemon.drivers.recording import is_sample_recording_name
from bogiemon.fleet.objects import SMALL_FILE_BYTES, ObjectStoreError, fetch, is_url, list_objects, open_store, scratch
from bogiemon.fleet.paths import FIRST_DAY, inside, is_utf8, last_day, one_line, shown

FLEET_FILE = "fleet.toml"
WAGON_CONFIG = "bogiemon.toml"
CALIBRATION = "calibration.toml"
DEFAULT_TYPE = "unspecified"
WAGON_ID = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")
DAY = re.compile(r"^\d{4}-\d{2}-\d{2}$")
CAN_LOG_SUFFIXES = (".asc", ".blf", ".log", ".trc")
IGNORED_SUFFIXES = (".json",)  # the simulator's sidecars and truth: what was simulated, not recordings
FLEET_FILE_KIND = FileKind(
    name="fleet file", description="fleet.toml is a page of TOML ([fleet] and [wagons.\"<id>\"])", max_bytes=1 << 20,
    too_large="fleet.toml is a page of TOML: is this the right file?",
)  # fmt: skip
# What the scan of an object store's copy says of every day and wagon, whose recordings stay in the store.
EMPTY_COPY = ("an empty day: no recordings", "no day with recordings yet")
NOT_UTF8 = "a name that is not UTF-8 (the windows, events and report hold UTF-8 only): rename it; skipped"


class FleetError(ValueError):
    """The fleet as a whole cannot be used (no such folder, a fleet.toml that does not parse)."""


@dataclass(frozen=True)
class Issue:
    """Something in the tree that is skipped: what and why, in one line, printable (a name that is
    not UTF-8 shows its bytes escaped: the issue goes to JSON, Parquet and HTML)."""

    path: str
    reason: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", shown(self.path))
        object.__setattr__(self, "reason", one_line(self.reason, 600))

    def as_dict(self) -> dict[str, str]:
        return {"path": self.path, "reason": self.reason}


@dataclass(frozen=True)
class InputFile:
    """A recording as found: its name, size and modification time identify its contents."""

    path: Path  # in an object store: its key under the fleet's prefix
    size_bytes: int
    mtime_ns: int
    url: str = ""  # in an object store: where it is read from (fleet/objects.py); "" for a local file

    @property
    def shown(self) -> str:
        """Where it is, as a message names it."""
        return self.url or str(self.path)

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
    url: str = ""  # a fleet in an object store: its URL (root is then that of its configs' copies, gone)

    @property
    def location(self) -> str:
        """Where the fleet is, as a summary records it and a later step scans it again."""
        return self.url or str(self.root)

    @property
    def local_inputs(self) -> dict[str, Path]:
        """The fleet's folder as an input no output may lie in (none for an object store)."""
        return {} if self.url else {"FLEET": self.root}

    def wagon(self, wagon_id: str) -> Wagon:
        for w in self.wagons:
            if w.wagon_id == wagon_id:
                return w
        why = next((i for i in self.issues if Path(i.path).is_relative_to(self.root / wagon_id)), None)
        if why is not None:
            raise FleetError(f"{why.path}: {why.reason}")
        known = ", ".join(w.wagon_id for w in self.wagons[:10]) or "none"
        raise FleetError(f"{shown(self.location)}: no usable wagon '{shown(wagon_id, 80)}' (usable wagons: {known})")

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
    return dt.datetime.strptime(date, "%Y-%m-%d").replace(tzinfo=dt.UTC).timestamp()


def _read_fleet_file(root: Path) -> dict[str, Any]:
    path = root / FLEET_FILE
    if not os.path.lexists(path):
        return {}
    if not inside(root, path):
        raise FleetError(f"{shown(path)}: leads out of the fleet folder ('..' and symlinks resolved); keep fleet.toml in FLEET")
    raw = read_untrusted(path, FLEET_FILE_KIND, FleetError)
    try:
        data = tomllib.loads(raw.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise FleetError(f"{path}: cannot be read as TOML: not UTF-8 text (byte {exc.start})") from None
    except (tomllib.TOMLDecodeError, RecursionError) as exc:
        raise FleetError(f"{path}: cannot be read as TOML: {one_line(exc)}") from None
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


def scan_fleet(root: str | Path, today: dt.date | None = None) -> Fleet:
    """The fleet under root (a folder, or an object store's URL: fleet/objects.py); FleetError only
    when root or its fleet.toml cannot be used. A day after the day after `today` (default: today,
    UTC) is skipped as no clock's reading yet."""
    if is_url(root):
        return scan_store(str(root), today)
    if not is_utf8(root):
        raise FleetError(f"{shown(root)}: the fleet folder's name is not UTF-8 (the windows, events and report hold UTF-8 only); rename it")
    try:
        root = Path(root).resolve()
    except (OSError, RuntimeError) as exc:
        raise FleetError(f"{shown(root)}: cannot be resolved ({one_line(exc)})") from None
    if not root.is_dir():
        raise FleetError(f"{shown(root)}: no such fleet folder (expected FLEET/<wagon-id>/<YYYY-MM-DD>/ recordings)")
    data = _read_fleet_file(root)
    meta, listed = data.get("fleet", {}), data.get("wagons", {})
    default_type = str(meta.get("default_type", DEFAULT_TYPE))
    issues: list[Issue] = []
    ids: list[str] = []
    # A folder holding the configs fleet.toml names (e.g. FLEET/configs/) is no wagon.
    config_homes = {Path(e["config"]).parts[0] for e in listed.values() if "config" in e and len(Path(e["config"]).parts) > 1}
    entries = _entries(root, issues)
    if entries is None:
        raise FleetError(f"{issues[-1].path}: {issues[-1].reason}")
    for entry in entries:
        if entry.name.startswith(".") or entry.name == FLEET_FILE or entry.name in config_homes:
            continue
        if not is_utf8(entry.name):
            issues.append(Issue(str(entry), NOT_UTF8))
        elif not entry.is_dir():
            if not entry.name.lower().endswith(IGNORED_SUFFIXES):  # e.g. a simulated fleet's truth.json
                issues.append(Issue(str(entry), "not a wagon folder (a file at the top of the fleet)"))
        elif not WAGON_ID.match(entry.name):
            issues.append(Issue(str(entry), "not a wagon id (letters, digits, '-', '_', '.'; at most 64 characters)"))
        elif not inside(root, entry):
            issues.append(Issue(str(entry), "leads out of the fleet folder ('..' and symlinks resolved); wagon skipped"))
        else:
            ids.append(entry.name)
    for wagon_id in listed:
        if wagon_id not in ids and not any(Path(i.path).name == wagon_id for i in issues):
            issues.append(Issue(str(root / wagon_id), f"listed in {FLEET_FILE} but has no folder of recordings"))
    wagons = []
    for wagon_id in ids:
        entry = listed.get(wagon_id, {})
        wagon = _scan_wagon(root, wagon_id, str(entry.get("type", default_type)), entry.get("config"), last_day(today), issues)
        if wagon is not None:
            wagons.append(wagon)
    return Fleet(root, str(meta.get("name", root.name)), tuple(wagons), tuple(issues))


def scan_store(url: str, today: dt.date | None = None) -> Fleet:
    """The fleet under an object store's prefix, by the local tree's rules: its small files
    fetched into a scratch folder and scanned there as a local tree would be, its recordings
    listed with their sizes and times and left in the store (fleet/objects.py)."""
    try:
        store = open_store(url)
        objects = list_objects(store)
    except ObjectStoreError as exc:
        raise FleetError(str(exc)) from None
    issues: list[Issue] = []
    usable = []
    for o in objects:
        parts = o.key.split("/")
        if any(p in ("", ".", "..") for p in parts) or len(parts) > 3:
            issues.append(Issue(store.url_of(o.key), "not in the tree FLEET/<wagon-id>/<YYYY-MM-DD>/<recording>; skipped"))
        else:
            usable.append((parts, o))
    with scratch("bogiemon-fleet-") as local:
        for parts, o in usable:  # the tree's folders, and its small files to read
            folder = local.joinpath(*parts[:-1])
            folder.mkdir(parents=True, exist_ok=True)
            if len(parts) <= 2 and o.key.endswith(".toml"):
                try:
                    fetch(store, o.key, local.joinpath(*parts), SMALL_FILE_BYTES, FleetError, o.size_bytes)
                except FleetError as exc:
                    issues.append(Issue(store.url_of(o.key), str(exc).removeprefix(store.url_of(o.key) + ": ")))
            elif len(parts) <= 2:  # an empty stand-in, for the scan to name it (a stray file, a sidecar it ignores)
                local.joinpath(*parts).touch()
        scanned = scan_fleet(local, today)
        recordings = {tuple(parts): o for parts, o in usable if len(parts) == 3}
        wagons = []
        for wagon in scanned.wagons:
            days = []
            for day_dir in sorted({p[1] for p in recordings if p[0] == wagon.wagon_id}):
                date = _date(day_dir)
                if date is None or not FIRST_DAY <= date <= last_day(today):
                    continue  # named by the scan of the copy, whose day folders are there (empty)
                files = []
                for name in sorted(p[2] for p in recordings if p[:2] == (wagon.wagon_id, day_dir)):
                    o = recordings[(wagon.wagon_id, day_dir, name)]
                    if name.startswith("."):
                        continue
                    if recording_kind(name) is None:
                        if not name.lower().endswith(IGNORED_SUFFIXES):
                            issues.append(Issue(store.url_of(o.key), "not a recording (.csv, .csv.gz, .parquet or a CAN log: .asc, .blf, .log, .trc); skipped"))
                        continue
                    files.append(InputFile(Path(o.key), o.size_bytes, o.mtime_ns, url=store.url_of(o.key)))
                if files:
                    days.append(Day(day_dir, tuple(files)))
            remote = store.url_of(wagon.wagon_id)
            wagons.append(dataclasses.replace(wagon, folder=Path(wagon.wagon_id), config_path=wagon.config_path.relative_to(local),
                                              calibration_path=None if wagon.calibration_path is None else Path(wagon.wagon_id, CALIBRATION),
                                              days=tuple(days)))  # fmt: skip
            if not days:
                issues.append(Issue(remote, "no day with recordings yet"))
        # What the scan of the copy said, naming the store's objects (its days hold no copies: not an issue).
        issues += [Issue(i.path.replace(str(local), store.url, 1), i.reason) for i in scanned.issues if i.reason not in EMPTY_COPY]
    return Fleet(Path(store.url), scanned.name if scanned.name != local.name else store.root.rsplit("/", 1)[-1], tuple(wagons), tuple(issues), url=store.url)


def _entries(folder: Path, issues: list[Issue]) -> list[Path] | None:
    """A folder's entries in name order; None (and an issue) when it cannot be listed."""
    try:
        return sorted(folder.iterdir())
    except OSError as exc:
        issues.append(Issue(str(folder), f"cannot be listed ({exc.strerror or exc}); skipped"))
        return None


def _config_path(root: Path, folder: Path, config_name: str | None) -> Path | str:
    """The wagon's config file, or why it cannot be used (it must lie inside the fleet)."""
    if config_name is None:
        path = folder / WAGON_CONFIG
    elif not config_name or "\0" in config_name or Path(config_name).is_absolute():
        return f"{FLEET_FILE} names config = {shown(repr(config_name), 80)}: expected a path relative to the fleet folder; wagon skipped"
    else:
        path = root / config_name
    if not inside(root, path):
        return f"its config {shown(path)} leads out of the fleet folder ('..' and symlinks resolved); wagon skipped"
    return path


def _scan_wagon(root: Path, wagon_id: str, wagon_type: str, config_name: str | None, newest: dt.date, issues: list[Issue]) -> Wagon | None:
    folder = root / wagon_id
    config_path = _config_path(root, folder, config_name)
    if isinstance(config_path, str):
        issues.append(Issue(str(folder), config_path))
        return None
    calibration = folder / CALIBRATION
    # A calibration.toml that is there is used or the wagon is skipped: a FIFO or a folder in its
    # place must not leave the wagon judged as if it had never been commissioned.
    calibration_path = calibration if os.path.lexists(calibration) else None
    if calibration_path is not None and not inside(root, calibration_path):
        issues.append(Issue(str(calibration), "leads out of the fleet folder ('..' and symlinks resolved); wagon skipped"))
        return None
    if not os.path.lexists(config_path):
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
    for entry in _entries(folder, issues) or ():
        if entry.name.startswith(".") or entry in (config_path, calibration):
            continue
        if not is_utf8(entry.name):
            issues.append(Issue(str(entry), NOT_UTF8))
            continue
        if not entry.is_dir():
            if entry.suffix != ".toml":
                issues.append(Issue(str(entry), "not a day folder (YYYY-MM-DD) nor the wagon's config; skipped"))
            continue
        day = _date(entry.name)
        if day is None:
            issues.append(Issue(str(entry), "a folder whose name is no date (YYYY-MM-DD); skipped"))
            continue
        if not FIRST_DAY <= day <= newest:
            issues.append(Issue(str(entry), f"a day outside {FIRST_DAY} .. {newest} (no gateway's clock reads it now); skipped"))
            continue
        if not inside(root, entry):
            issues.append(Issue(str(entry), "leads out of the fleet folder ('..' and symlinks resolved); skipped"))
            continue
        files = _recordings(root, entry, issues)
        if not files:
            issues.append(Issue(str(entry), "an empty day: no recordings"))
            continue
        days.append(Day(entry.name, tuple(files)))
    if not days:
        issues.append(Issue(str(folder), "no day with recordings yet"))
    return Wagon(wagon_id, wagon_type, folder, config_path, calibration_path, config, tuple(days))


def _recordings(root: Path, day: Path, issues: list[Issue]) -> list[InputFile]:
    """A day folder's recordings, in name order; what is no recording is an issue."""
    files = []
    for f in _entries(day, issues) or ():
        if f.name.startswith("."):
            continue  # an upload in progress, or the recorder's temporary file
        if not is_utf8(f.name):
            issues.append(Issue(str(f), NOT_UTF8))
            continue
        if not f.is_file() or recording_kind(f.name) is None:
            if not f.name.lower().endswith(IGNORED_SUFFIXES):
                issues.append(Issue(str(f), "not a recording (.csv, .csv.gz or a CAN log: .asc, .blf, .log, .trc); skipped"))
            continue
        if not inside(root, f):
            issues.append(Issue(str(f), "leads out of the fleet folder ('..' and symlinks resolved); skipped"))
            continue
        try:
            st = f.stat()
        except OSError as exc:
            issues.append(Issue(str(f), f"cannot be looked at ({exc.strerror or exc}); skipped"))
            continue
        files.append(InputFile(f, st.st_size, st.st_mtime_ns))
    return files


def _date(text: str) -> dt.date | None:
    """The date a day folder's name is, or None."""
    if not DAY.match(text):
        return None
    try:
        return dt.date.fromisoformat(text)
    except ValueError:
        return None
