"""Isolated outliers in a recording: found, reported with their rows, fitted around on request.

One current cell of 1000 A among 2000 samples of half an ampere (a logger glitch, a
mistyped cell) moved R by -76 % and J by +330 % with exit status 0: the fit read the
glitch as physics. A motor's signals cannot jump to a value far outside their own
range for one or two samples and come back (the winding's inductance and the rotor's
inertia forbid it), so such samples are found by a robust residual test:

* the residual of each sample against the median of the five samples around it (a
  median follows a step - a voltage edge, a wrap - but not a one- or two-sample
  spike);
* an outlier is a residual larger than half the signal's own range in its segment
  (0.5 to 99.5 percentile: the outliers themselves do not widen it) and larger than
  ``K_NOISE`` times the residuals' robust standard deviation, at a value outside
  that range by half its width, in at most two consecutive samples (a longer
  excursion is a real event, not a glitch; a pulse inside the range, a PRBS's, is a
  command);
* the sample must also jump away from both of its neighbours (a transient decays from
  its peak: the sample after it is still near it), and neither end of a segment is
  tested;
* the current is not tested within two samples of a voltage edge (a PRBS's one-sample
  pulse is a command, and the current follows it);
* a voltage sample inside the range the command swept in the ``LEAD_SAMPLES`` before
  it (the segment's history included) is the command, not a glitch: a segment marker
  that arrives a few samples after the command changed leaves the previous segment's
  last levels (a sweep's) at the start of the next one (a session's coast after its
  sweep: 6.18 V between 7.75 V and the 24 V spin-up, in range of the sweep's last
  samples, was refused as an outlier).

:func:`find_outliers` reports them (segment, sample, time, value, what the
neighbours read); :func:`drop_outliers` removes those samples, so the fit steps over
each as over a gap (``--drop-outliers``). Linear in the number of samples.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit
from pmdc_ident.core.data import Run, Segment, link_history

__all__ = ["K_NOISE", "Outlier", "drop_outliers", "find_outliers"]

FloatArray = NDArray[np.float64]
K_NOISE = 12.0  # robust standard deviations
MIN_SAMPLES = 9  # shorter segments (a table's few rows) are not tested
LEAD_SAMPLES = 50  # the voltage's own recent range (history included) a command stays in
SIGNALS = ("current", "speed", "position", "voltage", "terminal_voltage")
_UNITS = {"current": "A", "speed": "rad/s", "position": "rad", "voltage": "V"}


@dataclass(frozen=True)
class Outlier:
    """One sample of one signal that its neighbours contradict."""

    signal: str
    segment: str
    index: int  # in its segment
    row: int  # data row in the whole recording (0-based, over every segment in order)
    t_s: float
    value: float
    expected: float  # what the neighbours read (the median of five)
    score: float  # |value - expected| in robust standard deviations

    def describe(self, line: int | None = None) -> str:
        where = f"line {line}" if line is not None else f"data row {self.row + 1}"
        unit = _UNITS.get(self.signal, "V")
        return (
            f"{where} (t = {self.t_s:.6g} s, segment {self.segment!r}): {self.signal} "
            f"{self.value:.6g} {unit} where its neighbours read {self.expected:.4g} {unit}"
        )


@njit
def _median5_kernel(x, out):  # pragma: no cover - jitted
    n = x.size
    for k in range(n):
        v0 = x[min(max(k - 2, 0), n - 1)]
        v1 = x[min(max(k - 1, 0), n - 1)]
        v2 = x[k]
        v3 = x[min(k + 1, n - 1)]
        v4 = x[min(k + 2, n - 1)]
        # the nine-comparator sorting network for five; v2 ends as the median
        if v0 > v1:
            v0, v1 = v1, v0
        if v3 > v4:
            v3, v4 = v4, v3
        if v2 > v4:
            v2, v4 = v4, v2
        if v2 > v3:
            v2, v3 = v3, v2
        if v0 > v3:
            v0, v3 = v3, v0
        if v0 > v2:
            v0, v2 = v2, v0
        if v1 > v4:
            v1, v4 = v4, v1
        if v1 > v3:
            v1, v3 = v3, v1
        if v1 > v2:
            v1, v2 = v2, v1
        out[k] = v2


def _median5(x: FloatArray) -> FloatArray:
    """The running median of five (the ends padded with their own value), one compiled
    pass by the nine-comparator sorting network for five elements."""
    out = np.empty(x.size)
    if x.size:
        _median5_kernel(np.ascontiguousarray(x, dtype=np.float64), out)
    return out


def _filled(x: FloatArray) -> FloatArray:
    """``x`` with each NaN (an open armature's voltage) replaced by the value before it."""
    finite = np.isfinite(x)
    if finite.all():
        return x
    idx = np.where(finite, np.arange(x.size), 0)
    np.maximum.accumulate(idx, out=idx)
    out = x[idx]
    first = int(np.argmax(finite))
    out[:first] = x[first]
    return out


def _isolated(flag: NDArray[np.bool_], longest: int = 2) -> NDArray[np.bool_]:
    """``flag`` keeping only runs of at most ``longest`` consecutive True."""
    if not flag.any():
        return flag
    edges = np.diff(np.concatenate(([0], flag.view(np.int8), [0])))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    out = np.zeros_like(flag)
    for a, b in zip(starts, stops, strict=True):
        if b - a <= longest:
            out[a:b] = True
    return out


def _near_edges(
    v: FloatArray, width: int = 2, before: FloatArray | None = None
) -> NDArray[np.bool_]:
    """Samples within ``width`` of a change of the voltage command (an edge or opening).

    The first sample is one when the command before it (``before``: the segment's
    history) differs from it, or is unknown and the first sample drives the motor: a log
    that starts with its first level already on holds the current's transient from rest
    in its first samples (a 500 Hz log's peak at its second sample is physics)."""
    finite = np.isfinite(v)
    vv = np.where(finite, v, 0.0)
    span = float(np.ptp(vv[finite])) if finite.any() else 0.0
    change = np.zeros(v.size, dtype=bool)
    change[1:] = (np.abs(np.diff(vv)) > 0.01 * span) | (finite[1:] != finite[:-1])
    if v.size:
        prev = float(before[-1]) if before is not None and before.size else 0.0
        prev = prev if np.isfinite(prev) else 0.0
        change[0] = abs(float(vv[0]) - prev) > 0.01 * max(span, abs(float(vv[0])))
    near = change.copy()
    for k in range(1, width + 1):
        near[:-k] |= change[k:]
        near[k:] |= change[:-k]
    return near


def _signal_outliers(
    x: FloatArray, skip: NDArray[np.bool_] | None, before: FloatArray | None = None
) -> NDArray[np.intp]:
    """The isolated outliers of ``x`` (indices). ``before``: a command's samples before
    ``x`` (the segment's history voltage): a sample within the range of the
    :data:`LEAD_SAMPLES` before it is a command."""
    finite = np.isfinite(x)
    if finite.sum() < MIN_SAMPLES:
        return np.zeros(0, dtype=np.intp)
    xs = _filled(x)  # open-armature voltage cells: tested as the value before them
    lo, hi = np.percentile(x[finite], [0.5, 99.5])
    span = float(hi - lo)
    r = xs - _median5(xs)
    r[~finite] = 0.0
    sd = 1.4826 * float(np.median(np.abs(r[finite])))
    limit = max(K_NOISE * sd, 0.5 * span)
    if limit <= 0.0:  # a constant signal: any departure from it is one
        limit = 1e-12 * max(1.0, float(np.max(np.abs(x[finite]))))
    # a spike against its neighbours AND outside the signal's own range: a command's
    # one-sample pulse inside its range (a PRBS) is not a glitch
    outside = (x > hi + 0.5 * span) | (x < lo - 0.5 * span)
    flag = (np.abs(r) > limit) & finite & outside
    flag[:1] = flag[-1:] = False  # a record's end has a neighbour on one side only
    if skip is not None:
        flag &= ~skip
    flag = _isolated(flag)
    # a glitch jumps away from BOTH its unflagged neighbours and back (a transient
    # decays from its peak: the sample after it is still near it)
    idx = np.flatnonzero(flag)
    keep = []
    for k in idx.tolist():
        a = k - 1
        while a >= 0 and flag[a]:
            a -= 1
        b = k + 1
        while b < x.size and flag[b]:
            b += 1
        if a < 0 or b >= x.size:
            continue
        if min(abs(xs[k] - xs[a]), abs(xs[k] - xs[b])) > limit and not _in_lead(x, k, before):
            keep.append(k)
    return np.asarray(keep, dtype=np.intp)


def _in_lead(x: FloatArray, k: int, before: FloatArray | None) -> bool:
    """``x[k]`` lies within the range of the :data:`LEAD_SAMPLES` before it (``before``
    first), where ``before`` is given (a command's own recent levels)."""
    if before is None:
        return False
    lead = x[max(0, k - LEAD_SAMPLES) : k]
    if k < LEAD_SAMPLES and before.size:
        lead = np.concatenate((before[-(LEAD_SAMPLES - k) :], lead))
    lead = lead[np.isfinite(lead)]
    return bool(lead.size) and float(lead.min()) <= float(x[k]) <= float(lead.max())


def find_outliers(run: Run) -> list[Outlier]:
    """Every isolated outlier of every signal of ``run`` (see the module doc)."""
    found: list[Outlier] = []
    row0 = 0
    for seg in run.segments:
        near = (
            _near_edges(seg.voltage, before=seg.history_voltage)
            if seg.voltage is not None
            else None
        )
        for name in SIGNALS:
            x = getattr(seg, name)
            if x is None or seg.n < MIN_SAMPLES:
                continue
            x = np.asarray(x, dtype=float)
            skip = near if name in ("current", "terminal_voltage") else None
            before = None
            if name == "voltage":
                hv = seg.history_voltage
                before = np.asarray(hv, dtype=float) if hv is not None else np.zeros(0)
            idx = _signal_outliers(x, skip, before)
            if not idx.size:
                continue
            med = _median5(_filled(x))
            r = np.abs(x - med)
            sd = 1.4826 * float(np.median(r[np.isfinite(r)])) or 1e-300
            for k in idx.tolist():
                found.append(
                    Outlier(
                        name,
                        seg.label,
                        k,
                        row0 + k,
                        float(seg.t[k]),
                        float(x[k]),
                        float(med[k]),
                        float(r[k] / sd),
                    )
                )
        row0 += seg.n
    found.sort(key=lambda o: (o.row, o.signal))
    return found


def drop_outliers(run: Run, outliers: Sequence[Outlier]) -> Run:
    """``run`` without the samples of ``outliers`` (each becomes a gap the fit steps over)."""
    if not outliers:
        return run
    by_seg: dict[str, set[int]] = {}
    for o in outliers:
        by_seg.setdefault(o.segment, set()).add(o.index)
    segs: list[Segment] = []
    for seg in run.segments:
        gone = by_seg.get(seg.label)
        if not gone:
            segs.append(seg)
            continue
        keep = np.ones(seg.n, dtype=bool)
        keep[sorted(gone)] = False
        arrays = {
            name: (None if getattr(seg, name) is None else getattr(seg, name)[keep])
            for name in ("t", "voltage", "current", "position", "speed", "terminal_voltage")
        }
        segs.append(replace(seg, **arrays))
    return Run(link_history(segs), source=run.source)
