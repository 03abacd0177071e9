"""What bogiemon keeps in its state directory, and the room the event store needs to start.

Every file bogiemon writes there is recognisable as its own, by its name alone (own_kind):

    events.sqlite3, events.sqlite3-wal, -shm     the event store (daemon/store.py)
    .events.sqlite3.<8 characters>.new[-wal|-shm]  a store being created (daemon/store_file.py)
    <UTC time>_<reason>[-n].csv.gz | .parquet    a recording, in the recorder's folder (by default
                                                 recordings/ in it: daemon/recorder.py)
    .<8 hex digits>.<a recording's name>          a recording being written (drivers/atomic.py)

At a start, before the store opens, give_back() deletes what is bogiemon's own and no event, as far
as the store needs the room: first every temporary a killed writer left (a store's creation, a
recording's write: nobody writes them now, and they hold nothing whole), then the oldest recordings
while the event store's reserve is not free (docs/recorder.md). A disk filled to its last page by
a recorder killed in the middle of a write then starts, and commits what the run brings. The MQTT
outbox's status messages are in the store's own file: its bound keeps them within the reserve.
Nothing that is not bogiemon's is ever deleted.
"""

from __future__ import annotations

import os
from pathlib import Path

from bogiemon.daemon.config import BogiemonConfig
from bogiemon.daemon.logs import get_logger
from bogiemon.daemon.recorder import NAME_PATTERN, keep_the_reserve_free
from bogiemon.daemon.store_file import DB_NAME, STORE_TEMPORARY
from bogiemon.drivers.atomic import final_name_of

STORE_FILES = (DB_NAME, f"{DB_NAME}-wal", f"{DB_NAME}-shm")


def own_kind(name: str) -> str | None:
    """What bogiemon file a name in the state directory or the recordings folder is: "store",
    "store temporary", "recording", "recording temporary"; None: not bogiemon's."""
    if name in STORE_FILES:
        return "store"
    if STORE_TEMPORARY.fullmatch(name):
        return "store temporary"
    if NAME_PATTERN.fullmatch(name):
        return "recording"
    final = final_name_of(name)
    if final is not None and NAME_PATTERN.fullmatch(final):
        return "recording temporary"
    return None


def give_back(config: BogiemonConfig) -> None:
    """Before the store opens: delete the temporaries bogiemon left in its state directory and its
    recordings folder, then its oldest recordings while the event store's reserve is not free. A
    folder that cannot be read is left to the store's open (or the recorder) to name."""
    folders = [config.state.directory]
    if config.recorder.directory != config.state.directory:
        folders.append(config.recorder.directory)
    log = get_logger(component="state")
    for folder in folders:
        deleted, freed = _delete_temporaries(folder)
        if deleted:
            log.info("deleted what a killed writer left half-written", path=str(folder), files=deleted, bytes=freed)
    settings = config.recorder_settings()
    if settings is not None:
        keep_the_reserve_free(settings)


def _delete_temporaries(folder: Path) -> tuple[int, int]:
    """Delete the store's and the recorder's temporaries in folder: (how many, their bytes)."""
    deleted = freed = 0
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return 0, 0
    for entry in entries:
        if own_kind(entry.name) not in ("store temporary", "recording temporary"):
            continue
        try:
            if not entry.is_file(follow_symlinks=False):
                continue
            size = entry.stat(follow_symlinks=False).st_size
            os.unlink(entry.path)
        except OSError:
            continue  # gone meanwhile, or the disk refuses: the store's open says what is wrong
        deleted += 1
        freed += size
    return deleted, freed
