"""The rows of a CSV recording parsed without pyarrow: what a gateway installed without it reads.

A gateway's own recordings (the recorder's .csv.gz) are CSV, and `replay` of them must not need
pyarrow (170 MB on disk). pyarrow's CSV reader stays the parser where it is installed (ten times
faster); this one reads the same rows to the same bits (both round each number correctly) and
refuses the same lines, so a recording reads alike on either install (tests/drivers/test_csv_rows.py
checks the two against each other).

Two ways through a block of whole lines: numpy's loadtxt (C) where the block holds only the bytes
a recorder writes (digits, signs, points, exponents, commas, spaces, tabs and LF), and otherwise
the grammar pyarrow reads (NUMBER), line by line in Python: NaN spelled any way it accepts, CR
line breaks, and the bad line the caller must name.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
from numpy.typing import NDArray

# A number as pyarrow's CSV reader takes it (spaces and tabs around it allowed).
NUMBER = re.compile(rb"[ \t]*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan(?:\([0-9A-Za-z_]*\))?|inf(?:inity)?)[ \t]*", re.I)
N_COLUMNS = 4
_LINE_BREAK = re.compile(rb"\r\n|\r|\n")
# The bytes of the text numpy parses here: on them loadtxt and pyarrow agree on what a number is.
_PLAIN = bytes(range(256)).translate(None, b"0123456789+-.eE, \t\n")


class RowsError(ValueError):
    """A line of the block is no row of four numbers (the caller finds and names it)."""


def parse_rows(block: bytes) -> NDArray[np.float64]:
    """The rows of a block of whole lines as an (m, 4) float64 array; empty lines hold no row.

    RowsError if a line is not four numbers as pyarrow reads them; the caller then finds the
    line (recording.py's _first_bad_line) and parses the lines before it again.
    """
    if not block.strip(b"\r\n"):
        return np.zeros((0, N_COLUMNS))
    if not block.translate(None, _PLAIN):  # only the recorder's bytes: numpy's parser in C
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # a ragged block is an error, never a guess
                rows = np.loadtxt(block.decode("ascii").splitlines(), delimiter=",", dtype=np.float64, comments=None, ndmin=2)
        except (ValueError, UserWarning):
            pass  # the line-by-line parse below names nothing: it only refuses
        else:
            if rows.shape[1] == N_COLUMNS:
                return rows
    return _parse_lines(block)


def _parse_lines(block: bytes) -> NDArray[np.float64]:
    rows: list[list[float]] = []
    for line in _LINE_BREAK.split(block):
        if not line:
            continue
        cells = line.split(b",")
        if len(cells) != N_COLUMNS or not all(NUMBER.fullmatch(cell) for cell in cells):
            raise RowsError("a line is not four numbers")
        rows.append([_number(cell) for cell in cells])
    return np.array(rows, dtype=np.float64).reshape(-1, N_COLUMNS)


def _number(cell: bytes) -> float:
    """A cell NUMBER matched, as pyarrow reads it: NaN with or without its payload."""
    text = cell.strip(b" \t")
    if b"(" in text:
        return math.nan  # nan(...): pyarrow's NaN, a payload float() does not take
    return float(text)
