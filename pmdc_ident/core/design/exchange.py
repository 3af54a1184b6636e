"""A plan in the CSV exchange format, so any simulator or rig can play it.

Columns ``t`` (s, from 0 on the plan's sample grid), ``voltage`` (V, empty while the
armature is open) and ``segment`` (the label); ``#`` lines before the header say what
the plan is. A rig that plays it row by row and logs ``current`` and ``position`` or
``speed`` beside the same ``t`` and ``segment`` columns gives a file ``pmdc-ident
identify`` fits. Pure text in and out (the command writes the file).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.excitation import PlannedSegment, TestPlan

__all__ = ["plan_csv_text", "plan_from_csv_text"]


def plan_csv_text(plan: TestPlan, comments: Sequence[str] = ()) -> str:
    lines = [f"# {c}" for c in comments]
    lines.append("t,voltage,segment")
    k = 0
    for seg in plan.segments:
        for v in seg.voltage:
            cell = "" if math.isnan(v) else f"{v:.9g}"
            lines.append(f"{k * plan.dt_s:.9g},{cell},{seg.label}")
            k += 1
    return "\n".join(lines) + "\n"


def plan_from_csv_text(text: str, source: str = "plan") -> TestPlan:
    """The plan a CSV of :func:`plan_csv_text`'s form holds (one line on bad input)."""
    rows = [ln for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    if not rows:
        raise DataError(f"{source}: no header (expected t,voltage,segment)")
    header = [h.strip() for h in rows[0].split(",")]
    try:
        it, iv, isg = header.index("t"), header.index("voltage"), header.index("segment")
    except ValueError:
        raise DataError(
            f"{source}: header must hold t, voltage and segment, got {rows[0]!r}"
        ) from None
    t, v, labels = [], [], []
    for n, line in enumerate(rows[1:], start=2):
        cells = line.split(",")
        if len(cells) < len(header):
            raise DataError(f"{source}: row {n} has {len(cells)} cells, the header {len(header)}")
        try:
            t.append(float(cells[it]))
            cell = cells[iv].strip()
            v.append(math.nan if cell == "" else float(cell))
        except ValueError:
            raise DataError(
                f"{source}: row {n}: not a number in t or voltage ({line!r})"
            ) from None
        if not math.isfinite(t[-1]) or (cell and not math.isfinite(v[-1])):
            raise DataError(f"{source}: row {n}: t and voltage must be finite ({line!r})")
        labels.append(cells[isg].strip())
    if len(t) < 2:
        raise DataError(f"{source}: a plan needs at least two rows")
    ta = np.asarray(t)
    d = np.diff(ta)
    if np.any(d <= 0):
        raise DataError(f"{source}: t must increase from row to row")
    dt = float(np.median(d))
    if np.max(np.abs(d - dt)) > 1e-6 * dt + 1e-12:
        raise DataError(f"{source}: t is not on one sample grid (a plan plays one sample per row)")
    va = np.asarray(v)
    segs: list[PlannedSegment] = []
    start = 0
    for k in range(1, len(labels) + 1):
        if k == len(labels) or labels[k] != labels[start]:
            if not labels[start]:
                raise DataError(f"{source}: row {start + 2} has no segment label")
            if any(s.label == labels[start] for s in segs):
                raise DataError(f"{source}: segment {labels[start]!r} appears twice, apart")
            segs.append(PlannedSegment(labels[start], va[start:k].copy()))
            start = k
    return TestPlan(tuple(segs), dt)
