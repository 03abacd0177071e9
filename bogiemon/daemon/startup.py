"""What `run` reads to start, beside the config's own values: every file the config names, opened
and parsed as run opens and parses it, and one digest over all of it.

A config is its text and the files it names: its includes, the models of decision.models_dir, the
DBC of the source and of the CAN alarms, the recording a replay source reads. `check-config` runs
`check_start` (what the service opens at its start, short of the bus, the serial port and the
store's writes), so that a config it accepts is one `run` starts. A reload takes a `Snapshot` of
the new config and its files and compares it with the running one part by part (each section of
the resolved config, its includes merged in; each file it names by its content): nothing changed,
or which sections did (a file counts for the section that names it). That is the one way the service tells what a reload changed; a file
that cannot be read or parsed rejects the whole reload, the running config and files stay.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import stat
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

from bogiemon.daemon.config import (
    BogiemonConfig,
    CanSourceConfig,
    ReplaySourceConfig,
    SimulatedSourceConfig,
    load_config_and_files,
)
from bogiemon.drivers.recording import is_sample_recording_name
from bogiemon.judgement.models import model_paths

# A file is compared by its content up to this size (a DBC, a model, an include); a larger one (a
# recording being replayed) by what the file system says of it: device, inode, size, times.
MAX_HASHED_BYTES = 4 << 20
# Sections that are not settings: the include list is resolved into the others.
_NOT_PARTS = ("include", "allow_absolute_includes")


@dataclass(frozen=True)
class NamedFile:
    section: str  # the config section that names it ("config" for the config file and its includes)
    setting: str  # how, e.g. "source.dbc_path", "decision.models_dir", "include"
    path: Path


def named_files(config: BogiemonConfig, config_files: tuple[Path, ...] = ()) -> list[NamedFile]:
    """Every file run reads at its start for this config: config_files (the config and its
    includes, as load_config_and_files read them), the models, the DBCs, the replayed recording."""
    files = [NamedFile("config", "config" if i == 0 else "include", path) for i, path in enumerate(config_files)]
    files += [NamedFile("decision", "decision.models_dir", path) for path in model_paths(config.decision.models_dir)]
    src = config.source
    if isinstance(src, ReplaySourceConfig):
        files.append(NamedFile("source", "source.path", Path(src.path)))
    if isinstance(src, CanSourceConfig | SimulatedSourceConfig | ReplaySourceConfig) and src.dbc_path:
        if not (isinstance(src, ReplaySourceConfig) and is_sample_recording_name(src.path)):  # a recording of samples needs no DBC
            files.append(NamedFile("source", "source.dbc_path", Path(src.dbc_path)))
    if config.can_alarms.enabled and config.can_alarms.dbc_path:
        files.append(NamedFile("can_alarms", "can_alarms.dbc_path", Path(config.can_alarms.dbc_path)))
    return files


def check_start(config: BogiemonConfig) -> list[str]:
    """Open and parse what `run` opens and parses to start, as it does; raises the same user error
    (DbcError, RecordingError, StoreError, ModelError as ConfigError) where run would exit 2.

    Not opened: the CAN bus and the serial port (run waits for a device that is missing, and a
    check must not take it from a running daemon), the store for writing. Returns, one line each,
    the problems run logs and rides out: credential files that cannot be used now (the publisher
    reads them at each connection attempt).
    """
    from bogiemon.daemon.delivery.can_alarms import load_alarm_codecs
    from bogiemon.daemon.sources import open_source
    from bogiemon.daemon.store import DB_NAME, EventStore
    from bogiemon.drivers.candb import load_layout

    src = config.source
    if isinstance(src, ReplaySourceConfig):
        open_source(config).close()  # the recording's header, its rate against the config, its DBC
    elif isinstance(src, CanSourceConfig | SimulatedSourceConfig):
        load_layout(src.dbc_path or None, src.layout)
    if config.can_alarms.enabled:
        load_alarm_codecs(config.can_alarms.dbc_path or None)
    if (config.state.directory / DB_NAME).exists():  # a store run would refuse (damaged, newer): named now
        EventStore(config.state.directory, readonly=True).close()
    return credential_problems(config)


def credential_problems(config: BogiemonConfig) -> list[str]:
    """The [mqtt] TLS and credential files as the publisher reads them, one line per file it could not use."""
    m = config.mqtt
    if not m.enabled:
        return []
    from bogiemon.daemon.delivery import publisher_settings
    from bogiemon.daemon.delivery.connection import CredentialsError, read_secret, tls_context

    settings = publisher_settings(config).connection
    checks: list[tuple[str, Callable[[], object]]] = [("tls", lambda: tls_context(settings))] if m.tls else []
    for name, path, what in (("username_file", m.username_file, "MQTT username file"), ("password_file", m.password_file, "MQTT password file")):
        if path:
            checks.append((name, functools.partial(read_secret, path, what)))
    problems = []
    for name, check in checks:
        try:
            check()
        except CredentialsError as exc:
            problems.append(f"mqtt.{name}: {exc}")
    return problems


@dataclass(frozen=True)
class Snapshot:
    """A config and the files it names, as digests part by part: each section of the config, each file."""

    config: BogiemonConfig
    parts: Mapping[str, str] = field(repr=False)
    sections: Mapping[str, str] = field(repr=False)  # part -> the section it counts for

    @classmethod
    def of(cls, config: BogiemonConfig, config_files: tuple[Path, ...] = ()) -> Snapshot:
        data = config.model_dump(mode="json")
        parts = {name: _digest(json.dumps(value, sort_keys=True)) for name, value in data.items() if name not in _NOT_PARTS}
        sections = {name: name for name in parts}
        for named in named_files(config, config_files):
            if named.section == "config":
                continue  # the config and its includes are their values, the sections above
            key = f"{named.setting}:{named.path}"
            parts[key] = file_digest(named.path)
            sections[key] = named.section
        return cls(config, parts, sections)

    @property
    def digest(self) -> str:
        """A short hash of every part: equal digests, the same config and the same files."""
        return _digest(json.dumps(sorted(self.parts.items())))[:12]

    def changed(self, new: Snapshot) -> frozenset[str]:
        """The sections whose settings or files differ in new (empty: nothing changed)."""
        keys = set(self.parts) | set(new.parts)
        return frozenset(new.sections.get(k) or self.sections[k] for k in keys if self.parts.get(k) != new.parts.get(k))


def load_snapshot(path: str | Path | None) -> Snapshot:
    """The config at path (None: the shipped default) and the files it names, read now."""
    config, files = load_config_and_files(path)
    return Snapshot.of(config, files)


def file_digest(path: Path) -> str:
    """A file's content hash (up to MAX_HASHED_BYTES), else what the file system says of it; what
    keeps it from being read is part of the digest too (a file that appears is a change)."""
    try:
        st = os.stat(path)
    except (OSError, ValueError) as exc:
        return f"unreadable: {getattr(exc, 'strerror', None) or exc}"
    if not stat.S_ISREG(st.st_mode) or st.st_size > MAX_HASHED_BYTES:
        return f"stat: {stat.S_IFMT(st.st_mode)} {st.st_dev} {st.st_ino} {st.st_size} {st.st_mtime_ns} {st.st_ctime_ns}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)  # a FIFO swapped in meanwhile must not block
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    try:
        hasher = hashlib.sha256()
        left = MAX_HASHED_BYTES + 1
        while left > 0 and (chunk := os.read(fd, min(left, 1 << 16))):
            hasher.update(chunk)
            left -= len(chunk)
        return hasher.hexdigest()
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    finally:
        os.close(fd)


def _digest(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()
