"""Automatic segmentation of one continuous, unlabeled log into experiments.

Users' logs are one long record without segment labels. The command (voltage,
or current for a current-driven drive) is cut into *holds* (runs of one value,
within its noise); holds much shorter than the longest ones form *active*
stretches, classified by what the command does there:

=============  ====================================================================
label          what the command does
=============  ====================================================================
``step_up``    jumps up (or is already on at the first sample, rotor at rest) and
``step_down``  holds long enough for the response to settle
``plateau``    holds after an active stretch (no clean step into it)
``prbs``       switches between at most three levels at irregular times
``sweep``      varies smoothly and oscillates (a chirp, a sine)
``excitation`` varies in any other way (multisine, noise, a controller's output)
``coast``      the armature is open (empty voltage) while the rotor turns
``open``       the armature is open and the rotor is at rest
=============  ====================================================================

Segments are numbered per label (``step_up_1``, ``step_up_2``...) and are cut
with :meth:`Segment.slice`, so each keeps the commands and heat before it as
history; the labels can be passed to ``diagnose --holdout``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit
from pmdc_ident.core.data import HISTORY_S, Run, Segment, link_history
from pmdc_ident.core.quality.timing import time_constants_s

__all__ = [
    "UNLABELED",
    "Piece",
    "contiguous_pieces",
    "find_segments",
    "is_unlabeled",
    "segment_run",
    "split_restarts",
]

FloatArray = NDArray[np.float64]
_MIN_HOLD = 20  # samples: a hold shorter than this is never a step of its own
_LONG_SHARE = 0.25  # a hold is long when it lasts this share of the 3rd-longest hold


@dataclass(frozen=True)
class Piece:
    """One experiment found in a record: samples ``start:stop`` and its label."""

    start: int
    stop: int
    label: str
    level: float  # mean command over the piece (V, or A when current-driven)

    def describe(self, seg: Segment, unit: str) -> str:
        t0, t1 = float(seg.t[self.start]), float(seg.t[self.stop - 1])
        level = "open" if np.isnan(self.level) else f"{self.level:.4g} {unit}"
        return f"{self.label} {t0:.4g}-{t1:.4g} s ({self.stop - self.start} samples, {level})"


UNLABELED = "run"  # the label of a log read without a segment column


def is_unlabeled(run: Run) -> bool:
    """True for a log read without a segment column: one segment called ``run``, or the
    separate runs it was cut into where a new run starts (``run.1``, ``run.2``...;
    :func:`split_restarts`)."""
    labels = [s.label for s in run.segments]
    if labels == [UNLABELED]:
        return True
    return len(labels) > 1 and labels == [f"{UNLABELED}.{k + 1}" for k in range(len(labels))]


def split_restarts(run: Run) -> Run:
    """An unlabeled log cut where a new run starts (:func:`core.continuity.restarts`: the
    rotor at rest after a jump of its speed or position beyond what the record does in
    one sample), each part (``run.1``, ``run.2``...) a separate run from its own first
    sample. The gate's ``continuity`` finding says so, once."""
    from pmdc_ident.core.continuity import restarts

    if [s.label for s in run.segments] != [UNLABELED]:
        return run
    seg = run.segments[0]
    cuts = [0, *(k for k, _ in restarts(seg)), seg.n]
    if len(cuts) == 2 or min(b - a for a, b in zip(cuts[:-1], cuts[1:], strict=True)) < 2:
        return run  # no restart (or a 'run' of one sample: a spike, not a restart)
    parts = []
    for a, b in zip(cuts[:-1], cuts[1:], strict=True):
        part = seg.slice(a, b, label=f"{UNLABELED}.{len(parts) + 1}")
        parts.append(
            replace(part, history_voltage=None, history_heat_a2s=None, history_heat_profile=None)
        )
    return Run(tuple(parts), source=run.source)


def _command(seg: Segment) -> tuple[FloatArray, str]:
    if seg.voltage is not None:
        return seg.voltage, "V"
    assert seg.current is not None
    return seg.current, "A"


def _tolerance(x: FloatArray) -> float:
    finite = x[np.isfinite(x)]
    if finite.size < 3:
        return 0.0
    d = np.diff(finite)
    small = d[np.abs(d) < 0.02 * (np.ptp(finite) or 1.0)]
    noise = float(np.median(np.abs(small))) * 1.4826 if small.size else 0.0
    return max(6.0 * noise, 0.01 * float(np.ptp(finite)), 1e-12)


@njit
def _hold_ends(x, tol, ends):  # pragma: no cover - jitted
    """End index of each hold of ``x`` into ``ends``; their number."""
    n = x.size
    m = 0
    start = 0
    while start < n:
        ref = x[start]
        k = start + 1
        while k < n and abs(x[k] - ref) <= tol:
            k += 1
        ends[m] = k
        m += 1
        start = k
    return m


def _holds(x: FloatArray, tol: float) -> list[tuple[int, int]]:
    """Runs of one value: each ends where the command leaves its first sample by ``tol``.

    One compiled pass (a chirp is a hold per sample: a Python loop per hold made the
    automatic segmentation of a 3.7 M-sample log take minutes)."""
    if x.size == 0:
        return []
    ends = np.empty(x.size, dtype=np.int64)
    m = _hold_ends(np.ascontiguousarray(x, dtype=np.float64), float(tol), ends)
    stops = ends[:m].tolist()
    return list(zip([0, *stops[:-1]], stops, strict=True))


def _classify_active(x: FloatArray, tol: float) -> str:
    levels = np.unique(np.round(x / (3 * tol)))
    edges = int(np.sum(np.abs(np.diff(x)) > tol))
    if levels.size <= 3 and edges >= 6:
        return "prbs"
    changing = float(np.mean(np.abs(np.diff(x)) > 0))
    centred = x - np.median(x)
    crossings = int(np.sum(np.signbit(centred[1:]) != np.signbit(centred[:-1])))
    if changing > 0.5 and crossings >= 4:
        return "sweep"
    return "excitation"


def _driven_pieces(
    x: FloatArray, w: FloatArray, offset: int, after_open: bool, long_hold: int
) -> list[tuple[int, int, str, float]]:
    tol = _tolerance(x)
    holds = _holds(x, tol)
    long_ = [hi - lo >= long_hold for lo, hi in holds]
    # a lone short hold (a rest) just before a long one is the start of that step
    for j in range(len(holds) - 1):
        alone = j == 0 or long_[j - 1]
        if not long_[j] and alone and long_[j + 1]:
            holds[j + 1] = (holds[j][0], holds[j + 1][1])
            holds[j] = (holds[j][0], holds[j][0])
    kept = [(h, lg) for h, lg in zip(holds, long_, strict=True) if h[1] > h[0]]
    holds, long_ = [h for h, _ in kept], [lg for _, lg in kept]
    out: list[tuple[int, int, str, float]] = []
    j = 0
    w_scale = float(np.max(np.abs(w))) or 1.0
    prev_level: float | None = None
    while j < len(holds):
        lo, hi = holds[j]
        if long_[j]:
            tail = x[max(lo, hi - long_hold // 2) : hi]
            level = float(np.mean(tail))
            head = float(x[lo])
            if abs(head - level) > tol:
                prev_level = head  # the rest before the step, inside this piece
            if prev_level is None:
                at_rest = abs(float(w[lo])) <= 0.05 * w_scale
                step = after_open or (at_rest and abs(level) > tol)
                kind = ("step_up" if level >= 0 else "step_down") if step else "plateau"
            elif out and out[-1][2] in ("prbs", "sweep", "excitation") and prev_level == head:
                kind = "plateau"
            else:
                kind = "step_up" if level > prev_level else "step_down"
            out.append((offset + lo, offset + hi, kind, level))
            prev_level = level
            j += 1
            continue
        k = j
        while k < len(holds) and not long_[k]:
            k += 1
        for a, b, kind in _active_runs(x, holds[j:k], tol):
            out.append((offset + a, offset + b, kind, float(np.mean(x[a:b]))))
        prev_level = float(x[holds[k - 1][1] - 1])
        j = k
    return out


def _active_runs(
    x: FloatArray, holds: list[tuple[int, int]], tol: float
) -> list[tuple[int, int, str]]:
    """An active stretch cut where its character changes (jumps between levels vs. smooth)."""
    a, b = holds[0][0], holds[-1][1]
    span = float(np.ptp(x[a:b])) or 1.0
    levels = np.array([float(x[lo]) for lo, _ in holds])
    jumps = np.abs(np.diff(levels)) > 0.3 * span
    types = np.r_[jumps[:1], jumps] if jumps.size else np.zeros(1, dtype=bool)
    # majority over +-8 holds: the character of the neighbourhood, not of one hold
    csum = np.r_[0.0, np.cumsum(types.astype(float))]
    idx = np.arange(types.size)
    lo_i, hi_i = np.maximum(idx - 8, 0), np.minimum(idx + 9, types.size)
    smooth = (csum[hi_i] - csum[lo_i]) / (hi_i - lo_i) > 0.5
    cuts = [0, *(np.flatnonzero(np.diff(smooth.astype(int))) + 1).tolist(), len(holds)]
    min_len = max(50, (b - a) // 20)
    pieces: list[list[int]] = []
    for first, last in zip(cuts[:-1], cuts[1:], strict=True):
        lo, hi = holds[first][0], holds[last - 1][1]
        if pieces and hi - lo < min_len:
            pieces[-1][1] = hi
        else:
            pieces.append([lo, hi])
    if len(pieces) > 1 and pieces[0][1] - pieces[0][0] < min_len:
        pieces[1][0] = pieces.pop(0)[0]
    out: list[tuple[int, int, str]] = []
    for lo, hi in pieces:
        kind = _classify_active(x[lo:hi], tol) if hi - lo > 2 else "plateau"
        if out and out[-1][2] == kind:
            out[-1] = (out[-1][0], hi, kind)
        else:
            out.append((lo, hi, kind))
    return out


def long_hold(parts: Sequence[Segment]) -> int:
    """Samples a hold must last to be a step of its own: three mechanical time constants
    (the speed settles) and a quarter of the record's third-longest hold."""
    lengths = [0]
    for seg in parts:
        x, _ = _command(seg)
        is_open = np.isnan(x)
        bounds = np.r_[0, np.flatnonzero(np.diff(is_open.astype(int))) + 1, seg.n]
        finite = x[~is_open]
        if finite.size:
            tol = _tolerance(finite)
            for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
                if not is_open[lo]:
                    lengths += [b - a for a, b in _holds(x[lo:hi], tol)]
    third = sorted(lengths)[-3] if len(lengths) >= 3 else max(lengths)
    # a step must last long enough for the speed to settle (3 mechanical time constants)
    _, tau_m = time_constants_s([w for seg in parts for w in _windows(seg)])
    settle = 3.0 * tau_m / parts[0].dt_s if tau_m else 0.0
    return max(_MIN_HOLD, int(_LONG_SHARE * third), int(settle))


def find_segments(seg: Segment, hold: int | None = None) -> list[Piece]:
    """The experiments in one continuous record (see the module table); ``hold``: the
    samples a step lasts at least (default: :func:`long_hold` of this record)."""
    x, _ = _command(seg)
    w = seg.speed_or_derivative()
    w_scale = float(np.max(np.abs(w))) or 1.0
    is_open = np.isnan(x)
    bounds = np.r_[0, np.flatnonzero(np.diff(is_open.astype(int))) + 1, seg.n]
    long_hold_ = long_hold([seg]) if hold is None else hold
    raw: list[tuple[int, int, str, float]] = []
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        if is_open[lo]:
            moving = abs(float(w[lo])) > 0.05 * w_scale
            raw.append((int(lo), int(hi), "coast" if moving else "open", float("nan")))
        else:
            after_open = lo > 0
            raw += _driven_pieces(x[lo:hi], w[lo:hi], int(lo), after_open, long_hold_)
    return _numbered(_merge_short(raw))


_WINDOWS, _WINDOW = 8, 25_000  # samples: the time constants of a long log from its windows


def _windows(seg: Segment) -> list[Segment]:
    """``[seg]``, or for a long record evenly spaced windows of it (the time constants are
    properties of the motor: a regression over every sample of an hour-long log cost
    seconds for the same value)."""
    if seg.n <= _WINDOWS * _WINDOW:
        return [seg]
    starts = [round(k * (seg.n - _WINDOW) / (_WINDOWS - 1)) for k in range(_WINDOWS)]
    return [_piece(seg, a, a + _WINDOW, f"{seg.label}.w{k}") for k, a in enumerate(starts)]


def _merge_short(raw: list[tuple[int, int, str, float]]) -> list[tuple[int, int, str, float]]:
    """Pieces under the minimum length join the piece before them (or after, at the start)."""
    out: list[tuple[int, int, str, float]] = []
    for piece in raw:
        if piece[1] - piece[0] < _MIN_HOLD // 2 and out:
            lo, _, kind, level = out[-1]
            out[-1] = (lo, piece[1], kind, level)
        else:
            out.append(piece)
    if len(out) > 1 and out[0][1] - out[0][0] < _MIN_HOLD // 2:
        first = out.pop(0)
        lo, hi, kind, level = out[0]
        out[0] = (first[0], hi, kind, level)
    return out


def _numbered(raw: Sequence[tuple[int, int, str, float]]) -> list[Piece]:
    count: dict[str, int] = {}
    out = []
    for lo, hi, kind, level in raw:
        count[kind] = count.get(kind, 0) + 1
        out.append(Piece(lo, hi, f"{kind}_{count[kind]}", level))
    return out


def segment_run(run: Run) -> tuple[Run, list[str]]:
    """``run`` cut into its experiments when it is unlabeled, with one line per segment
    (each separate run of a log cut at its restarts is cut on its own; the labels are
    numbered over the whole log)."""
    if not is_unlabeled(run):
        return run, []
    hold = long_hold(run.segments)  # one rule over the whole log, however it is cut
    found = [(part, find_segments(part, hold)) for part in run.segments]
    if len(found) == 1:
        pieces = found[0][1]
        if not pieces or (len(pieces) == 1 and pieces[0].label.startswith(("plateau", "excit"))):
            return run, []
    count: dict[str, int] = {}
    segs: list[Segment] = []
    lines: list[str] = []
    for part, pieces in found:
        _, unit = _command(part)
        numbered: list[Piece] = []
        for p in pieces or [Piece(0, part.n, "excitation_0", float("nan"))]:
            kind = p.label.rsplit("_", 1)[0]
            count[kind] = count.get(kind, 0) + 1
            numbered.append(replace(p, label=f"{kind}_{count[kind]}"))
            lines.append(numbered[-1].describe(part, unit))
        segs += _cut(part, numbered)  # within one run; the runs stay separate
    return Run(tuple(segs), source=run.source), lines


def _cut(seg: Segment, pieces: Sequence[Piece]) -> list[Segment]:
    """``seg`` cut into ``pieces``, each continuing the one before it.

    ``link_history`` gives each piece the history of the piece before (its commands and
    heat), linear in the record; ``Segment.slice`` would sum the whole record before each
    piece (quadratic on a long log)."""
    segs = [seg.slice(pieces[0].start, pieces[0].stop, label=pieces[0].label)]
    segs += [_piece(seg, p.start, p.stop, p.label) for p in pieces[1:]]
    linked = list(link_history(segs))
    if seg.voltage is not None and seg.history_voltage is None:
        # the commands before each piece as a view of the record's own (no copy per piece)
        keep = int(math.ceil(HISTORY_S / seg.dt_s))
        for k, p in enumerate(pieces[1:], start=1):
            if linked[k].history_voltage is not None:
                view = seg.voltage[max(0, p.start - keep) : p.start]
                linked[k] = replace(linked[k], history_voltage=view)
    return linked


def _piece(seg: Segment, start: int, stop: int, label: str) -> Segment:
    """Samples ``start:stop`` of ``seg`` without history (``link_history`` adds it)."""
    names = ("t", "voltage", "current", "position", "speed", "terminal_voltage")
    arrays = {n: (None if getattr(seg, n) is None else getattr(seg, n)[start:stop]) for n in names}
    return replace(
        seg,
        label=label,
        history_voltage=None,
        history_heat_a2s=None,
        history_heat_profile=None,
        **arrays,
    )


def contiguous_pieces(
    seg: Segment, *, jitter: float = 0.25, min_samples: int = 21
) -> tuple[list[Segment], int]:
    """The stretches of ``seg`` between its gaps in time, and the number of gaps.

    A gap is a sample interval off the median period by more than ``jitter`` of it
    (dropped samples, a paused logger). Each stretch of at least ``min_samples``
    becomes a segment ``label.1``, ``label.2``... (a fit gives each its own initial
    state); shorter stretches are left out. A stretch after a gap keeps the heat
    before it but not the commands (their timing across the gap is unknown).
    """
    dt = np.diff(seg.t)
    breaks = np.flatnonzero(np.abs(dt - seg.dt_s) > jitter * seg.dt_s) + 1
    bounds = [0, *breaks.tolist(), seg.n]
    pieces = []
    for lo, hi in zip(bounds[:-1], bounds[1:], strict=True):
        if hi - lo < min_samples:
            continue
        piece = seg.slice(lo, hi, label=f"{seg.label}.{len(pieces) + 1}")
        pieces.append(piece if lo == 0 else replace(piece, history_voltage=None))
    return pieces, int(breaks.size)
