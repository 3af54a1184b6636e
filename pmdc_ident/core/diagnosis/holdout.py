"""Split the segments of a session into fit and held-out sets.

The default split keeps every test type in both sets, so a candidate effect is
judged on the same kinds of experiment it was fitted on, but on samples the fit
never saw:

* several segments of one kind (staircase levels, steps): alternate them, the
  first, third... are fitted and the second, fourth... held out (``step_up``
  fitted, ``step_down`` held out);
* a single segment of a kind (the sweep, the coast-down): cut it in time, the
  sweep into quarters (1st and 3rd fitted, 2nd and 4th held out, so both sets
  span low and high frequencies), any other into halves (first fitted); a segment
  that opens the armature is cut in the middle of its open part (both halves coast).

A piece cut in time keeps the samples before it as history (``Segment.slice``), so
a delay line and a resistance drift continue into it as they did in the motor.

``holdout_labels`` overrides the default: exactly those segments are held out.

:func:`swapped` exchanges the two sides (the other half of a two-fold
cross-validation): an effect confined to one regime that the default split fits
(the lowest staircase level, the opening step) is then judged where it is.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmdc_ident.core.data import Segment, TestKind
from pmdc_ident.core.errors import DataError, DataOptionError

__all__ = ["HoldoutSplit", "split_segments", "swapped"]

MIN_PIECE_SAMPLES = 2


@dataclass(frozen=True)
class HoldoutSplit:
    """The fit and held-out segments and how they were chosen."""

    fit: tuple[Segment, ...]
    held_out: tuple[Segment, ...]
    rule: str  # "default", "user" or "swapped" (the default's sides exchanged)
    description: tuple[str, ...]

    def to_json(self) -> dict[str, object]:
        return {
            "rule": self.rule,
            "fit_segments": [s.label for s in self.fit],
            "held_out_segments": [s.label for s in self.held_out],
            "description": list(self.description),
        }


def _pieces(seg: Segment, count: int) -> list[Segment]:
    n = seg.n
    edges = [round(k * n / count) for k in range(count + 1)]
    return [
        seg.slice(edges[k], edges[k + 1], label=f"{seg.label}[{k + 1}/{count}]")
        for k in range(count)
    ]


def _halves(seg: Segment) -> list[Segment]:
    """The segment in two halves, each with half of its open-armature samples when it
    has both driven and open ones: a coast-down shows B/J and the friction only while
    the armature is open, and a plain cut in time puts all of that on one side when
    the drive before it is as long (the fit then cannot know what it is scored on)."""
    v = seg.voltage
    idx = None
    if v is not None:
        open_k = np.flatnonzero(np.isnan(v))
        if 0 < open_k.size < seg.n:
            idx = int(open_k[open_k.size // 2])
    if idx is None or not MIN_PIECE_SAMPLES <= idx <= seg.n - MIN_PIECE_SAMPLES:
        return _pieces(seg, 2)
    return [
        seg.slice(0, idx, label=f"{seg.label}[1/2]"),
        seg.slice(idx, seg.n, label=f"{seg.label}[2/2]"),
    ]


def split_segments(
    segments: Sequence[Segment], holdout_labels: Sequence[str] | None = None
) -> HoldoutSplit:
    """Fit / held-out split (see the module notes); refuses a split with an empty side."""
    segs = tuple(segments)
    if not segs:
        msg = "no segments to diagnose"
        raise DataError(msg)
    if holdout_labels:
        wanted = list(dict.fromkeys(holdout_labels))
        known = {s.label for s in segs}
        unknown = [w for w in wanted if w not in known]
        if unknown:
            why = (
                f"names unknown segment(s) {', '.join(unknown)}; "
                f"segments are: {', '.join(s.label for s in segs)}"
            )
            raise DataOptionError("holdout", unknown, why)
        held = tuple(s for s in segs if s.label in wanted)
        fit = tuple(s for s in segs if s.label not in wanted)
        if not fit:
            why = "holds out every segment; at least one must remain to fit"
            raise DataOptionError("holdout", wanted, why)
        return HoldoutSplit(fit, held, "user", (f"held out by request: {', '.join(wanted)}",))

    fit: list[Segment] = []
    held: list[Segment] = []
    notes: list[str] = []
    by_kind: dict[TestKind, list[Segment]] = {}
    for s in segs:
        by_kind.setdefault(s.kind, []).append(s)
    for kind, group in by_kind.items():
        if len(group) >= 2:
            fit += group[0::2]
            held += group[1::2]
            notes.append(
                f"{kind.value}: alternate segments, fit {', '.join(s.label for s in group[0::2])}"
                f"; held out {', '.join(s.label for s in group[1::2])}"
            )
            continue
        seg = group[0]
        count = 4 if kind is TestKind.SWEEP else 2
        if seg.n < count * MIN_PIECE_SAMPLES:
            count = 2
        if seg.n < 2 * MIN_PIECE_SAMPLES:
            fit.append(seg)
            notes.append(f"{kind.value}: {seg.label} too short to split, fitted only")
            continue
        pieces = _pieces(seg, count) if count == 4 else _halves(seg)
        fit += pieces[0::2]
        held += pieces[1::2]
        how = (
            "quarters 1 and 3 fitted, 2 and 4 held out"
            if count == 4
            else ("first half fitted, second half held out")
        )
        notes.append(f"{kind.value}: {seg.label} cut in time, {how}")
    if not held:
        msg = "cannot hold out any data: every segment is too short to split"
        raise DataError(msg)
    return HoldoutSplit(tuple(fit), tuple(held), "default", tuple(notes))


def swapped(split: HoldoutSplit) -> HoldoutSplit:
    """The split with its sides exchanged: fitted on what ``split`` holds out, judged on
    what it fits (still on samples the fit never saw)."""
    return HoldoutSplit(
        split.held_out,
        split.fit,
        "swapped",
        (
            *split.description,
            "sides swapped: fitted on the held-out pieces above, judged on the fitted ones",
        ),
    )
