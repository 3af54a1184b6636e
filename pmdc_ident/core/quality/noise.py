"""Measurement noise per signal from the record alone (one estimator for the gate and
the diagnosis).

Two estimates, each of which errs high in its own case, and the smaller is kept:

* the robust spread of second differences (MAD / sqrt(6)) is right for a
  well-sampled signal but counts a signal that changes within a sample (a 50 Hz
  log of a motor whose current settles in a millisecond) as noise;
* the one-step prediction residual of a small ARX model (the signal's own past,
  the other signals now and one sample before, the direction of rotation) is right
  for that case but counts model error as noise; it is only computed where the
  first estimate is not already far below the signal's span.

A quantised signal is never quieter than its step / sqrt(12).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.quality.physics import noise_level
from pmdc_ident.core.quantisation import quantisation_sd, quantum

__all__ = ["arx_residual", "segment_noise", "signal_noise"]

FloatArray = NDArray[np.float64]
RESOLVED_SHARE = 0.01  # second-difference noise below this share of the span: resolved


def arx_residual(s: Segment, x: FloatArray) -> float | None:
    """RMS one-step prediction error of ``x`` from its past and the other signals."""
    if s.n < 20 or not np.isfinite(x).all():
        return None
    cols = [x[:-1], np.ones(s.n - 1)]
    for other in (s.voltage, s.current, s.speed):
        if other is not None and other is not x:
            o = np.nan_to_num(other)
            cols += [o[:-1], o[1:]]
    if s.speed is not None or s.position is not None:
        cols.append(np.sign(s.speed_or_derivative()[1:]))
    a = np.column_stack(cols)
    scale = np.sqrt((a * a).sum(axis=0))
    scale[scale == 0] = 1.0
    a /= scale
    coef = np.linalg.pinv(a.T @ a, rcond=1e-12) @ (a.T @ x[1:])
    resid = x[1:] - a @ coef
    dof = max(s.n - 1 - a.shape[1], 1)
    return float(np.sqrt(resid @ resid / dof))


def segment_noise(s: Segment, x: FloatArray, *, arx: bool = True) -> float:
    """Noise of ``x`` (a signal of ``s``): see the module notes."""
    est = noise_level(x)
    # a well-sampled signal's second differences are its noise; only a signal that
    # changes within a sample needs the (costlier) prediction residual
    if arx and not est < RESOLVED_SHARE * float(np.ptp(x)):
        r = arx_residual(s, x)
        if r is not None:
            est = min(est, r)
    q = quantum(x)
    floor = quantisation_sd(q.step) if q is not None else 0.0
    return max(est, floor, 1e-9 * float(np.sqrt(np.mean(x * x)) or 1.0))


def signal_noise(
    segments: Sequence[Segment],
    values: Callable[[Segment], FloatArray | None],
    *,
    arx: bool = True,
) -> float | None:
    """Median over the segments that carry a signal (``values(seg)``, None where
    absent) of :func:`segment_noise`; None when no segment carries it."""
    vals = []
    for s in segments:
        x = values(s)
        if x is None or x.size < 4:
            continue
        vals.append(segment_noise(s, np.asarray(x, dtype=float), arx=arx))
    return float(np.median(vals)) if vals else None
