"""The bounds of a Parquet file read from its own bytes, before pyarrow decompresses a page.

A Parquet footer declares totals (a row group's byte size, a column chunk's uncompressed size)
that nothing obliges to be true, and pyarrow allocates what each page header says its page
inflates to: a 1.9 MB file of pages declaring 512 MiB each took 1.66 GB. So the footer's column
chunks are read here (the Thrift compact protocol, a small decoder over the file's bytes: not
pyarrow's metadata objects, which abort the process on some damaged statistics), and every page
header of the columns that will be read is walked, through the descriptor that was checked: each
page must inflate to at most MAX_PAGE_BYTES, a row group's pages together to at most what its
rows can hold, and every page must lie inside its column chunk and the file.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Sequence
from dataclasses import dataclass

# Thrift compact protocol field types.
_STOP, _TRUE, _FALSE, _BYTE, _I16, _I32, _I64, _DOUBLE, _BINARY, _LIST, _SET, _MAP, _STRUCT = range(13)
MAX_CONTAINER = 1 << 20  # elements of a list, bytes of a string: a recording's footer has a few
MAX_DEPTH = 32
# A page of a recording: writers cut pages at 1 MiB (pyarrow, Spark, polars, DuckDB); a
# dictionary page holds at most 65536 distinct 8-byte values of a 16-bit converter.
MAX_PAGE_BYTES = 32 << 20
# A page header: its statistics hold at most a min and a max value.
MAX_PAGE_HEADER_BYTES = 1 << 20
MAX_FOOTER_BYTES = 16 << 20


class ParquetBoundsError(ValueError):
    """A Parquet file whose footer or pages break a bound; the message says which (no path)."""


class _Reader:
    """The Thrift compact protocol over bytes, into {field id: value} dicts."""

    def __init__(self, data: bytes, pos: int = 0) -> None:
        self.data = data
        self.pos = pos

    def byte(self) -> int:
        if self.pos >= len(self.data):
            raise ParquetBoundsError("the metadata ends early")
        value = self.data[self.pos]
        self.pos += 1
        return value

    def varint(self) -> int:
        shift = result = 0
        while True:
            b = self.byte()
            result |= (b & 0x7F) << shift
            if not b & 0x80:
                return result
            shift += 7
            if shift > 70:
                raise ParquetBoundsError("a varint of the metadata runs on")

    def zigzag(self) -> int:
        n = self.varint()
        return (n >> 1) ^ -(n & 1)

    def binary(self) -> bytes:
        n = self.varint()
        if n > MAX_CONTAINER or self.pos + n > len(self.data):
            raise ParquetBoundsError("a string of the metadata is too long")
        value = self.data[self.pos : self.pos + n]
        self.pos += n
        return value

    def value(self, kind: int, depth: int) -> object:
        if depth > MAX_DEPTH:
            raise ParquetBoundsError("the metadata nests too deep")
        if kind in (_TRUE, _FALSE):
            return kind == _TRUE
        if kind == _BYTE:
            return self.byte()
        if kind in (_I16, _I32, _I64):
            return self.zigzag()
        if kind == _DOUBLE:
            if self.pos + 8 > len(self.data):
                raise ParquetBoundsError("the metadata ends early")
            self.pos += 8
            return struct.unpack_from("<d", self.data, self.pos - 8)[0]
        if kind == _BINARY:
            return self.binary()
        if kind in (_LIST, _SET):
            header = self.byte()
            size, element = header >> 4, header & 0x0F
            if size == 15:
                size = self.varint()
            if size > MAX_CONTAINER:
                raise ParquetBoundsError("a list of the metadata is too long")
            if element in (_TRUE, _FALSE):  # booleans in a list are a byte each
                return [self.byte() == _TRUE for _ in range(size)]
            return [self.value(element, depth + 1) for _ in range(size)]
        if kind == _MAP:
            size = self.varint()
            if size > MAX_CONTAINER:
                raise ParquetBoundsError("a map of the metadata is too long")
            if size == 0:
                return {}
            types = self.byte()
            return {self._hashable(self.value(types >> 4, depth + 1)): self.value(types & 0x0F, depth + 1) for _ in range(size)}
        if kind == _STRUCT:
            return self.struct(depth + 1)
        raise ParquetBoundsError(f"an unknown type {kind} in the metadata")

    @staticmethod
    def _hashable(value: object) -> object:
        return value if isinstance(value, int | bytes | bool | float) else repr(value)

    def struct(self, depth: int = 0) -> dict[int, object]:
        fields: dict[int, object] = {}
        last = 0
        while True:
            header = self.byte()
            kind = header & 0x0F
            if kind == _STOP:
                return fields
            delta = header >> 4
            field = last + delta if delta else self.zigzag()
            fields[field] = self.value(kind, depth)
            last = field


@dataclass(frozen=True)
class ColumnChunk:
    name: str  # its path in the schema, dotted
    start: int  # its first page (the dictionary page where there is one)
    compressed_bytes: int


@dataclass(frozen=True)
class RowGroup:
    rows: int
    columns: tuple[ColumnChunk, ...]


def _int(fields: dict[int, object], key: int, default: int = 0) -> int:
    value = fields.get(key, default)
    if not isinstance(value, int) or isinstance(value, bool):
        raise ParquetBoundsError("a number of the metadata is no number")
    return value


def read_footer(fd: int, size_bytes: int) -> list[RowGroup]:
    """The row groups and column chunks the footer of the file on fd declares."""
    if size_bytes < 12:
        raise ParquetBoundsError("too short for a Parquet file")
    tail = os.pread(fd, 8, size_bytes - 8)
    if len(tail) != 8 or tail[4:] != b"PAR1":
        raise ParquetBoundsError("no Parquet footer at its end")
    length = struct.unpack("<I", tail[:4])[0]
    if length > MAX_FOOTER_BYTES or length > size_bytes - 12:
        raise ParquetBoundsError(f"its footer declares {length} bytes")
    footer = os.pread(fd, length, size_bytes - 8 - length)
    meta = _Reader(footer).struct()
    groups = meta.get(4, [])
    if not isinstance(groups, list):
        raise ParquetBoundsError("its row groups are no list")
    out = []
    for group in groups:
        if not isinstance(group, dict):
            raise ParquetBoundsError("a row group is no structure")
        chunks = []
        columns = group.get(1, [])
        for chunk in columns if isinstance(columns, list) else ():
            column = chunk.get(3) if isinstance(chunk, dict) else None
            if not isinstance(column, dict):
                raise ParquetBoundsError("a column chunk has no metadata")
            path = column.get(3, [])
            name = ".".join(p.decode("utf-8", "replace") for p in path if isinstance(p, bytes)) if isinstance(path, list) else ""
            data_page = _int(column, 9)
            dictionary_page = _int(column, 11, 0)
            start = dictionary_page if 0 < dictionary_page < data_page else data_page
            chunks.append(ColumnChunk(name, start, _int(column, 7)))
        out.append(RowGroup(_int(group, 3), tuple(chunks)))
    return out


def check_pages(fd: int, size_bytes: int, groups: Sequence[RowGroup], columns: Sequence[str], bytes_per_value: int) -> None:
    """Walk every page header of the named columns; ParquetBoundsError at the first page that
    would inflate past MAX_PAGE_BYTES, a row group whose pages would inflate past
    bytes_per_value per row and column (plus a page's slack each), or a page outside its chunk."""
    wanted = set(columns)
    for i, group in enumerate(groups):
        total = 0
        for chunk in group.columns:
            if chunk.name not in wanted:
                continue
            end = chunk.start + chunk.compressed_bytes
            if chunk.start < 4 or chunk.compressed_bytes < 0 or end > size_bytes:
                raise ParquetBoundsError(f"row group {i}, column {chunk.name}: its pages lie outside the file")
            pos = chunk.start
            while pos < end:
                header, used = _page_header(fd, pos, end)
                inflated = _int(header, 2)
                packed = _int(header, 3)
                if inflated < 0 or packed < 0 or pos + used + packed > end:
                    raise ParquetBoundsError(f"row group {i}, column {chunk.name}: a page at byte {pos} runs out of its column chunk")
                if inflated > MAX_PAGE_BYTES:
                    raise ParquetBoundsError(
                        f"row group {i}, column {chunk.name}: a page at byte {pos} inflates to {inflated} bytes from {packed}"
                    )
                total += inflated
                pos += used + packed
        allowed = len(wanted) * (group.rows * bytes_per_value + (1 << 20))
        if total > allowed:
            raise ParquetBoundsError(f"row group {i}: its pages inflate to {total} bytes for {group.rows} rows")


def _page_header(fd: int, pos: int, end: int) -> tuple[dict[int, object], int]:
    """The page header at pos and its length in bytes."""
    size = 4096
    while True:
        data = os.pread(fd, min(size, end - pos), pos)
        try:
            reader = _Reader(data)
            return reader.struct(), reader.pos
        except ParquetBoundsError:
            if len(data) < size or size >= MAX_PAGE_HEADER_BYTES:
                raise
            size *= 8
