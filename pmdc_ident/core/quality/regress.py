"""Quick least-squares looks at a record, for the gate (no fit, no simulation).

Each helper works over the samples of several segments at once and returns the
coefficients with their standard errors, so a check can ask "is this sign
certain?" before it speaks. The equations are the motor's, written over one
sample interval (ZOH voltage, trapezoidal current and speed)::

    V dt       = R ibar dt + L (i[k+1] - i[k]) + Ke wbar dt            (electrical)
    w[k+1]-w[k] = (a ibar - b wbar - c sign(wbar) - d) dt              (mechanical)

with ``a = Kt/J``, ``b = B/J``, ``c = Tc/J``, ``d = T_load/J``.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment

__all__ = [
    "MIN_DYNAMIC",
    "LinearFit",
    "arx_pole",
    "dynamic",
    "electrical_fit",
    "mechanical_fit",
    "memo",
    "memoised",
    "voltage_speed_response",
]


FloatArray = NDArray[np.float64]
# A segment with fewer samples is a table row group (steady-state levels), not a time series.
MIN_DYNAMIC = 20


_MEMO: dict[tuple, object] | None = None


@contextmanager
def memo() -> Iterator[None]:
    """Within this block, the fits below are computed once per set of segments."""
    global _MEMO
    outer = _MEMO
    _MEMO = {} if outer is None else outer
    try:
        yield
    finally:
        _MEMO = outer


def memoised(func):  # type: ignore[no-untyped-def]
    def wrapper(segments, *args, **kwargs):  # type: ignore[no-untyped-def]
        if _MEMO is None:
            return func(segments, *args, **kwargs)
        segs = tuple(segments)
        key = (func.__name__, tuple(id(s) for s in segs), args, tuple(sorted(kwargs.items())))
        if key not in _MEMO:
            _MEMO[key] = (segs, func(segs, *args, **kwargs))  # segs kept: ids stay valid
        return _MEMO[key][1]  # type: ignore[index]

    wrapper.__name__ = func.__name__
    wrapper.__doc__ = func.__doc__
    return wrapper


def dynamic(segments: Sequence[Segment]) -> list[Segment]:
    """The segments that are time series (not steady-state table rows)."""
    return [s for s in segments if s.n >= MIN_DYNAMIC]


@dataclass(frozen=True)
class LinearFit:
    """Coefficients of a least-squares fit, their standard errors and the sample count."""

    names: tuple[str, ...]
    coef: FloatArray
    stderr: FloatArray
    n: int
    rms: float
    quasi_static: bool = False

    def __getitem__(self, name: str) -> float:
        return float(self.coef[self.names.index(name)])

    def t(self, name: str) -> float:
        """The coefficient over its standard error (inf when exact)."""
        k = self.names.index(name)
        se = float(self.stderr[k])
        return float(self.coef[k]) / se if se > 0 else float(np.sign(self.coef[k])) * np.inf


def _lstsq(names: tuple[str, ...], a: FloatArray, y: FloatArray) -> LinearFit | None:
    keep = np.isfinite(a).all(axis=1) & np.isfinite(y)
    a, y = a[keep], y[keep]
    n, p = a.shape
    if n <= p + 2:
        return None
    scale = np.sqrt((a * a).sum(axis=0))
    used = scale > 0
    if not used.any():
        return None
    a_s = a[:, used] / scale[used]
    # normal equations on unit-norm columns: p is small, n large (much faster than an SVD)
    gram = a_s.T @ a_s
    cov_unit = np.linalg.pinv(gram, rcond=1e-12)
    coef_s = cov_unit @ (a_s.T @ y)
    resid = y - a_s @ coef_s
    dof = max(n - int(used.sum()), 1)
    s2 = float(resid @ resid) / dof
    cov = cov_unit * s2
    coef = np.zeros(p)
    se = np.full(p, np.inf)
    coef[used] = coef_s / scale[used]
    se[used] = np.sqrt(np.clip(np.diag(cov), 0.0, None)) / scale[used]
    return LinearFit(names, coef, se, n, float(np.sqrt(s2)))


@memoised
def electrical_fit(segments: Sequence[Segment]) -> LinearFit | None:
    """The armature equation over the driven intervals, in the form the record supports.

    ``V dt = R ibar dt + L di + Ke wbar dt + c dt`` (trapezoid) when the current's
    transients span samples; ``V[k] = R i[k+1] + Ke w[k+1] + c`` (quasi-static, L
    = 0) when they settle within a sample. The form with the smaller relative
    residual is returned (``quasi_static`` says which).
    """
    trap_rows: list[FloatArray] = []
    trap_ys: list[FloatArray] = []
    qs_rows: list[FloatArray] = []
    qs_ys: list[FloatArray] = []
    for s in dynamic(segments):
        if s.voltage is None or s.current is None:
            continue
        dt = np.diff(s.t)
        w = s.speed_or_derivative()
        driven = ~np.isnan(s.voltage[:-1])
        ib = 0.5 * (s.current[1:] + s.current[:-1])
        wb = 0.5 * (w[1:] + w[:-1])
        cols = np.column_stack([ib * dt, np.diff(s.current), wb * dt, dt])
        trap_rows.append(cols[driven])
        trap_ys.append((s.voltage[:-1] * dt)[driven])
        zero = np.zeros(s.n - 1)
        qs = np.column_stack([s.current[1:], zero, w[1:], np.ones(s.n - 1)])
        qs_rows.append(qs[driven])
        qs_ys.append(s.voltage[:-1][driven])
    if not trap_rows or not sum(len(y) for y in qs_ys):
        return None
    names = ("R", "L", "Ke", "offset")
    a_t, a_q = np.vstack(trap_rows), np.vstack(qs_rows)
    if np.ptp(np.concatenate(qs_ys)) == 0:
        # one held voltage: an offset would absorb it all (R = Ke = 0); no offset then
        a_t[:, 3] = 0.0
        a_q[:, 3] = 0.0
    trap = _lstsq(names, a_t, np.concatenate(trap_ys))
    qs_fit = _lstsq(names, a_q, np.concatenate(qs_ys))
    if trap is None or qs_fit is None:
        return trap
    scale_t = float(np.sqrt(np.mean(np.concatenate(trap_ys) ** 2))) or 1.0
    scale_q = float(np.sqrt(np.mean(np.concatenate(qs_ys) ** 2))) or 1.0
    if qs_fit.rms / scale_q < 0.5 * trap.rms / scale_t:
        return replace(qs_fit, quasi_static=True)
    return trap


@memoised
def mechanical_fit(segments: Sequence[Segment], *, coulomb: bool = True) -> LinearFit | None:
    """``dw = (a ibar - b wbar - c sign(wbar) - d) dt`` over all intervals (open: i = 0)."""
    rows: list[FloatArray] = []
    ys: list[FloatArray] = []
    for s in dynamic(segments):
        if s.current is None:
            continue
        dt = np.diff(s.t)
        w = s.speed_or_derivative()
        i = np.where(s.open_mask, 0.0, s.current)
        ib = 0.5 * (i[1:] + i[:-1])
        wb = 0.5 * (w[1:] + w[:-1])
        cols = [ib * dt, -wb * dt]
        if coulomb:
            cols.append(-np.sign(wb) * dt)
        cols.append(-dt)
        rows.append(np.column_stack(cols))
        ys.append(np.diff(w))
    if not rows:
        return None
    names = ("a", "b", "c", "d") if coulomb else ("a", "b", "d")
    return _lstsq(names, np.vstack(rows), np.concatenate(ys))


def arx_pole(
    y: FloatArray, inputs: Sequence[FloatArray], mask: NDArray[np.bool_] | None = None
) -> float | None:
    """Pole ``a`` of ``y[k+1] = a y[k] + sum b_j u_j[k] + c`` (per sample), or ``None``."""
    cols = [y[:-1], *[u[:-1] for u in inputs], np.ones(y.size - 1)]
    a = np.column_stack(cols)
    target = y[1:]
    if mask is not None:
        a, target = a[mask[:-1]], target[mask[:-1]]
    fit = _lstsq(tuple(f"x{k}" for k in range(a.shape[1])), a, target)
    if fit is None or not np.isfinite(fit.stderr[0]) or abs(fit.t("x0")) < 5:
        return None
    return float(fit.coef[0])


def voltage_speed_response(segments: Sequence[Segment]) -> tuple[float, float] | None:
    """Gain (rad/s per V) and time constant (s) of voltage -> speed, or ``None``.

    One first-order ARX ``w[k+1] = a w[k] + b v[k] + c`` over the driven samples of
    all dynamic segments together (a step holds its voltage: only several of them
    vary it), on their median period: with ``Kt = Ke`` the gain is
    ``Ke / (R B + Ke^2)`` and the time constant ``R J / (R B + Ke^2)`` (L neglected).
    """
    rows, ys, dts = [], [], []
    for s in dynamic(segments):
        if s.voltage is None:
            continue
        driven = (~s.open_mask)[:-1] & (~s.open_mask)[1:]
        if driven.sum() < 10:
            continue
        w = s.speed_or_derivative()
        rows.append(np.column_stack([w[:-1], s.voltage[:-1], np.ones(s.n - 1)])[driven])
        ys.append(w[1:][driven])
        dts.append(s.dt_s)
    if not rows:
        return None
    a = np.vstack(rows)
    if np.ptp(a[:, 1]) == 0:
        return None
    coef, *_ = np.linalg.lstsq(a, np.concatenate(ys), rcond=None)
    if not (0.0 < coef[0] < 1.0 and coef[1] > 0):
        return None
    return float(coef[1] / (1.0 - coef[0])), float(-np.median(dts) / np.log(coef[0]))
