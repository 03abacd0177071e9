"""Where the back office reads and writes: names, places and Parquet files it does not trust.

FLEET, WINDOWS and JUDGED hold what gateways, uploaders and people put there. Every file in them
is opened through drivers/files.py (a regular file within its kind's size, never a FIFO or a
device); a name that is not UTF-8 is skipped and shown with its bytes escaped (Parquet, JSON and
HTML hold UTF-8 only); what a symlink or '..' resolves to must stay inside its tree; an output
is a folder or a file, never what it finds in its place. Each refusal is one line with the
caller's own error class, naming the path as it can be printed.
"""

from __future__ import annotations

import datetime as dt
import os
import shutil
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from bogiemon.drivers.base import MAX_TIME_S
from bogiemon.drivers.files import FileKind, UntrustedFile, open_untrusted

if TYPE_CHECKING:  # pyarrow is imported where a Parquet file is read or written: the names and places need none of it
    import pyarrow as pa
    import pyarrow.parquet as pq

# The days a fleet's recordings may lie on: no gateway records before 2000, and a time after the
# last one is no clock's reading (drivers/base.py MAX_TIME_S); a day folder outside is skipped.
FIRST_DAY = dt.date(2000, 1, 1)
LAST_DAY = dt.datetime.fromtimestamp(MAX_TIME_S, dt.UTC).date() - dt.timedelta(days=1)
# Nor is a day after tomorrow (UTC) yet: a gateway whose clock was set years ahead would otherwise
# stand as the wagon's latest state until that day came. A day of margin for the time zones.
FUTURE_DAYS = 1
SHOWN_CHARS = 500  # a path in a message: at most this long


def shown(path: str | os.PathLike[str], limit: int = SHOWN_CHARS) -> str:
    """A path as a message prints it: bytes that are not UTF-8 as \\xNN, control characters
    escaped, at most limit characters (the end kept: it names the file)."""
    text = os.fsencode(path).decode("utf-8", "backslashreplace")
    text = "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii") for c in text)
    return text if len(text) <= limit else "..." + text[-(limit - 3) :]


def is_utf8(name: str | os.PathLike[str]) -> bool:
    """Whether a name's bytes are UTF-8 (a name that is not reads back with surrogate escapes)."""
    try:
        os.fspath(name).encode("utf-8")
    except UnicodeEncodeError:
        return False
    return True


def inside(root: Path, path: Path) -> bool:
    """Whether path, its symlinks and '..' resolved, lies inside root (itself resolved)."""
    try:
        return path.resolve().is_relative_to(root)
    except (OSError, RuntimeError):  # a symlink loop
        return False


def last_day(today: dt.date | None = None) -> dt.date:
    """The last day a recording may lie on, seen on `today` (default: today, UTC)."""
    today = today if today is not None else dt.datetime.now(dt.UTC).date()
    return min(LAST_DAY, today + dt.timedelta(days=FUTURE_DAYS))


def output_folder(path: str | os.PathLike[str], error: type[Exception], what: str, inputs: Mapping[str, str | os.PathLike[str]]) -> Path:
    """A folder to write into (made if missing); error naming it when it is something else,
    cannot be made, or lies in one of the run's inputs ({name: folder})."""
    folder = Path(path)
    if not is_utf8(folder):
        raise error(f"{shown(folder)}: {what} must have a UTF-8 name (Parquet and JSON hold no other); rename it")
    outside_inputs(folder, error, what, inputs)
    if folder.exists() and not folder.is_dir():
        raise error(f"{shown(folder)}: not a folder; {what} is a folder: name a new one or an earlier one")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise error(f"{shown(folder)}: cannot make the folder {what}: {exc.strerror or exc}") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise error(f"{shown(folder)}: {what} is not writable")
    return folder


def outside_inputs(path: Path, error: type[Exception], what: str, inputs: Mapping[str, str | os.PathLike[str]]) -> None:
    """error when path ('..' and symlinks resolved) is one of the inputs or lies inside one: the
    run would read what it writes (WINDOWS inside FLEET is scanned as a wagon, JUDGED inside
    WINDOWS as a partition)."""
    try:
        resolved = path.resolve()
        for name, folder in inputs.items():
            if resolved.is_relative_to(Path(folder).resolve()):
                raise error(f"{shown(path)}: {what} lies inside {name} ({shown(folder)}); write it beside {name}, not into it")
    except (OSError, RuntimeError) as exc:  # a symlink loop
        raise error(f"{shown(path)}: cannot be resolved ({one_line(exc)})") from None


def output_file(path: str | os.PathLike[str], error: type[Exception], what: str, inputs: Mapping[str, str | os.PathLike[str]]) -> Path:
    """A file to write (renamed over what is there); error when something other than a regular
    file is in its place (a rename over /dev/null, run as root, would replace the device) or when
    it lies in one of the run's inputs."""
    out = Path(path)
    outside_inputs(out, error, what, inputs)
    place = place_of(out)
    if place not in (None, "missing"):
        raise error(f"{shown(out)}: {place} in its place; {what} is a file: name a new one, or remove what is there")
    return out


def make_room(path: Path, root: Path) -> str | None:
    """Make path's folders real folders inside root and its place free for a rename over it; what
    was in the way, in words, or None. A folder, a symlink or a file where a folder must be is
    removed (these trees are the back office's own output); a FIFO or a symlink in the file's
    place is replaced by the rename itself, a folder there is removed here."""
    removed = []
    folder = root
    for part in path.relative_to(root).parts[:-1]:
        folder = folder / part
        if _is_real_folder(folder):
            continue
        if os.path.lexists(folder):
            removed.append(f"{_kind(folder)} in the place of the folder {part}")
            _remove(folder)
        folder.mkdir()
    if os.path.lexists(path) and _is_real_folder(path):
        removed.append("a folder in its place")
        _remove(path)
    elif os.path.lexists(path) and not stat.S_ISREG(os.lstat(path).st_mode):
        removed.append(f"{_kind(path)} in its place")
    return "; ".join(removed) or None


def _is_real_folder(path: Path) -> bool:
    try:
        return stat.S_ISDIR(os.lstat(path).st_mode)
    except OSError:
        return False


def _kind(path: Path) -> str:
    mode = os.lstat(path).st_mode
    if stat.S_ISLNK(mode):
        return "a symlink"
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    return "a file" if stat.S_ISREG(mode) else "a special file"


def _remove(path: Path) -> None:
    if _is_real_folder(path):
        shutil.rmtree(path)
    else:
        path.unlink()


def place_of(path: Path) -> str | None:
    """What is at path when it is not a regular file (lstat: a symlink is named as one), else None."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return "missing"
    except OSError as exc:
        return f"cannot be looked at ({exc.strerror or exc})"
    return None if stat.S_ISREG(mode) else _kind(path)


def open_parquet(path: Path, kind: FileKind, error: type[Exception]) -> tuple[UntrustedFile, pq.ParquetFile]:
    """A Parquet file opened within its kind's bounds, its footer read by pyarrow, its pages'
    checksums verified as they are read (where written). The caller closes the file."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    f = open_untrusted(path, kind, error)
    try:
        return f, pq.ParquetFile(f, page_checksum_verification=True)
    except (OSError, pa.ArrowException) as exc:
        f.close()
        raise error(f"{shown(path)}: not a readable Parquet file ({one_line(exc)})") from None
    except BaseException:
        f.close()
        raise


def read_parquet(path: Path, kind: FileKind, error: type[Exception], columns: list[str] | None = None) -> tuple[pa.Table, dict[bytes, bytes]]:
    """A whole Parquet file (or its columns), within its kind's bounds, with its schema metadata;
    error for a file pyarrow cannot read."""
    import pyarrow as pa

    f, parquet = open_parquet(path, kind, error)
    try:
        with f:
            table = parquet.read(columns=columns, use_threads=False)
    except (OSError, pa.ArrowException) as exc:
        raise error(f"{shown(path)}: not a readable Parquet file ({one_line(exc)})") from None
    return table, dict(parquet.schema_arrow.metadata or {})


def write_parquet(table: pa.Table, temporary: Path) -> None:
    """A table to a file (any name: Python opens it, so a name pyarrow cannot encode is no
    matter), with page checksums so that a page damaged later is found when it is read."""
    import pyarrow.parquet as pq

    with temporary.open("wb") as f:
        pq.write_table(table, f, compression="zstd", write_page_checksum=True)


def one_line(exc: BaseException | str, limit: int = 300) -> str:
    """An exception's message on one line of at most limit characters."""
    text = " ".join(str(exc).split()) or (type(exc).__name__ if isinstance(exc, BaseException) else "")
    return shown(text, limit) if len(text) > limit or not text.isprintable() else text


def parquet_kind(name: str, description: str, max_bytes: int) -> FileKind:
    """The FileKind of a Parquet file the back office reads (never compressed as a whole)."""
    return FileKind(name=name, description=description, max_bytes=max_bytes, too_large=f"{description}: is this the right file?")
