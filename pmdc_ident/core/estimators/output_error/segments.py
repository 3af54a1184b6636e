"""Segments prepared for the output-error fit: inputs, outputs, free initial states
and the per-signal noise levels the residuals are scaled by."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import DataError, ParameterError
from pmdc_ident.core.quantisation import quantisation_sd

__all__ = [
    "SIGNALS",
    "PreparedSegment",
    "initial_noise",
    "noise_level",
    "prepare_segments",
    "x0_from_data",
]

FloatArray = NDArray[np.float64]
SIGNALS = ("current", "speed", "position")


@dataclass
class PreparedSegment:
    """One segment as the fit sees it: its input, outputs and free initial states."""

    seg: Segment
    dt: float
    voltage: FloatArray | None  # None: current-driven (mechanical only)
    current_in: FloatArray  # measured current (input in current mode)
    outputs: list[tuple[int, FloatArray]]  # (state index 0/1/2, measured)
    nuis: list[int]  # state indices of the free initial states
    x0: FloatArray
    dJ: float = 0.0  # known inertia added for this segment (kg*m^2)


def x0_from_data(seg: Segment) -> FloatArray:
    """Initial state from a segment's first samples.

    Speed: a straight line through the first 5 samples, taken at t0 (a median or
    mean would lag a rotor that is already accelerating); from position alone, the
    slope at t0 of a parabola through the first 6 samples.
    """
    i0 = float(seg.current[0]) if seg.current is not None else 0.0
    if seg.voltage is not None and math.isnan(seg.voltage[0]):
        i0 = 0.0
    t = seg.t - seg.t[0]
    if seg.speed is not None:
        k = min(5, seg.n)
        w0 = float(np.polyfit(t[:k], seg.speed[:k], 1)[1]) if k >= 3 else float(seg.speed[0])
        if np.all(seg.speed[:k] == 0.0):
            w0 = 0.0
    else:
        assert seg.position is not None
        k = min(6, seg.n)
        deg = 2 if k >= 4 else 1
        w0 = float(np.polyfit(t[:k], seg.position[:k], deg)[deg - 1])
        if np.all(seg.position[:k] == seg.position[0]):
            w0 = 0.0
    th0 = float(seg.position[0]) if seg.position is not None else 0.0
    if abs(w0) < 1e-12:
        w0 = 0.0
    return np.array([i0, w0, th0])


def prepare_segments(
    segments: Sequence[Segment],
    warnings: list[str],
    added_inertia: Mapping[str, float] | None = None,
) -> list[PreparedSegment]:
    added = dict(added_inertia or {})
    unknown = sorted(set(added) - {s.label for s in segments})
    if unknown:
        msg = f"added inertia given for unknown segment(s): {', '.join(unknown)}"
        raise ParameterError(msg)
    for label, dj in added.items():
        if not (math.isfinite(dj) and dj >= 0.0):
            msg = f"added inertia of segment {label!r} must be >= 0 kg*m^2, got {dj}"
            raise ParameterError(msg)
    if not segments:
        msg = "no segments to fit"
        raise DataError(msg)
    modes = {s.voltage is None for s in segments}
    if len(modes) > 1:
        msg = "some segments have a voltage column and some do not; fit them separately"
        raise DataError(msg)
    out: list[PreparedSegment] = []
    jittery: list[str] = []
    for s in segments:
        if not s.is_uniform:
            jittery.append(s.label)
        outputs: list[tuple[int, FloatArray]] = []
        nuis: list[int] = []
        if s.voltage is None:
            if s.current is None:
                msg = f"segment {s.label!r}: without voltage the current column is needed"
                raise DataError(msg)
        else:
            nuis.append(0)
            if s.current is not None:
                outputs.append((0, s.current))
        nuis.append(1)
        if s.speed is not None:
            outputs.append((1, s.speed))
        else:
            assert s.position is not None
            outputs.append((2, s.position))
            nuis.append(2)
        cur = s.current if s.current is not None else np.zeros(s.n)
        out.append(
            PreparedSegment(
                s,
                s.dt_s,
                s.voltage,
                cur,
                outputs,
                nuis,
                x0_from_data(s),
                float(added.get(s.label, 0.0)),
            )
        )
    if jittery:
        warnings.append(
            "sample period not uniform (timestamp jitter above 1 %) in "
            f"{', '.join(jittery)}: each simulated on its median period"
        )
    return out


def noise_level(signal: int, y: FloatArray, seg: Segment, step: float | None = None) -> float:
    """Robust white-noise level from second differences, floored by resolution.

    ``step``: the signal's quantum over the whole record (``core.quantisation``);
    without it, the smallest difference between the segment's values.
    """
    if y.size < 8:
        return max(1e-9, float(np.std(y)), quantisation_sd(step or 0.0))
    d2 = np.diff(y, 2)
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    scale = float(np.max(np.abs(y))) or 1.0
    if step is None:
        step = float(np.min(np.abs(np.diff(np.unique(y))))) if np.unique(y).size > 1 else 0.0
    floor = max(1e-4 * scale, quantisation_sd(step), 1e-12)
    return max(sigma, floor)


def initial_noise(
    segs: list[PreparedSegment], steps: Mapping[str, float] | None = None
) -> dict[str, float]:
    """Per signal, the median over segments of :func:`noise_level` (``steps``: the
    quantum of each quantised signal over the record)."""
    steps = steps or {}
    per: dict[str, list[float]] = {}
    for ps in segs:
        for idx, y in ps.outputs:
            name = SIGNALS[idx]
            per.setdefault(name, []).append(noise_level(idx, y, ps.seg, steps.get(name)))
    return {k: float(np.median(v)) for k, v in per.items()}
