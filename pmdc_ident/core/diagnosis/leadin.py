"""Held-out predictions that start before the held-out segment (a lead-in).

A free-run prediction of a held-out segment needs the state at its first sample.
Read off a few samples, that state carries the sensors' noise: a speed
differentiated from a coarse encoder can be wrong by a fifth of the signal, and
the back-EMF error then shows as a current error of many noise levels over a
mechanical time constant, for every candidate alike, drowning the effects that the
scoring is there to see. Where the record runs on contiguously from an earlier
segment, the prediction therefore starts ``LEAD_IN_TAU`` mechanical time constants
earlier, from that segment's data, and is scored on the held-out samples only:
the initial-state error has decayed by then (the model is damped), and no
held-out sample is used to set a state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.estimators.output_error import FitResult, Prediction

__all__ = ["LEAD_IN_TAU", "LeadIn", "lead_ins", "predict_held_out"]

LEAD_IN_TAU = 6.0  # mechanical time constants simulated before a held-out segment
_SIGNALS = ("voltage", "current", "position", "speed", "terminal_voltage")


@dataclass(frozen=True)
class LeadIn:
    """A held-out segment extended at its front by ``samples`` earlier samples."""

    segment: Segment
    samples: int


def _continues(prev: Segment, seg: Segment) -> bool:
    """``seg`` follows ``prev`` in one record: same period, next sample, and its
    command history ends with ``prev``'s last command."""
    dt = prev.dt_s
    if abs(seg.dt_s - dt) > 0.01 * dt or abs(float(seg.t[0] - prev.t[-1]) - dt) > 0.5 * dt:
        return False
    hv, pv = seg.history_voltage, prev.voltage
    if hv is None or pv is None or hv.size == 0:
        return False
    a, b = float(hv[-1]), float(pv[-1])
    return (math.isnan(a) and math.isnan(b)) or a == b


def _extend(prev: Segment, seg: Segment, m: int) -> Segment | None:
    head = prev.slice(prev.n - m, prev.n)
    arrays = {}
    for name in _SIGNALS:
        a, b = getattr(head, name), getattr(seg, name)
        if (a is None) != (b is None):
            return None
        arrays[name] = None if a is None else np.concatenate([a, b])
    return Segment(
        label=seg.label,
        t=np.concatenate([head.t, seg.t]),
        kind=seg.kind,
        history_voltage=head.history_voltage,
        history_heat_a2s=head.history_heat_a2s,
        history_heat_profile=head.history_heat_profile,
        **arrays,
    )


def lead_ins(pieces: Sequence[Segment], held_out: Sequence[Segment], tau_s: float) -> list[LeadIn]:
    """For each held-out segment, itself with a lead-in from the piece (fit or held out)
    it continues, when there is one; ``pieces`` are all segments of the split."""
    out = []
    for seg in held_out:
        prev = next((p for p in pieces if p is not seg and _continues(p, seg)), None)
        ext = None
        if prev is not None and math.isfinite(tau_s) and tau_s > 0.0:
            m = min(prev.n - 1, max(2, math.ceil(LEAD_IN_TAU * tau_s / seg.dt_s)))
            ext = _extend(prev, seg, m) if m >= 2 else None
        out.append(LeadIn(seg, 0) if ext is None else LeadIn(ext, ext.n - seg.n))
    return out


def predict_held_out(fit: FitResult, leads: Sequence[LeadIn]) -> list[Prediction]:
    """The fit's free-run predictions of the held-out segments, each from its lead-in."""
    preds = fit.simulate_segments([li.segment for li in leads])
    out = []
    for li, p in zip(leads, preds, strict=True):
        k = li.samples
        if k == 0:
            out.append(p)
            continue
        out.append(Prediction(p.label, p.t[k:], p.current[k:], p.speed[k:], p.position[k:]))
    return out
