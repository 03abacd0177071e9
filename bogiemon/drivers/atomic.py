"""Files written whole or not at all: the one atomic write of bogiemon, with fsync.

A reader (the daemon at a restart, the fleet's next step, an uploader) never sees a file half
written: the content goes to a hidden temporary beside the final name (an uploader skips names
that begin with '.'; the name ends as the final one does, so a writer that takes its format from
the suffix, .csv.gz or .parquet, writes the same bytes there), is fsynced, renamed over the final
name, and the folder is fsynced so that the rename itself survives a power cut. A failure leaves
the old file (or none) and no temporary; one a killed writer left is named by TEMPORARY.
"""

from __future__ import annotations

import os
import re
import uuid
from collections.abc import Callable
from pathlib import Path

# A temporary's name: '.', 8 hex digits (unique: two writers never share one), '.', the final name.
TEMPORARY = re.compile(r"\.[0-9a-f]{8}\.(?P<final>.+)")


def temporary_name(path: Path) -> Path:
    """The hidden temporary a write of path goes to first, beside it: .<8 hex>.<name>."""
    return path.with_name(f".{uuid.uuid4().hex[:8]}.{path.name}")


def final_name_of(name: str) -> str | None:
    """The final name a temporary's name stands for (a writer that died left it); None for another name."""
    match = TEMPORARY.fullmatch(name)
    return match.group("final") if match else None


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
