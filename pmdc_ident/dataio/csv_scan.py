"""One compiled pass over a CSV run's bytes: is it plain, how many rows, where labels change.

:func:`pmdc_ident.dataio.csvio.read_csv` reads a plain file - one cell per header
column on every line, every numeric cell a number as loggers write one (ASCII digits,
one point, an exponent; an empty voltage cell for an open armature), no quotes, no
comment or blank line after the header - with numpy's C parser, and anything else
row by row, naming the line of the first error. Deciding "plain" used to take
Python work per line (and the whole file as Python strings: about 5 bytes of memory
per byte of a 200 MB log). This module decides it in one numba pass over the file
mapped in memory, validating every numeric cell strictly on the way (``1_000`` is
not plain, and the careful reader refuses it by its line), and finds the lines where
the segment column's label changes, so the labels of 3.7 M rows cost only as many
Python strings as there are segments. Linear in the file's size.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit

__all__ = ["PLAIN", "scan_body"]

PLAIN = 0
# why a body is not plain (the careful reader then names the line)
NOT_PLAIN_CELLS, NOT_PLAIN_NUMBER, NOT_PLAIN_CHAR = 1, 2, 3

_COMMA, _NL, _CR, _SPACE, _TAB = 44, 10, 13, 32, 9
_QUOTE, _HASH, _NUL = 34, 35, 0
MAX_NUMBER_CELL = 32  # bytes: longer numeric cells are not plain (read by the careful path)


@njit
def _number_ok(buf, a, b, may_be_empty):  # pragma: no cover - jitted
    """``buf[a:b]`` is one strict number (spaces around allowed), or empty when allowed."""
    while a < b and (buf[a] == _SPACE or buf[a] == _TAB):
        a += 1
    while b > a and (buf[b - 1] == _SPACE or buf[b - 1] == _TAB or buf[b - 1] == _CR):
        b -= 1
    if a == b:
        return may_be_empty
    if b - a > MAX_NUMBER_CELL:
        return False
    k = a
    if buf[k] == 43 or buf[k] == 45:  # + -
        k += 1
    digits = 0
    while k < b and 48 <= buf[k] <= 57:
        k += 1
        digits += 1
    if k < b and buf[k] == 46:  # .
        k += 1
        while k < b and 48 <= buf[k] <= 57:
            k += 1
            digits += 1
    if digits == 0:
        return False
    if k < b and (buf[k] == 101 or buf[k] == 69):  # e E
        k += 1
        if k < b and (buf[k] == 43 or buf[k] == 45):
            k += 1
        exp = 0
        while k < b and 48 <= buf[k] <= 57:
            k += 1
            exp += 1
        if exp == 0:
            return False
    return k == b


@njit
def _same(buf, a0, b0, a1, b1):  # pragma: no cover - jitted
    if b0 - a0 != b1 - a1:
        return False
    for k in range(b0 - a0):
        if buf[a0 + k] != buf[a1 + k]:
            return False
    return True


@njit
def _scan(buf, start, n_cols, kind, label_col, changes, chunk, marks):  # pragma: no cover
    """(status, rows, label changes) of ``buf[start:]``; ``kind[c]``: 0 text, 1 number,
    2 number or empty (voltage). ``changes`` receives (row, start, end) of each label
    that differs from the row before (row 0 always), up to its length; ``marks`` the
    byte where every ``chunk``-th row starts."""
    n = buf.size
    rows = 0
    n_changes = 0
    pa = -1
    pb = -1
    k = start
    while k < n:
        if rows % chunk == 0 and rows // chunk < marks.size:
            marks[rows // chunk] = k
        col = 0
        cell = k
        while True:
            if k >= n or buf[k] == _NL or buf[k] == _COMMA:
                end = k
                if col >= n_cols:
                    return NOT_PLAIN_CELLS, rows, n_changes
                if kind[col] > 0:
                    if not _number_ok(buf, cell, end, kind[col] == 2):
                        return NOT_PLAIN_NUMBER, rows, n_changes
                if col == label_col:
                    b = end
                    if b > cell and buf[b - 1] == _CR:
                        b -= 1
                    if pa < 0 or not _same(buf, pa, pb, cell, b):
                        if n_changes < changes.shape[0]:
                            changes[n_changes, 0] = rows
                            changes[n_changes, 1] = cell
                            changes[n_changes, 2] = b
                        n_changes += 1
                        pa = cell
                        pb = b
                col += 1
                if k >= n or buf[k] == _NL:
                    break
                k += 1
                cell = k
                continue
            c = buf[k]
            if c == _QUOTE or c == _HASH or c == _NUL:
                return NOT_PLAIN_CHAR, rows, n_changes
            k += 1
        if col != n_cols:
            return NOT_PLAIN_CELLS, rows, n_changes
        rows += 1
        k += 1  # past the newline
    return PLAIN, rows, n_changes


def scan_body(
    buf: NDArray[np.uint8], start: int, kinds: list[int], label_col: int, chunk: int = 1 << 18
) -> tuple[int, int, list[tuple[int, int, int]], list[int]]:
    """Scan ``buf[start:]`` (the body of a CSV run): ``(status, rows, label changes,
    chunk starts)``.

    ``kinds[c]`` is 0 for a text column, 1 for a numeric one, 2 for numeric or empty
    (the voltage); ``label_col`` is the segment column's index (-1: none). The label
    changes are ``(row, start byte, end byte)``; the chunk starts the byte offsets of
    rows 0, ``chunk``, 2 ``chunk``... and of the end (the parser converts a chunk at a
    time: never the whole table at once).
    """
    kind = np.asarray(kinds, dtype=np.int64)
    changes = np.zeros((4096, 3), dtype=np.int64)
    marks = np.full(buf.size // (max(len(kinds), 1) * chunk) + 2, -1, dtype=np.int64)
    args = (buf, start, len(kinds), kind, label_col)
    status, rows, n_changes = _scan(*args, changes, chunk, marks)
    if status == PLAIN and n_changes > changes.shape[0]:  # many segments: once more, larger
        changes = np.zeros((n_changes, 3), dtype=np.int64)
        status, rows, n_changes = _scan(*args, changes, chunk, marks)
    found = [tuple(int(v) for v in row) for row in changes[: min(n_changes, changes.shape[0])]]
    starts = [int(m) for m in marks if m >= 0] + [int(buf.size)]
    return int(status), int(rows), found, starts  # type: ignore[return-value]
