"""Does a segment continue the one before it? Judged from the samples (issue 22).

A clock that runs on does not make one record: a logger writing ``t = index / fs``,
or a script that joins runs, puts experiment B one sample period after the end of
experiment A while B starts from rest and A ended at speed. Read as a continuation,
B carries A's commands and heat as history and a held-out prediction of B starts from
A's end state: the diagnosis then calls every clean run ``unexplained``.

So a segment continues the one before only when, besides the time (one sample period
later, on the same period), its first samples follow from the previous one's last
within what this motor does in one sample: per measured signal (speed, current,
position), the jump across the boundary is at most :data:`MARGIN` times the largest
sample-to-sample change the record shows elsewhere, plus :data:`NOISE_SIGMAS` noise
levels and one quantum. Otherwise it is a separate run, started from its own first
sample. The bound is the record's own (no motor parameter is known when a file is
read), so it is unit-free: a log in rpm or mA is judged as in SI units.

Inside one unlabeled log the same rule finds where a new run starts
(:func:`restarts`): the rotor is at rest at that sample, and the speed or the
position jumped there beyond what the record does in one sample elsewhere (a
position that restarts at 0 with each run is a restart, not a wrap).

Pure numpy on arrays (no import of :mod:`pmdc_ident.core.data`, which calls this
module from :func:`~pmdc_ident.core.data.link_history`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pmdc_ident.core.data import Segment

__all__ = ["MARGIN", "NOISE_SIGMAS", "Jump", "boundary_jump", "restarts", "step_limits"]

FloatArray = NDArray[np.float64]
MARGIN = 1.5  # x the largest one-sample change seen elsewhere in the record
NOISE_SIGMAS = 6.0  # plus this many noise levels (and one quantum)
SIGNALS = ("speed", "position", "current")
_UNITS = {"speed": "rad/s", "position": "rad", "current": "A"}
_REGULAR = 0.25  # intervals off the median period by more than this are gaps, not samples


@dataclass(frozen=True)
class Jump:
    """A change across one sample interval beyond what the motor does in one sample."""

    signal: str
    before: float
    after: float
    limit: float

    def describe(self) -> str:
        unit = _UNITS.get(self.signal, "")
        return (
            f"{self.signal} {self.before:.4g} -> {self.after:.4g} {unit} in one sample, where "
            f"the record changes it by at most {self.limit:.3g} {unit}"
        )


def _noise(x: FloatArray) -> float:
    """Robust white-noise level from second differences (MAD)."""
    if x.size < 8:
        return 0.0
    d2 = np.diff(x, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _quantum(d: FloatArray) -> float:
    """The smallest nonzero change (a quantised signal's step; 0 when none repeats)."""
    nz = np.abs(d[d != 0.0])
    return float(nz.min()) if nz.size else 0.0


def _regular(t: FloatArray) -> NDArray[np.bool_]:
    dt = np.diff(t)
    if dt.size == 0:
        return np.zeros(0, dtype=bool)
    med = float(np.median(dt))
    return np.abs(dt - med) <= _REGULAR * med


def step_limits(segments: Sequence[Segment]) -> dict[str, float]:
    """Per measured signal, the largest change across one sample that still follows
    from the motor: ``MARGIN`` x the largest within-segment change, plus noise and one
    quantum (signals whose column no segment has are left out)."""
    out: dict[str, float] = {}
    for name in SIGNALS:
        big, sig, q = 0.0, [], []
        for s in segments:
            x = getattr(s, name)
            if x is None or s.n < 3:
                continue
            d = np.diff(x)[_regular(s.t)]
            if d.size == 0:
                continue
            big = max(big, float(np.max(np.abs(d))))
            sig.append(_noise(x))
            q.append(_quantum(d))
        if sig:
            out[name] = MARGIN * big + NOISE_SIGMAS * float(np.median(sig)) + max(q)
    return out


def boundary_jump(prev: Segment, seg: Segment, limits: dict[str, float]) -> Jump | None:
    """The first signal whose change from ``prev``'s last sample to ``seg``'s first
    exceeds its limit, or None when ``seg`` follows from ``prev``."""
    for name, limit in limits.items():
        a, b = getattr(prev, name), getattr(seg, name)
        if a is None or b is None:
            continue
        before, after = float(a[-1]), float(b[0])
        if abs(after - before) > limit:
            return Jump(name, before, after, limit)
    return None


def _speed(seg: Segment) -> FloatArray:
    """Speed at each sample: the column, else the forward difference of the position
    (a restart's jump then shows before it, not at the new run's first sample)."""
    if seg.speed is not None:
        return seg.speed
    assert seg.position is not None
    d = np.diff(seg.position) / np.diff(seg.t)
    return np.r_[d, d[-1:]] if d.size else np.zeros(seg.n)


def restarts(seg: Segment) -> list[tuple[int, Jump]]:
    """Samples of one continuous record at which a new run starts: the rotor is at rest
    there, and the speed or the position jumped onto it by more than
    ``MARGIN`` x the largest change across samples where the rotor does not come to
    rest, plus noise and one quantum."""
    if seg.n < 20:
        return []
    w = _speed(seg)
    regular = _regular(seg.t)
    w_scale = float(np.max(np.abs(w))) or 1.0
    w_noise, w_q = _noise(w), _quantum(np.diff(w))
    at_rest = np.abs(w) <= NOISE_SIGMAS * w_noise + w_q + 0.01 * w_scale
    landing = at_rest[1:]  # interval k -> k+1 ends with the rotor at rest
    out: dict[int, Jump] = {}
    for name in ("speed", "position"):
        x = getattr(seg, name)
        if x is None:
            continue
        d = np.diff(x)
        other = np.abs(d[regular & ~landing])
        if other.size == 0:
            continue
        limit = MARGIN * float(np.max(other)) + NOISE_SIGMAS * _noise(x) + _quantum(d)
        for k in np.flatnonzero(regular & landing & (np.abs(d) > limit)):
            k1 = int(k) + 1
            if name == "position" and not _restarted_position(x, k1, limit):
                continue  # a jump elsewhere than to a run's start: not this rule's
            out.setdefault(k1, Jump(name, float(x[k]), float(x[k1]), limit))
    return sorted(out.items())


def _restarted_position(x: FloatArray, k: int, limit: float) -> bool:
    """The position after the jump is where runs start: 0, or the record's first value."""
    return abs(float(x[k])) <= limit or abs(float(x[k] - x[0])) <= limit
