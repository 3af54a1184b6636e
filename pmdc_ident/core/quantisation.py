"""Quantised signals (encoders, counters, ADCs): their step, and the noise it adds.

One rule for the data-quality gate, which reports an encoder's counts per turn
from the position's step, and for the output-error fit, whose noise model holds
each quantised signal at no less than its step / sqrt(12) (the standard
deviation of rounding to the step).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment

__all__ = ["Quantum", "quantisation_sd", "quantum", "record_steps"]

FloatArray = NDArray[np.float64]
_SIGNALS = ("current", "speed", "position")


@dataclass(frozen=True)
class Quantum:
    """The step of a quantised signal and how many distinct levels it visits."""

    step: float
    levels: int

    @property
    def counts_per_rev(self) -> float:
        """Counts per shaft turn of an encoder whose step (in rad) this is."""
        return 2.0 * math.pi / self.step


def quantisation_sd(step: float) -> float:
    """Standard deviation of rounding to ``step``."""
    return step / math.sqrt(12.0)


def quantum(x: FloatArray) -> Quantum | None:
    """The step ``q`` when every change of ``x`` is a whole multiple of one ``q``.

    Changes below 1e-12 of the span (float rounding of a unit conversion) are no
    change; ``None`` when fewer than 20 changes are seen or they are no multiples
    of one step (within 2 % for 95 % of them).
    """
    d = np.abs(np.diff(x))
    span = float(np.ptp(x)) if x.size else 0.0
    d = d[(d > 1e-12 * max(span, 1e-300)) & (d < 0.5 * span)]
    if d.size < 20:
        return None
    q0 = float(np.min(d))
    r = d / q0
    if float(np.median(r)) > 1e4:
        return None
    k = np.round(r)
    err = np.abs(r - k)
    if float(np.percentile(err, 95)) > 0.02:
        return None
    q = float(np.sum(d * k) / np.sum(k * k))
    levels = int(np.unique(np.round(x / q)).size)
    return Quantum(q, levels)


def record_steps(
    segments: Sequence[Segment], signals: Sequence[str] = _SIGNALS
) -> dict[str, Quantum]:
    """The quantum of each measured signal over the whole record (all segments).

    Positions are taken from each segment's first sample (an encoder's steps do
    not line up across a re-zeroed segment). Signals that are not quantised are
    left out.
    """
    out: dict[str, Quantum] = {}
    for name in signals:
        arrs = [getattr(s, name) for s in segments if getattr(s, name) is not None]
        if not arrs:
            continue
        if name == "position":
            arrs = [a - a[0] for a in arrs]
        q = quantum(np.concatenate(arrs))
        if q is not None:
            out[name] = q
    return out
