"""What a file from outside holds, by its content: a recording of samples or a CAN log, and which
log format (drivers/canlog.py reads them). Light: no python-can, so that reading a recording of
samples never loads it (nor the asyncio python-can brings)."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from bogiemon.drivers.files import UntrustedFile

SQLITE_MAGIC = b"SQLite format 3\x00"
BLF_MAGIC = b"LOGG"
MF4_MAGICS = (b"MDF     ", b"UnFinMF ")  # a finished file; a logger's unfinished one (CANedge)


@dataclass(frozen=True)
class LogFormat:
    """One CAN log format: its key, its words, the suffixes that name it."""

    key: str
    words: str  # "a candump -L log"
    suffixes: tuple[str, ...]
    streams: bool  # read forwards only: its gzip-compressed form is read too


FORMATS: dict[str, LogFormat] = {f.key: f for f in (
    LogFormat("candump", "a candump -L log", (".log",), True),
    LogFormat("asc", "a Vector ASC log", (".asc",), True),
    LogFormat("blf", "a Vector BLF log", (".blf",), True),
    LogFormat("trc", "a PEAK TRC log", (".trc",), True),
    LogFormat("pycsv", "a python-can CSV log", (".csv",), True),
    LogFormat("sqlite", "a python-can SQLite log", (".db", ".sqlite", ".sqlite3"), False),
    LogFormat("mf4", "an MF4 bus log", (".mf4", ".mdf"), False),
)}  # fmt: skip
CAN_LOG_SUFFIXES: tuple[str, ...] = tuple(s for f in FORMATS.values() for s in f.suffixes)
PYCAN_CSV_HEADER = "timestamp,arbitration_id,extended,remote,error,dlc,data"
# candump -L: "(1712345678.123456) can0 123#DEADBEEF"; its human formats: "(2024-01-15 10:00:00.123456)
# can0 123 [8] ..." (-ta), "(000.000213) can0 ..." (-td, -tz), or no time at all.
_CANDUMP_L = re.compile(rb"^\(\s*-?\d+(\.\d+)?\)\s+\S+\s+[0-9A-Fa-f]+#")
# A header of named columns: two or more names (letters first) separated by , ; tab or |.
_HEADER_LINE = re.compile(rb"^[\"']?[A-Za-z_][^,;\t|#]*([,;\t|][^,;\t|#]+)+$")
_CANDUMP_HUMAN = re.compile(rb"^\s*(\(\s*[\d :.-]+\)\s+)?\S+\s+[0-9A-Fa-f]{3,8}\s+\[\d{1,2}\]")


def input_kind(f: UntrustedFile) -> str | None:
    """What a file holds, by its content: "can" (CAN frames: a log of FORMATS, an MF4 with
    CAN_DataFrame groups), "samples" (a recording: CSV text with a header, Parquet, an MF4 of
    signals), or None (neither: refused by the caller, naming what is read)."""
    head = f.head(4096)
    if head.startswith(b"PAR1") or (not head and f.path.name.lower().endswith((".csv", ".csv.gz", ".parquet"))):
        return "samples"
    samples = _looks_like_samples(head)
    try:
        key = sniff_log_format(head, "" if samples else f.path.name)
    except CandumpHuman:
        return "can"  # refused as a log, with its remedy
    if key == "mf4":
        from bogiemon.drivers.mf4 import open_mf4

        mf4 = open_mf4(f.reopen())
        try:
            return "can" if any(mf4.bus_groups().values()) else "samples"
        finally:
            mf4.close()
    if key is not None or f.path.name.lower().endswith(".mfc"):
        return "can"
    if samples or f.path.name.lower().endswith((".csv", ".csv.gz", ".parquet")):
        return "samples"
    return None


NOT_READ = (
    "not a recording bogiemon replays: use a recording (.csv, .csv.gz, .parquet, MF4 of signals) or a CAN log "
    "(.log from candump -L, .asc, .blf, .trc, python-can's .csv or .db, an MF4 bus log)"
)


def _looks_like_samples(head: bytes) -> bool:
    """A text whose first line is a header of named columns, not a log's (a recording's CSV)."""
    first = next((line.strip() for line in head.splitlines() if line.strip()), b"")
    return bool(_HEADER_LINE.match(first)) and not first.lower().startswith(PYCAN_CSV_HEADER.encode())


def sniff_log_format(head: bytes, name: str) -> str | None:
    """The format key of a CAN log from its first (decompressed) bytes, else from its name's
    suffix (.gz taken off); None if it is none of FORMATS. CandumpHuman for candump's human
    format, which is no format bogiemon reads."""
    if head.startswith(BLF_MAGIC):
        return "blf"
    if head.startswith(SQLITE_MAGIC):
        return "sqlite"
    if head.startswith(MF4_MAGICS):
        return "mf4"
    first = next((line.strip() for line in head.splitlines() if line.strip()), b"")
    if first.lower().startswith(PYCAN_CSV_HEADER.encode()):
        return "pycsv"
    if _CANDUMP_L.match(first):
        return "candump"
    if _CANDUMP_HUMAN.match(first):
        raise CandumpHuman
    if first.lower().startswith((b"date ", b"base ")) or b"\nbase hex" in head.lower() or b"\nbase dec" in head.lower():
        return "asc"
    if first.startswith(b";$FILEVERSION") or first.startswith(b";   Start time") or first.startswith(b";##"):
        return "trc"
    # The content said nothing (a damaged first line, an empty log): a text log by its name. The
    # other formats are known by their content alone (a .csv of samples is no python-can log).
    lower = name.lower().removesuffix(".gz")
    return next((f.key for f in FORMATS.values() if f.key in ("candump", "asc", "trc") and lower.endswith(f.suffixes)), None)


class CandumpHuman(Exception):
    """candump's human output (-ta, -tz, -td, or no time), not its log format."""


def candump_human_message(path: str | Path) -> str:
    return (
        f"{path}: this is candump's human output (candump -ta, -tz or -td), not a log bogiemon reads: its times "
        "are rounded or relative and its lines are for the eye. Record with `candump -L can0 > run.log` "
        "(or `candump -l`), which writes every frame with its absolute time"
    )


def readable_name(name: str) -> bool:
    """Whether a file's name is one of a recording or a CAN log (a text log's also gzip-compressed)."""
    lowered = name.lower().removesuffix(".gz")
    text_logs = tuple(s for f in FORMATS.values() if f.streams for s in f.suffixes)
    if name.lower().endswith(".gz"):
        return lowered.endswith((".csv", *text_logs))
    return lowered.endswith((".csv", ".parquet", *CAN_LOG_SUFFIXES))


def expand_folders(paths: list[str | Path], error: type[Exception]) -> list[Path]:
    """The files named, a folder standing for the recordings and CAN logs in it (not its
    subfolders), in name order: loggers and the recorder number or date their files, so that
    is their time order. `error` for a folder holding none."""
    out: list[Path] = []
    for path in map(Path, paths):
        if not path.is_dir():
            out.append(path)
            continue
        found = sorted(p for p in path.iterdir() if p.is_file() and readable_name(p.name))
        if not found:
            raise error(f"{path}: a folder holding no recording or CAN log (.csv, .csv.gz, .parquet, .mf4, {', '.join(CAN_LOG_SUFFIXES[:4])}, ...)")
        out.extend(found)
    return out
