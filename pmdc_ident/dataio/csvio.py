"""CSV runs: the offline exchange format of DESIGN.md §4.

One header row, then one row per sample. Columns (names case-insensitive, any
order; unknown columns are ignored):

=================  =====  ==============================================
column             unit   meaning
=================  =====  ==============================================
``t``              s      sample time, strictly increasing within a segment
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

Lines starting with ``#`` are comments (provenance notes). Only an empty
voltage cell means "open"; a NaN written anywhere, an empty cell
in another column, a non-numeric cell or time that does not increase is refused
with one line naming the row and column.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable
from pathlib import Path
from typing import TextIO

import numpy as np

from pmdc_ident.core.data import Run, Segment, link_history
from pmdc_ident.core.errors import DataError

__all__ = ["CSV_COLUMNS", "read_csv", "write_csv"]

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


def read_csv(path: str | Path) -> Run:
    """Read a CSV run (schema in the module docs) into a :class:`Run`."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        msg = f"{p}: not a text (UTF-8) CSV file"
        raise DataError(msg) from None
    rows = list(
        csv.reader(
            line
            for line in text.splitlines()
            if line.strip() and not line.lstrip().startswith("#")
        )
    )
    if not rows:
        msg = f"{p}: empty file (expected a header row: t, voltage, current, speed...)"
        raise DataError(msg)
    header = [h.strip().lower() for h in rows[0]]
    cols = {name: k for k, name in enumerate(header) if name in CSV_COLUMNS}
    dupes = sorted({h for h in header if h and header.count(h) > 1})
    if dupes:
        msg = f"{p}: repeated column(s) {', '.join(dupes)}"
        raise DataError(msg)
    if "t" not in cols:
        msg = f"{p}: missing column 't' (header has: {', '.join(header) or 'nothing'})"
        raise DataError(msg)
    if "position" not in cols and "speed" not in cols:
        msg = f"{p}: needs a 'position' or 'speed' column (header has: {', '.join(header)})"
        raise DataError(msg)
    if "voltage" not in cols and "current" not in cols:
        msg = f"{p}: needs a 'voltage' column (or 'current' for current-driven data)"
        raise DataError(msg)
    body = rows[1:]
    if not body:
        msg = f"{p}: header only, no samples"
        raise DataError(msg)
    data: dict[str, np.ndarray] = {}
    for name in _NUMERIC:
        if name in cols:
            data[name] = _column(p, body, name, cols[name])
    labels = (
        [r[cols["segment"]].strip() if cols["segment"] < len(r) else "" for r in body]
        if "segment" in cols
        else ["run"] * len(body)
    )
    return Run(link_history(tuple(_segments(p, data, labels))), source=str(p))


def _column(p: Path, body: list[list[str]], name: str, k: int) -> np.ndarray:
    out = np.empty(len(body))
    for row_no, row in enumerate(body, start=2):
        cell = row[k].strip() if k < len(row) else ""
        if cell == "":
            if name == "voltage":
                out[row_no - 2] = math.nan  # armature open
                continue
            msg = f"{p}: row {row_no}: empty '{name}' cell (only voltage may be empty)"
            raise DataError(msg)
        try:
            value = float(cell)
        except ValueError:
            msg = f"{p}: row {row_no}: '{name}' is not a number: {cell[:20]!r}"
            raise DataError(msg) from None
        if not math.isfinite(value):
            hint = " (leave the voltage cell empty to mark an open armature)" * (name == "voltage")
            msg = f"{p}: row {row_no}: '{name}' is {cell!r}{hint}"
            raise DataError(msg)
        out[row_no - 2] = value
    return out


def _segments(p: Path, data: dict[str, np.ndarray], labels: list[str]) -> Iterable[Segment]:
    n = len(labels)
    seen: dict[str, int] = {}
    start = 0
    while start < n:
        stop = start + 1
        while stop < n and labels[stop] == labels[start]:
            stop += 1
        base = labels[start] or "run"
        seen[base] = seen.get(base, 0) + 1
        label = base if seen[base] == 1 else f"{base}_{seen[base]}"
        t = data["t"][start:stop]
        dt = np.diff(t)
        if (dt <= 0).any():
            k = int(np.argmax(dt <= 0)) + start
            msg = (
                f"{p}: row {k + 3}: time does not increase "
                f"(t = {data['t'][k + 1]:.6g} s after {data['t'][k]:.6g} s)"
            )
            raise DataError(msg)
        if stop - start < 2:
            msg = f"{p}: segment {label!r} (row {start + 2}) has only one sample"
            raise DataError(msg)

        def cut(name: str, lo: int = start, hi: int = stop) -> np.ndarray | None:
            arr = data.get(name)
            return None if arr is None else arr[lo:hi].copy()

        try:
            yield Segment(
                label=label,
                t=t.copy(),
                voltage=cut("voltage"),
                current=cut("current"),
                position=cut("position"),
                speed=cut("speed"),
                terminal_voltage=cut("terminal_voltage"),
            )
        except DataError as exc:
            msg = f"{p}: {exc}"
            raise DataError(msg) from None
        start = stop


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
    p = Path(path)
    with p.open("w", newline="") as fh:
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
