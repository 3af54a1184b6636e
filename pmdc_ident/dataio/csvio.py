"""CSV runs: the offline exchange format of docs/design.md §4.

One header row, then one row per sample. Columns (names case-insensitive, any
order; unknown columns are ignored):

=================  =====  ==============================================
column             unit   meaning
=================  =====  ==============================================
``t``              s      sample time, strictly increasing through the file
``voltage``        V      commanded voltage; an *empty* cell marks a sample
                          with the armature open (coast-down). Without this
                          column the run is current-driven (mechanical only)
``current``        A      armature current (optional)
``position``       rad    shaft angle (``position`` and/or ``speed`` needed)
``speed``          rad/s  shaft speed
``terminal_voltage`` V    measured terminal voltage (optional)
``segment``        -      label; contiguous rows with one label are one
                          experiment (default: one segment called ``run``)
=================  =====  ==============================================

Tables (seed 000's steady-state staircase and retardation test) use the same
schema: each staircase level is a segment ``staircase_NN`` of a few constant
rows, the retardation table a ``coast`` segment with empty voltage cells and
the measured speeds (see ``test/fixtures/``).

Lines starting with ``#`` are comments (provenance notes). Files from other
tools keep their own headers: ``columns={"speed": "Speed_rpm"}`` reads the
column headed ``Speed_rpm`` as ``speed`` (units are converted on top of this by
:mod:`pmdc_ident.dataio.units`). Only an empty
voltage cell means "open"; a NaN written anywhere, an empty cell in another
column, a non-numeric cell, a row with more or fewer cells than the header
(empty trailing cells aside), time that does not increase (across segment
boundaries too) or a value beyond any motor test
(:data:`~pmdc_ident.core.data.SIGNAL_LIMITS`) is refused with one line naming
the file's line and the column.
"""

from __future__ import annotations

import csv
import math
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from pmdc_ident.core.data import Run, Segment, link_history
from pmdc_ident.core.errors import DataError, DataOptionError, SignalRangeError
from pmdc_ident.core.errors import option_name as opt

__all__ = ["CSV_COLUMNS", "parse_number", "read_csv", "write_csv"]

CSV_COLUMNS: tuple[str, ...] = (
    "t",
    "voltage",
    "current",
    "position",
    "speed",
    "terminal_voltage",
    "segment",
)
_NUMERIC = ("t", "voltage", "current", "position", "speed", "terminal_voltage")
# A number as loggers write one, and nothing else: ASCII digits, one point, an
# exponent (nan/inf are recognised to be refused with their own message). Python's
# float() also takes "1_000" and other scripts' digits: a cell written so is a
# typing slip or another locale, never a measurement to read as 1000.
_NUMBER = re.compile(
    r"[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?|[+-]?(?:nan|inf|infinity)",
    re.IGNORECASE | re.ASCII,
)


def parse_number(cell: str) -> float:
    """``cell`` (stripped) as a float, read strictly (:data:`_NUMBER`); ValueError else."""
    if _NUMBER.fullmatch(cell) is None:
        raise ValueError(cell)
    return float(cell)


def read_csv(
    path: str | Path,
    columns: Mapping[str, str] | None = None,
    scale: Mapping[str, float] | None = None,
) -> Run:
    """Read a CSV run (schema in the module docs) into a :class:`Run`.

    ``columns`` maps a schema name (``t``, ``speed``...) to the file's own header
    for it (case-insensitive; ``"none"`` ignores the file's column of that name);
    the file's column of that schema name, if any, is then ignored. ``scale``
    multiplies a column by a factor to SI before the run is built (the unit
    layer :mod:`pmdc_ident.dataio.units` computes it).
    """
    from pmdc_ident.core.safe_write import protect

    p = Path(path)
    protect([p])  # what a command reads, it never writes (core.safe_write)
    table = _fast_table(p, columns or {})
    if table is None:  # anything odd: row by row, every error naming the file's line
        table = _careful_table(p, _text(p), columns or {})
    data, runs, where = table
    _check_time(p, data["t"], where)
    for name, factor in (scale or {}).items():
        if name in data and factor != 1.0:
            data[name] = data[name] * factor
    return Run(link_history(tuple(_segments(p, data, runs, where))), source=str(p))


# (numeric columns, the runs of one label as (first row, end row, label), each body
# row's line number in the file)
_Runs = list[tuple[int, int, str]]
_Table = tuple[dict[str, np.ndarray], _Runs, Sequence[int]]


def _header(p: Path, row: list[str], columns: Mapping[str, str]) -> tuple[int, dict[str, int]]:
    """The header's cell count and each schema column's index (refusing what cannot be read)."""
    header = [h.strip().lower() for h in row]
    _check_separator(p, header)
    if header and all(_NUMBER.fullmatch(h) for h in header if h):
        shown = ", ".join(h for h in row[:4])
        msg = (
            f"{p}: no header line: the first line holds numbers ({shown}, ...), not column "
            "names; add a first line naming the columns, such as "
            f"t,voltage,current,position,speed (or your names with {opt('column')} NAME=HEADER)"
        )
        raise DataError(msg)
    header = _rename(p, header, columns)
    cols = {name: k for k, name in enumerate(header) if name in CSV_COLUMNS}
    dupes = sorted({h for h in header if h and header.count(h) > 1})
    if dupes:
        msg = f"{p}: repeated column(s) {', '.join(dupes)}"
        raise DataError(msg)
    if "t" not in cols:
        msg = f"{p}: missing column 't' (header has: {', '.join(header) or 'nothing'}){_hint(row)}"
        raise DataError(msg)
    if "position" not in cols and "speed" not in cols:
        msg = (
            f"{p}: needs a 'position' or 'speed' column (header has: {', '.join(header)})"
            f"{_hint(row)}"
        )
        raise DataError(msg)
    if "voltage" not in cols and "current" not in cols:
        msg = f"{p}: needs a 'voltage' column (or 'current' for current-driven data)"
        raise DataError(msg)
    return len(header), cols


def _hint(row: list[str]) -> str:
    """``; fix: --column t='t [s]' ...`` for header cells that are a column name with its
    unit or other text around it (``Time (s)``, ``speed_rad_s``), else ''."""
    found: list[str] = []
    aliases = {"time": "t", "volt": "voltage", "amp": "current", "pos": "position", "vel": "speed"}
    for cell in row:
        low = cell.strip().lower()
        if low in CSV_COLUMNS:
            continue
        for name in (*CSV_COLUMNS, *aliases):
            if low.startswith(name) and len(low) > len(name) and not low[len(name)].isalpha():
                target = aliases.get(name, name)
                if target not in [f.split("=")[0] for f in found]:
                    found.append(f"{target}={cell.strip()!r}")
                break
    if not found:
        return ""
    return "; fix: " + " ".join(f"{opt('column')} {f}" for f in found)


def _careful_table(p: Path, text: str, columns: Mapping[str, str]) -> _Table:
    rows, lines = _rows(p, text)
    if not rows:
        msg = f"{p}: empty file (expected a header row: t, voltage, current, speed...)"
        raise DataError(msg)
    n_header, cols = _header(p, rows[0], columns)
    body, where = rows[1:], lines[1:]
    if not body:
        msg = f"{p}: header only, no samples"
        raise DataError(msg)
    _check_cells(p, n_header, body, where)
    data: dict[str, np.ndarray] = {}
    for name in _NUMERIC:
        if name in cols:
            data[name] = _column(p, body, where, name, cols[name])
    if "segment" not in cols:
        return data, [(0, len(body), "run")], where
    labels = [r[cols["segment"]].strip() for r in body]
    runs: _Runs = []
    for k, label in enumerate(labels):
        if runs and runs[-1][2] == label:
            runs[-1] = (runs[-1][0], k + 1, label)
        else:
            runs.append((k, k + 1, label))
    return data, runs, where


def _fast_table(p: Path, columns: Mapping[str, str]) -> _Table | None:
    """A plain file through a compiled scan and numpy's C parser, or None for anything else.

    Plain: no quotes, comment or blank line after the header, every body line with
    exactly one cell per header column, every numeric cell a strict number (an empty
    voltage cell = open). The file is never held as Python strings (a 200 MB log was
    1 GB of them): :mod:`pmdc_ident.dataio.csv_scan` checks it mapped in memory,
    ``numpy.loadtxt`` converts it in chunks. Whatever is not plain goes to
    :func:`_careful_table`, which accepts a superset and names the line of any error;
    both give the same arrays on a plain file.
    """
    from pmdc_ident.dataio.csv_scan import PLAIN, scan_body

    try:
        if p.stat().st_size < 4:
            return None
        buf = np.memmap(p, dtype=np.uint8, mode="r")
    except (OSError, ValueError):
        return None
    try:
        head = _plain_header(buf)
        if head is None:
            return None
        line_no, header_cells, body_start = head
        try:
            n_header, cols = _header(p, header_cells, columns)
        except DataError:
            return None  # the careful reader says what is wrong, in its order
        names = {k: name for name, k in cols.items()}
        kinds = [
            2 if names.get(k) == "voltage" else 1 if names.get(k) in _NUMERIC else 0
            for k in range(n_header)
        ]
        status, rows, changes, chunks = scan_body(buf, body_start, kinds, cols.get("segment", -1))
        if status != PLAIN or rows == 0:
            return None
        runs: _Runs = [(0, rows, "run")]
        if "segment" in cols:
            try:
                labels = [bytes(buf[a:b]).decode("utf-8").strip() for _, a, b in changes]
            except UnicodeDecodeError:
                return None
            starts = [r for r, _, _ in changes]
            runs = [
                (r0, r1, lab)
                for r0, r1, lab in zip(starts, [*starts[1:], rows], labels, strict=True)
            ]
    finally:
        del buf  # unmapped: its pages leave this process's memory before the parse
    numeric = [(name, cols[name]) for name in _NUMERIC if name in cols]
    data = {name: np.empty(rows) for name, _ in numeric}
    done = 0
    try:
        with p.open("rb") as fh:
            for a, b in zip(chunks[:-1], chunks[1:], strict=True):
                fh.seek(a)
                part = _parse_chunk(fh.read(b - a), numeric)
                if part is None:
                    return None
                n = next(iter(part.values())).size
                if done + n > rows:
                    return None
                for name, values in part.items():
                    data[name][done : done + n] = values
                done += n
    except (ValueError, OSError):
        return None
    if done != rows:
        return None
    return data, runs, range(line_no + 1, line_no + 1 + rows)


def _parse_chunk(text: bytes, numeric: list[tuple[str, int]]) -> dict[str, np.ndarray] | None:
    """The numeric columns of a chunk of plain rows (numpy's C parser); None if odd."""
    import io

    dtype = np.dtype([(name, "S32" if name == "voltage" else "f8") for name, _ in numeric])
    table = np.loadtxt(
        io.BytesIO(text),
        delimiter=",",
        comments=None,
        usecols=[k for _, k in numeric],
        dtype=dtype,
        ndmin=1,
        quotechar=None,
    )
    out: dict[str, np.ndarray] = {}
    for name, _ in numeric:
        if name == "voltage":
            cells = table[name]
            cells[cells == b""] = b"nan"  # an empty cell: the armature open
            try:
                out[name] = cells.astype(np.float64)  # spaces around a number are fine
            except ValueError:  # a cell of spaces only
                stripped = np.char.strip(cells)
                stripped[stripped == b""] = b"nan"
                out[name] = stripped.astype(np.float64)
        else:
            out[name] = np.ascontiguousarray(table[name])
            if not np.isfinite(out[name]).all():
                return None
    return out


def _plain_header(buf: np.ndarray) -> tuple[int, list[str], int] | None:
    """(line number, cells, byte after it) of the header: the first line that is not
    blank or a comment (after a UTF-8 BOM); None when none is found early."""
    k = 3 if bytes(buf[:3]) == b"\xef\xbb\xbf" else 0
    line_no = 0
    while k < buf.size and line_no < 10_000:
        end = k
        while end < buf.size and buf[end] != 10:
            end += 1
            if end - k > 1_000_000:
                return None
        line_no += 1
        try:
            text = bytes(buf[k:end]).decode("utf-8")
        except UnicodeDecodeError:
            return None
        if "\x00" in text:
            return None
        k = end + 1
        if text.strip() and not text.lstrip().startswith("#"):
            return line_no, text.rstrip("\r").split(","), k
    return None


def _voltage_cell(cell: str) -> float:
    """An empty voltage cell is an open armature (NaN); a written NaN or inf is not plain."""
    if not cell.strip():
        return math.nan
    value = parse_number(cell.strip())
    if not math.isfinite(value):
        raise ValueError(cell)
    return value


def _text(p: Path) -> str:
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        msg = f"{p}: not a text (UTF-8) CSV file"
        raise DataError(msg) from None
    if "\x00" in text:
        msg = f"{p}: holds NUL bytes: a binary or UTF-16 file, not a UTF-8 CSV file"
        raise DataError(msg)
    return text


def _rows(p: Path, text: str) -> tuple[list[list[str]], list[int]]:
    """The rows of the file without blank and comment lines, and each row's line number."""
    numbered = [
        (k, line)
        for k, line in enumerate(text.splitlines(), start=1)
        if line.strip() and not line.lstrip().startswith("#")
    ]
    reader = csv.reader(line for _, line in numbered)
    rows: list[list[str]] = []
    lines: list[int] = []
    prev = 0  # lines the reader had consumed before the current row
    try:
        for row in reader:
            rows.append(row)
            lines.append(numbered[prev][0])  # a quoted cell may span lines: the row's first
            prev = reader.line_num
    except csv.Error as exc:
        line = numbered[min(prev, len(numbered) - 1)][0]
        msg = f"{p}: line {line}: not a CSV row ({exc})"
        raise DataError(msg) from None
    return rows, lines


def _check_separator(p: Path, header: list[str]) -> None:
    if len(header) == 1:
        for sep, name in ((";", "semicolons"), ("\t", "tabs")):
            if sep in header[0]:
                msg = (
                    f"{p}: the header is one cell holding {name} ({header[0][:40]!r}): "
                    "columns must be separated by commas"
                )
                raise DataError(msg)


def _check_cells(p: Path, n_header: int, body: list[list[str]], where: Sequence[int]) -> None:
    """Every row has one cell per header column (trailing empty cells are tolerated)."""
    for k, row in enumerate(body):
        if len(row) == n_header:
            continue
        if len(row) > n_header and not any(c.strip() for c in row[n_header:]):
            del row[n_header:]  # a trailing separator some tools write
            continue
        what = (
            "a cut-off line?"
            if len(row) < n_header
            else "which column are the extra for? a decimal comma (0,5) splits a number in "
            "two: write numbers with a point (0.5)"
        )
        msg = f"{p}: line {where[k]}: {len(row)} cells, the header has {n_header} ({what})"
        raise DataError(msg)


def _rename(p: Path, header: list[str], columns: Mapping[str, str]) -> list[str]:
    """The header with each ``columns`` entry's HEADER renamed to its schema NAME."""
    out = list(header)
    for name, wanted in columns.items():
        if name not in CSV_COLUMNS:
            why = f"{name}=...: {name!r} is not a column name ({', '.join(CSV_COLUMNS)})"
            raise DataOptionError("column", name, why)
        key = wanted.strip().lower()
        if key == "none":
            out = [f"(unused {h})" if h == name else h for h in out]
            continue
        if key not in header:
            msg = (
                f"{p}: no column {wanted!r} for {name!r} "
                f"(header has: {', '.join(header) or 'nothing'})"
            )
            raise DataError(msg)
        out = [f"(unused {h})" if h == name else h for h in out]
        out[header.index(key)] = name
    return out


def _column(p: Path, body: list[list[str]], where: Sequence[int], name: str, k: int) -> np.ndarray:
    out = np.empty(len(body))
    for i, row in enumerate(body):
        cell = row[k].strip()
        if cell == "":
            if name == "voltage":
                out[i] = math.nan  # armature open
                continue
            if all(not r[k].strip() for r in body):
                fix = f"{opt('column')} {name}=none (the file has no {name} measurement)"
            else:
                fix = "remove the row or fill the cell (a sample missing on one signal)"
            msg = (
                f"{p}: line {where[i]}: empty '{name}' cell (only voltage may be empty, "
                f"for an open armature); fix: {fix}"
            )
            raise DataError(msg)
        try:
            value = parse_number(cell)
        except ValueError:
            hint = ""
            if "_" in cell or "," in cell:
                hint = " (digits, one point and an exponent only: no digit separators)"
            elif name == "t" and any(c in cell for c in ":-/") and any(c.isdigit() for c in cell):
                hint = " (a date or clock time: t must be seconds, e.g. since the start)"
            msg = f"{p}: line {where[i]}: '{name}' is not a number: {cell[:20]!r}{hint}"
            raise DataError(msg) from None
        if not math.isfinite(value):
            if name == "voltage":
                hint = " (leave the voltage cell empty to mark an open armature)"
            elif cell.strip().lower() == "nan":
                hint = (
                    f" (a missing {name} measurement: remove the row; a gap in time is fitted "
                    f"around, or {opt('column')} {name}=none if the column holds none)"
                )
            else:
                hint = " (a value beyond any measurement: a logger overflow?)"
            msg = f"{p}: line {where[i]}: '{name}' is {cell[:20]!r}{hint}"
            raise DataError(msg)
        out[i] = value
    return out


def _check_time(p: Path, t: np.ndarray, where: Sequence[int]) -> None:
    """``t`` increases through the whole file, across segment boundaries too."""
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0])
        if t[k + 1] == t[k]:
            msg = (
                f"{p}: line {where[k + 1]}: time does not increase: t = {t[k]:.6g} s repeats "
                "the line before it (a duplicated row? remove it; t increases through the "
                "whole file)"
            )
            raise DataError(msg)
        msg = (
            f"{p}: line {where[k + 1]}: time does not increase "
            f"(t = {t[k + 1]:.6g} s after {t[k]:.6g} s; t increases through the whole file, "
            "across segments too: runs on clocks of their own go in separate files)"
        )
        raise DataError(msg)


def _segments(p: Path, data: dict[str, np.ndarray], runs: _Runs, where: Sequence[int]):  # type: ignore[no-untyped-def]
    seen: dict[str, int] = {}
    for start, stop, raw in runs:
        base = raw or "run"
        seen[base] = seen.get(base, 0) + 1
        label = base if seen[base] == 1 else f"{base}_{seen[base]}"
        if stop - start < 2:
            msg = f"{p}: segment {label!r} (line {where[start]}) has only one sample"
            raise DataError(msg)

        whole = start == 0 and stop == data["t"].size  # one segment: no copy of a long log

        def cut(
            name: str, lo: int = start, hi: int = stop, all_: bool = whole
        ) -> np.ndarray | None:
            arr = data.get(name)
            if arr is None:
                return None
            return arr if all_ else arr[lo:hi].copy()

        try:
            yield Segment(
                label=label,
                t=cut("t"),
                voltage=cut("voltage"),
                current=cut("current"),
                position=cut("position"),
                speed=cut("speed"),
                terminal_voltage=cut("terminal_voltage"),
            )
        except SignalRangeError as exc:  # which signal and value, for the unit hint
            raise exc.prefixed(f"{p}: ") from None
        except DataError as exc:
            msg = f"{p}: {exc}"
            raise DataError(msg) from None


def write_csv(run: Run | Iterable[Segment], path: str | Path | TextIO) -> Path | TextIO:
    """Write segments in the schema :func:`read_csv` reads (open armature -> empty cell).

    ``path`` is a file name or an open text stream (such as ``sys.stdout``).
    """
    segs = list(run.segments if isinstance(run, Run) else run)
    names = ["t"]
    for name in ("voltage", "current", "position", "speed", "terminal_voltage"):
        if any(getattr(s, name) is not None for s in segs):
            if not all(getattr(s, name) is not None for s in segs):
                msg = f"cannot write CSV: only some segments have a '{name}' signal"
                raise DataError(msg)
            names.append(name)
    if not isinstance(path, (str, Path)):
        _write_rows(path, names, segs)
        return path
    from pmdc_ident.core.safe_write import atomic_open

    p = Path(path)
    with atomic_open(p, "w", newline="") as fh:  # complete under its name, or not there
        _write_rows(fh, names, segs)
    return p


def _write_rows(fh: TextIO, names: list[str], segs: list[Segment]) -> None:
    w = csv.writer(fh, lineterminator="\n")
    w.writerow([*names, "segment"])
    for s in segs:
        arrays = [getattr(s, n) for n in names]
        for k in range(s.n):
            row = []
            for arr in arrays:
                v = float(arr[k])
                row.append("" if math.isnan(v) else repr(v))
            row.append(s.label)
            w.writerow(row)
