"""Parquet's bytes taken apart and put back, for the fuzz targets that damage them (fuzz_recordings):
thrift's compact protocol (a footer and its page headers are made of it), the footer and the page
headers of a file, and the offsets that move when a header changes size. No reader's code: a plain
codec of the format, so that a damage can be aimed at one field and the file still parse up to it.
"""

from __future__ import annotations

import struct
from typing import Any


# ---- thrift's compact protocol: what a Parquet footer and its page headers are made of ----------

STOP, TRUE, FALSE, BYTE, I16, I32, I64, DOUBLE, BINARY, LIST, SET, MAP, STRUCT = range(13)
Fields = list[list[Any]]  # a struct: [field id, type, value] in order


class ThriftError(ValueError):
    """Bytes that are no compact-protocol struct."""


def _varint(data: bytes, at: int) -> tuple[int, int]:
    shift = value = 0
    while True:
        if at >= len(data) or shift > 63:
            raise ThriftError("a varint past the end")
        byte = data[at]
        at += 1
        value |= (byte & 0x7F) << shift
        shift += 7
        if not byte & 0x80:
            return value, at


def _unzigzag(n: int) -> int:
    return (n >> 1) ^ -(n & 1)


def decode_struct(data: bytes, at: int = 0, depth: int = 0) -> tuple[Fields, int]:
    """A struct's fields and the offset after it."""
    if depth > 16:
        raise ThriftError("nested too deep")
    fields: Fields = []
    last = 0
    while True:
        if at >= len(data):
            raise ThriftError("a struct past the end")
        head = data[at]
        at += 1
        kind = head & 0x0F
        if kind == STOP:
            return fields, at
        if head >> 4:
            fid = last + (head >> 4)
        else:
            raw, at = _varint(data, at)
            fid = _unzigzag(raw)
        last = fid
        if kind in (TRUE, FALSE):
            fields.append([fid, kind, kind == TRUE])
        else:
            value, at = _decode_value(data, at, kind, depth)
            fields.append([fid, kind, value])


def _decode_value(data: bytes, at: int, kind: int, depth: int) -> tuple[Any, int]:
    if kind == BYTE:
        if at >= len(data):
            raise ThriftError("a byte past the end")
        return struct.unpack_from("b", data, at)[0], at + 1
    if kind in (I16, I32, I64):
        raw, at = _varint(data, at)
        return _unzigzag(raw), at
    if kind == DOUBLE:
        if at + 8 > len(data):
            raise ThriftError("a double past the end")
        return struct.unpack_from("<d", data, at)[0], at + 8
    if kind == BINARY:
        n, at = _varint(data, at)
        if at + n > len(data):
            raise ThriftError("a string past the end")
        return bytes(data[at : at + n]), at + n
    if kind in (LIST, SET):
        if at >= len(data):
            raise ThriftError("a list past the end")
        n, etype = data[at] >> 4, data[at] & 0x0F
        at += 1
        if n == 15:
            n, at = _varint(data, at)
        if n > len(data) - at:
            raise ThriftError("a list longer than the bytes")
        items = []
        for _ in range(n):
            if etype in (TRUE, FALSE):
                items.append(data[at] == TRUE)
                at += 1
            else:
                item, at = _decode_value(data, at, etype, depth + 1)
                items.append(item)
        return {"list": etype, "items": items}, at
    if kind == MAP:
        n, at = _varint(data, at)
        if n > len(data) - at:
            raise ThriftError("a map longer than the bytes")
        if n == 0:
            return {"map": 0, "items": []}, at
        types = data[at]
        at += 1
        pairs = []
        for _ in range(n):
            key, at = _decode_value(data, at, types >> 4, depth + 1)
            value, at = _decode_value(data, at, types & 0x0F, depth + 1)
            pairs.append([key, value])
        return {"map": types, "items": pairs}, at
    if kind == STRUCT:
        return decode_struct(data, at, depth + 1)
    raise ThriftError(f"unknown type {kind}")


def encode_struct(fields: Fields) -> bytes:
    out = bytearray()
    _put_struct(out, fields)
    return bytes(out)


def _put_varint(out: bytearray, value: int) -> None:
    value &= (1 << 64) - 1
    while value >= 0x80:
        out.append((value & 0x7F) | 0x80)
        value >>= 7
    out.append(value)


def _put_int(out: bytearray, n: int) -> None:
    n = max(-(2**63), min(2**63 - 1, n))
    _put_varint(out, (n << 1) ^ (n >> 63))


def _put_struct(out: bytearray, fields: Fields) -> None:
    last = 0
    for fid, kind, value in fields:
        if kind in (TRUE, FALSE):
            kind = TRUE if value else FALSE
        if 0 < fid - last <= 15:
            out.append(((fid - last) << 4) | kind)
        else:
            out.append(kind)
            _put_int(out, fid)
        last = fid
        if kind not in (TRUE, FALSE):
            _put_value(out, kind, value)
    out.append(STOP)


def _put_value(out: bytearray, kind: int, value: Any) -> None:
    if kind == BYTE:
        out += struct.pack("b", max(-128, min(127, value)))
    elif kind in (I16, I32, I64):
        _put_int(out, value)
    elif kind == DOUBLE:
        out += struct.pack("<d", value)
    elif kind == BINARY:
        _put_varint(out, len(value))
        out += value
    elif kind in (LIST, SET):
        etype, items = value["list"], value["items"]
        out.append((len(items) << 4) | etype if len(items) < 15 else 0xF0 | etype)
        if len(items) >= 15:
            _put_varint(out, len(items))
        for item in items:
            if etype in (TRUE, FALSE):
                out.append(TRUE if item else FALSE)
            else:
                _put_value(out, etype, item)
    elif kind == MAP:
        _put_varint(out, len(value["items"]))
        if value["items"]:
            out.append(value["map"])
            for key, item in value["items"]:
                _put_value(out, value["map"] >> 4, key)
                _put_value(out, value["map"] & 0x0F, item)
    elif kind == STRUCT:
        _put_struct(out, value)
    else:
        raise ThriftError(f"unknown type {kind}")


def _field(fields: Fields, fid: int) -> list[Any] | None:
    return next((f for f in fields if f[0] == fid), None)


def int_fields(fields: Fields, path: tuple[Any, ...] = ()) -> list[tuple[Fields, int, tuple[Any, ...]]]:
    """Every integer field of a struct, nested ones too: (its struct, its index there, its path of ids)."""
    out = []
    for i, (fid, kind, value) in enumerate(fields):
        if kind in (BYTE, I16, I32, I64):
            out.append((fields, i, (*path, fid)))
        elif kind == STRUCT:
            out += int_fields(value, (*path, fid))
        elif kind in (LIST, SET) and value["list"] == STRUCT:
            for j, item in enumerate(value["items"]):
                out += int_fields(item, (*path, fid, j))
    return out


# ---- Parquet's layout: the footer, the column chunks' page headers -------------------------------

# FileMetaData: 2 schema, 3 num_rows, 4 row_groups. RowGroup: 1 columns, 2 total_byte_size,
# 3 num_rows, 5 file_offset, 6 total_compressed_size. ColumnChunk: 2 file_offset, 3 meta_data,
# 4 offset_index_offset, 6 column_index_offset. ColumnMetaData: 1 type, 4 codec, 5 num_values,
# 6 total_uncompressed_size, 7 total_compressed_size, 9 data_page_offset, 10 index_page_offset,
# 11 dictionary_page_offset, 14 bloom_filter_offset. SchemaElement: 1 type, 2 type_length,
# 3 repetition_type, 4 name, 5 num_children, 6 converted_type. PageHeader: 1 type,
# 2 uncompressed_page_size, 3 compressed_page_size, 5/7/8 the data, dictionary and v2 headers
# (their field 1: num_values).
_OFFSETS_CHUNK = (2, 4, 6)
_OFFSETS_META = (9, 10, 11, 14)


def split_parquet(raw: bytes) -> tuple[bytes, Fields] | None:
    """(the bytes before the footer, the footer) of a well-formed Parquet file, else None."""
    if len(raw) < 12 or raw[:4] != b"PAR1" or raw[-4:] != b"PAR1":
        return None
    n = struct.unpack("<I", raw[-8:-4])[0]
    if n > len(raw) - 12:
        return None
    try:
        footer, end = decode_struct(raw[-8 - n : -8])
    except ThriftError:
        return None
    return (raw[: -8 - n], footer) if end == n else None


def join_parquet(body: bytes, footer: Fields) -> bytes:
    encoded = encode_struct(footer)
    return body + encoded + struct.pack("<I", len(encoded)) + b"PAR1"


def _chunks(footer: Fields) -> list[Fields]:
    """The ColumnMetaData of every column chunk, row group by row group."""
    out = []
    groups = _field(footer, 4)
    for group in groups[2]["items"] if groups else []:
        columns = _field(group, 1)
        for chunk in columns[2]["items"] if columns else []:
            meta = _field(chunk, 3)
            if meta is not None:
                out.append(meta[2])
    return out


def page_headers(body: bytes, footer: Fields) -> list[tuple[int, int, Fields]]:
    """(start, end, fields) of every page header the column chunks hold, as their metadata say."""
    out: list[tuple[int, int, Fields]] = []
    for meta in _chunks(footer):
        first = min(f[2] for f in meta if f[0] in (9, 11) and isinstance(f[2], int))
        size = _field(meta, 7)
        end = first + (size[2] if size else 0)
        at = first
        while 0 <= at < min(end, len(body)) and len(out) < 4096:
            try:
                header, after = decode_struct(body, at)
            except ThriftError:
                break
            compressed = _field(header, 3)
            out.append((at, after, header))
            if compressed is None or compressed[2] < 0:
                break
            at = after + compressed[2]
    return out


def move_offsets(footer: Fields, at: int, shift: int) -> None:
    """Every offset in the footer past `at` moved by `shift` bytes, and the chunk holding `at` grown by it."""
    groups = _field(footer, 4)
    for group in groups[2]["items"] if groups else []:
        group_start = _field(group, 5)
        if group_start is not None and group_start[2] > at:
            group_start[2] += shift
        held = False
        columns = _field(group, 1)
        for chunk in columns[2]["items"] if columns else []:
            for f in chunk:
                if f[0] in _OFFSETS_CHUNK and isinstance(f[2], int) and f[2] > at:
                    f[2] += shift
            meta = _field(chunk, 3)
            if meta is None:
                continue
            starts = [f[2] for f in meta[2] if f[0] in (9, 11) and isinstance(f[2], int)]
            size = _field(meta[2], 7)
            if starts and size is not None and min(starts) <= at < min(starts) + size[2]:
                held = True
                size[2] += shift
                for fid in (6,):
                    total = _field(meta[2], fid)
                    if total is not None:
                        total[2] += shift
            for f in meta[2]:
                if f[0] in _OFFSETS_META and isinstance(f[2], int) and f[2] > at:
                    f[2] += shift
        if held:
            compressed = _field(group, 6)
            if compressed is not None:
                compressed[2] += shift
