"""Files written whole or not at all: the one atomic write of bogiemon, with fsync.

A reader (the daemon at a restart, the fleet's next step, an uploader) never sees a file half
written: the content goes to a hidden temporary beside the final name (an uploader skips names
that begin with '.'), is fsynced, renamed over the final name, and the folder is fsynced so that
the rename itself survives a power cut. A failure leaves the old file (or none) and no temporary.
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable
from pathlib import Path

TEMPORARY_SUFFIX = ".tmp"


def temporary_name(path: Path) -> Path:
    """The hidden temporary a write of path goes to first: .<name>.<8 hex>.tmp, beside it (unique,
    so that two writers never share one)."""
    return path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}{TEMPORARY_SUFFIX}")


def is_temporary_of(name: str, final_name: str) -> bool:
    """Whether a file name is one of temporary_name's for final_name (left by a writer that died)."""
    head = f".{final_name}."
    return name.startswith(head) and name.endswith(TEMPORARY_SUFFIX) and len(name) == len(head) + 8 + len(TEMPORARY_SUFFIX)


def fsync_path(path: str | Path) -> None:
    """fsync a file or a folder (a rename or link is durable once its folder is synced)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_atomically(path: str | Path, write: Callable[[Path], object]) -> None:
    """Write path whole or not at all: write(temporary) writes the content to the temporary it is
    given (by any writer: pyarrow, gzip, numpy); OSError and anything write raises propagate after
    the temporary is removed."""
    final = Path(path)
    temporary = temporary_name(final)
    try:
        write(temporary)
        fsync_path(temporary)
        os.replace(temporary, final)
    finally:
        temporary.unlink(missing_ok=True)
    fsync_path(final.parent)


def write_bytes_atomically(path: str | Path, data: bytes) -> None:
    write_atomically(path, lambda temporary: temporary.write_bytes(data))


def write_text_atomically(path: str | Path, text: str) -> None:
    """UTF-8 text, written whole or not at all."""
    write_bytes_atomically(path, text.encode("utf-8"))
