"""Opening files that come from outside: configs, recordings, CAN logs, a fleet's uploads.

Every file a user, a logger or a gateway made is opened here, with the bounds of its kind
(FileKind), so that a wrong or hostile file costs a bounded amount of memory and time and ends
as one line naming the file and what to do:

- it must be a regular file: a folder, a FIFO, a device or a socket is refused, and a FIFO is
  opened without blocking (O_NONBLOCK, then fstat) so that naming one by mistake never hangs;
- its size is capped (FileKind.max_bytes), before a byte is read and again while reading (a file
  that grows while it is read is cut at the cap, not read for ever);
- a gzip stream (by its magic bytes, or a name ending in .gz) is read decompressed where the kind
  allows it, with a bound on what it decompresses to: at most max_inflate_ratio times its
  compressed size (at least MIN_INFLATED_BYTES) and never more than max_inflated_bytes, which no
  real recording comes near and every compression bomb does; a stream cut short or damaged is
  one error naming the file;
- lines (UntrustedFile.lines) are at most max_line_bytes long: a file of one 256 MiB line is
  refused after reading max_line_bytes of it, never held whole.

The API, for any reader of outside files (fleet/ included):

    open_untrusted(path, kind, error=RecordingError) -> UntrustedFile   # a binary stream
    read_untrusted(path, kind, error=ConfigError) -> bytes              # a whole small file
    UntrustedFile.lines() -> (number, bytes) ...; .text_lines() -> TextLines (for python-can)
    UntrustedFile.reopen() -> UntrustedFile     # the same file from its start, not by its name
    UntrustedFile.head(n) -> bytes              # its first n bytes (decompressed), for sniffing
    UntrustedFile.proc_path -> "/proc/self/fd/N" # for a library that insists on a name
    one_line(text) -> str                       # file-supplied text, escaped, for a message

An UntrustedFile that is not compressed is seekable: pyarrow.parquet.ParquetFile(f) reads one.
A reader that passes over a file twice, or hands it to a library that opens files by name, never
opens the name again (another file may have taken it meanwhile): reopen() and proc_path go
through the descriptor that was checked, to the same inode.

`error` is the caller's own user-error class (ConfigError, RecordingError, ...), raised with a
message `"<path>: <what is wrong>; <what to do>"`, so each caller keeps catching what it caught.
This module imports only the standard library: a config can be read without numpy.
"""

from __future__ import annotations

import gzip
import io
import os
import re
import stat
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, NoReturn, overload

from bogiemon.drivers.quoting import quoted

GZIP_MAGIC = b"\x1f\x8b"
# A compressed file may always decompress to this much, whatever its ratio: a small file of a
# few constant rows compresses far better than a recording does.
MIN_INFLATED_BYTES = 1 << 20
# What reading raises for a gzip stream that is cut short or damaged (BadGzipFile is an OSError).
_GZIP_ERRORS = (EOFError, zlib.error, gzip.BadGzipFile)
# A line break: CRLF, LF or a lone CR (the line ends Python's universal newlines and pyarrow know).
_LINE_BREAK = re.compile(rb"\r\n|\r|\n")


class UntrustedFileError(ValueError):
    """A file refused by open_untrusted when the caller names no error class of its own."""


@dataclass(frozen=True)
class FileKind:
    """A kind of file a reader accepts: its bounds, and the words of its errors.

    name: the kind in "cannot read the <name>" ("config file", "recording");
    description: what such a file is, after a refusal ("a config is a TOML text file");
    too_large: what to do with one larger than max_bytes;
    gzip: whether a gzip stream is read decompressed (else its bytes are read as they are);
    max_inflated_bytes, max_inflate_ratio: the bound on what a gzip stream decompresses to;
    max_line_bytes: the longest line UntrustedFile.lines() gives, its line break not counted.
    """

    name: str
    description: str
    max_bytes: int
    too_large: str
    gzip: bool = False
    max_inflated_bytes: int = 0
    max_inflate_ratio: float = 0.0
    max_line_bytes: int = 1 << 20


def one_line(text: str | bytes, limit: int = 80) -> str:
    """Text from a file as a message quotes it (drivers/quoting.py), cut to 80 characters by default."""
    return quoted(text, limit)


def size_text(n_bytes: int) -> str:
    """A byte count as the messages write it: whole GiB, else KiB, else bytes."""
    if n_bytes >= 1 << 30 and n_bytes % (1 << 30) == 0:
        return f"{n_bytes >> 30} GiB"
    return f"{n_bytes >> 10} KiB" if n_bytes >= 1 << 10 else f"{n_bytes} bytes"


def short_name(path: str | os.PathLike[str], limit: int = 80) -> str:
    """repr() of a name that is no file name (a NUL in it), cut to a line's worth."""
    text = repr(str(path))
    return text if len(text) <= limit else text[: limit - 3] + "..."


class UntrustedFile(io.RawIOBase):
    """A regular file opened by open_untrusted: its bytes (decompressed if it was gzip), within
    its kind's bounds. A readable binary stream (read, readinto, tell; seek when not compressed)
    that pyarrow and the standard library can read from, with its lines bounded (lines,
    text_lines); every refusal is the caller's error class."""

    def __init__(self, path: Path, kind: FileKind, error: type[Exception], fd: int, size_bytes: int, compressed: bool) -> None:
        super().__init__()
        self.path = path
        self.kind = kind
        self.error = error
        self.size_bytes = size_bytes  # on disk, at the open
        self.compressed = compressed
        self._raw = io.FileIO(fd, "rb", closefd=True)
        self._gzip = gzip.GzipFile(fileobj=self._raw, mode="rb") if compressed else None
        if compressed:
            allowance = max(MIN_INFLATED_BYTES, int(kind.max_inflate_ratio * size_bytes))
            self.max_read_bytes = min(kind.max_inflated_bytes, allowance)
        else:
            self.max_read_bytes = kind.max_bytes
        self._position = 0

    # -- the stream ------------------------------------------------------------------------------

    def readable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return not self.compressed  # a gzip stream is read forwards only

    def tell(self) -> int:
        return self._position

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        if self.compressed:
            raise io.UnsupportedOperation("a compressed stream is read forwards only")
        self._position = self._raw.seek(offset, whence)
        return self._position

    def fileno(self) -> int:
        return self._raw.fileno()

    @property
    def proc_path(self) -> str:
        """A name of the checked descriptor's file, for a library that only opens names: the
        same inode whatever has happened to the name since."""
        return f"/proc/self/fd/{self.fileno()}"

    def reopen(self, kind: FileKind | None = None) -> UntrustedFile:
        """The same file from its start, as a stream of its own (its own offset and gzip state),
        through the checked descriptor: never the name again; with another kind's bounds where
        one is given (a file sniffed as one kind, read as another)."""
        kind = kind or self.kind
        try:
            fd = os.open(self.proc_path, os.O_RDONLY | os.O_CLOEXEC)
        except OSError as exc:
            self.refuse(f"cannot read the {self.kind.name} again: {exc.strerror or exc}")
        before, after = os.fstat(self.fileno()), os.fstat(fd)
        if (before.st_dev, before.st_ino) != (after.st_dev, after.st_ino):  # pragma: no cover - the kernel's promise
            os.close(fd)
            self.refuse(f"the {self.kind.name} changed under its descriptor")
        if self.size_bytes > kind.max_bytes:
            os.close(fd)
            self.refuse(f"larger than {size_text(kind.max_bytes)}; {kind.too_large}")
        compressed = self.compressed and kind.gzip
        return UntrustedFile(self.path, kind, self.error, fd, self.size_bytes, compressed)

    def head(self, n_bytes: int) -> bytes:
        """The first n_bytes of the file (decompressed if it is compressed), read from a stream of
        its own: this one's position is not moved. A damaged or cut gzip stream gives what it has."""
        if not self.compressed:
            return os.pread(self.fileno(), n_bytes, 0)
        with self.reopen() as f:
            assert f._gzip is not None
            try:
                return f._gzip.read(n_bytes)
            except (*_GZIP_ERRORS, OSError):
                return b""

    def read(self, size: int | None = -1) -> bytes:
        """At most size bytes (all there are: -1 or None), within the bounds."""
        if size is None or size < 0:
            return self.read_whole()
        # One byte beyond the bound is asked for, so that a stream ending exactly at it is whole.
        size = min(size, self.max_read_bytes + 1 - self._position)
        try:
            data = (self._gzip if self._gzip is not None else self._raw).read(size) or b""
        except _GZIP_ERRORS as exc:
            self.refuse(gzip_problem(exc, self.kind))
        except OSError as exc:
            self.refuse(f"cannot read the {self.kind.name}: {exc.strerror or exc}")
        self._position += len(data)
        if self._position > self.max_read_bytes:
            self._refuse_too_long()
        return data

    def readinto(self, buffer: memoryview | bytearray) -> int:  # type: ignore[override]
        data = self.read(len(memoryview(buffer).cast("B")))
        memoryview(buffer).cast("B")[: len(data)] = data
        return len(data)

    def readall(self) -> bytes:
        return self.read_whole()

    def read_whole(self) -> bytes:
        """Everything there is (within the bounds): for small files."""
        chunks = []
        while chunk := self.read(1 << 16):
            chunks.append(chunk)
        return b"".join(chunks)

    def close(self) -> None:
        if not self.closed:
            try:
                if self._gzip is not None:
                    self._gzip.close()
            finally:
                self._raw.close()
        super().close()

    # -- lines -----------------------------------------------------------------------------------

    @overload
    def lines(self, first_number: int = 1, chunk_bytes: int = 1 << 20, skip_long: Literal[False] = False) -> Iterator[tuple[int, bytes]]: ...
    @overload
    def lines(self, first_number: int = 1, chunk_bytes: int = 1 << 20, *, skip_long: bool) -> Iterator[tuple[int, bytes | None]]: ...
    def lines(self, first_number: int = 1, chunk_bytes: int = 1 << 20, skip_long: bool = False) -> Iterator[tuple[int, bytes | None]]:
        """(line number, bytes) of every line from here on, without its line break (CRLF, LF or CR).

        A line longer than the kind's max_line_bytes is refused when that much of it has been
        read; with skip_long it is read to its end without being kept, and given as (number, None).
        """
        limit = self.kind.max_line_bytes
        number = first_number
        pending = b""
        skipping = False  # inside a line too long, after the part of it that was read
        while True:
            chunk = self.read(chunk_bytes)
            data = pending + chunk
            start = 0
            # A CR at the very end may be the first half of a CRLF: wait for the next chunk.
            end = len(data) - 1 if chunk and data.endswith(b"\r") else len(data)
            for found in _LINE_BREAK.finditer(data, 0, end):
                line = data[start : found.start()]
                if skipping or len(line) > limit:
                    if not skip_long:
                        self.refuse_line(number, f"longer than {size_text(limit)}")
                    yield number, None
                    skipping = False
                else:
                    yield number, line
                number += 1
                start = found.end()
            pending = data[start:]
            if len(pending) > limit:
                if not skip_long:
                    self.refuse_line(number, f"longer than {size_text(limit)}")
                skipping, pending = True, pending[-1:] if pending.endswith(b"\r") else b""
            if not chunk:
                if pending or skipping:
                    yield number, None if skipping else pending
                return

    def text_lines(self, encoding: str = "utf-8") -> TextLines:
        """This file's lines as text, for a parser that iterates a text file (python-can's log readers)."""
        return TextLines(self, encoding)

    # -- errors ----------------------------------------------------------------------------------

    def refuse(self, problem: str) -> NoReturn:
        """Raise the caller's error: '<path>: <problem>'."""
        raise self.error(f"{self.path}: {problem}") from None

    def refuse_line(self, number: int, problem: str) -> NoReturn:
        raise self.error(
            f"{self.path}: line {number}: {problem}; {self.kind.description}: is this the right file?"
        ) from None

    def _refuse_too_long(self) -> NoReturn:
        if self.compressed:
            self.refuse(
                f"decompresses to more than {size_text(self.max_read_bytes)} "
                f"({self.kind.max_inflate_ratio:g} times its compressed size, or {size_text(self.kind.max_inflated_bytes)}): "
                f"no {self.kind.name} compresses that well (a compression bomb?); {self.kind.description}"
            )
        self.refuse(f"grew past {size_text(self.kind.max_bytes)} while it was read; {self.kind.too_large}")


class LineTooLong(ValueError):
    """A line longer than its kind allows, read to its end and not kept (TextLines)."""


class TextLines:
    """The lines of an UntrustedFile as text, for a parser that iterates a text file line by line
    (python-can's .log and .asc readers): undecodable bytes replaced, each line ending in "\n".

    A line longer than the kind's max_line_bytes is read to its end without being kept, and
    raises LineTooLong at its place, once: a parser that counts a bad line and reads on from the
    next one (drivers/replay.py) does so, in bounded memory, whatever the line's length.
    """

    def __init__(self, f: UntrustedFile, encoding: str = "utf-8") -> None:
        self.file = f
        self.encoding = encoding
        self._lines = f.lines(skip_long=True)

    def __iter__(self) -> TextLines:
        return self

    def __next__(self) -> str:
        number, line = next(self._lines)
        if line is None:
            raise LineTooLong(f"{self.file.path}: line {number}: longer than {size_text(self.file.kind.max_line_bytes)}")
        return line.decode(self.encoding, errors="replace") + "\n"

    def readline(self) -> str:
        return next(self, "")

    @property
    def closed(self) -> bool:
        return self.file.closed

    def close(self) -> None:
        self.file.close()


def gzip_problem(exc: BaseException, kind: FileKind) -> str:
    """What a gzip error means, in a message's words (without the path)."""
    if isinstance(exc, EOFError):
        return (
            f"the compressed {kind.name} is cut short (its gzip stream ends early: a partial copy or upload?); copy it again"
        )
    return f"not a readable gzip file ({exc}); the compressed {kind.name} is damaged: copy it again"


def open_untrusted(path: str | os.PathLike[str], kind: FileKind, error: type[Exception] = UntrustedFileError) -> UntrustedFile:
    """Open a file from outside for reading, within the bounds of its kind; raise `error` naming it.

    Refused before any byte is read: a name that cannot be opened (missing, no permission, a NUL
    in it), anything but a regular file (without blocking on a FIFO), a file larger than
    kind.max_bytes. Refused while reading: more bytes than the bounds allow (a growing file, a
    gzip stream decompressing past its bound), a damaged or cut gzip stream.
    """
    try:
        # O_NONBLOCK: a FIFO named by mistake must not block the open; it is refused below.
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        raise error(f"{path}: cannot read the {kind.name}: {exc.strerror or exc}") from None
    except ValueError:  # a NUL in the name
        raise error(f"{short_name(path)}: not a file name") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            what = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise error(f"{path}: {what}; {kind.description}")
        if st.st_size > kind.max_bytes:
            raise error(f"{path}: larger than {size_text(kind.max_bytes)}; {kind.too_large}")
        os.set_blocking(fd, True)  # a regular file: reads never block anyway; this keeps EAGAIN out
        compressed = kind.gzip and (Path(path).name.lower().endswith(".gz") or os.pread(fd, len(GZIP_MAGIC), 0) == GZIP_MAGIC)
    except OSError as exc:
        os.close(fd)
        raise error(f"{path}: cannot read the {kind.name}: {exc.strerror or exc}") from None
    except BaseException:
        os.close(fd)
        raise
    return UntrustedFile(Path(path), kind, error, fd, st.st_size, compressed)


def read_untrusted(path: str | os.PathLike[str], kind: FileKind, error: type[Exception] = UntrustedFileError) -> bytes:
    """A whole small file's bytes (decompressed if it was gzip and the kind allows it), within its bounds."""
    with open_untrusted(path, kind, error) as f:
        return f.read_whole()
