"""Equation-error (ARX-type) regression on the exactly discretised equations.

A fast, non-iterative start for the output-error fit. Over every pair of
consecutive samples with the armature closed, the exact ZOH model reads::

    [i, w][k+1] = Phi [i, w][k] + Gamma_V V[k] + Gamma_T (Tc sign(w[k]) + T_load)

which is linear in the entries of ``Phi`` and ``Gamma``; both rows are solved by
least squares and mapped back to the continuous parameters through the matrix
logarithm (``A = log(Phi)/dt``, ``B = A (Phi - I)^-1 Gamma``). When the
electrical time constant is far below the sample period (``Phi_ii`` near 0,
the logarithm ill-posed), a quasi-static form is used instead: ``V = R i + Ke
w`` on the samples and the mechanical row alone, with ``L`` left unknown.

Equation error is biased when the regressors are noisy (errors in variables);
that is why it only starts the output-error fit and is reported for comparison.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import DataError

__all__ = [
    "ONE_DIRECTION_NOTE",
    "EquationErrorResult",
    "fit_equation_error",
    "fit_mechanical_equation_error",
    "one_direction",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class EquationErrorResult:
    values: dict[str, float]  # R, L (may be absent), Ke, Kt, J, B, coulomb/load torques
    method: str  # "zoh-log" or "quasi-static"
    n_samples: int
    notes: tuple[str, ...]


def _rows(segments: Sequence[Segment]) -> tuple[FloatArray, ...]:
    cols: list[list[FloatArray]] = [[] for _ in range(7)]
    dts = []
    for s in segments:
        dt = np.diff(s.t)
        if s.voltage is None or s.current is None or s.n < 4:
            continue
        if np.any(np.abs(dt - s.dt_s) > 0.25 * s.dt_s):  # gaps: not one sample period
            continue
            continue
        w = s.speed_or_derivative()
        v = s.voltage
        ok = ~np.isnan(v[:-1]) & ~np.isnan(v[1:])
        if ok.sum() < 3:
            continue
        idx = np.nonzero(ok)[0]
        cols[0].append(s.current[idx])
        cols[1].append(w[idx])
        cols[2].append(v[idx])
        cols[3].append(np.sign(w[idx]))
        cols[4].append(s.current[idx + 1])
        cols[5].append(w[idx + 1])
        cols[6].append(np.full(idx.size, s.dt_s))
        dts.append(s.dt_s)
    if not dts:
        msg = "equation error needs regularly sampled segments with voltage and current"
        raise DataError(msg)
    return tuple(np.concatenate(c) for c in cols)


def fit_equation_error(
    segments: Sequence[Segment],
    *,
    coulomb: bool = True,
    Kt: float | None = None,
    J: float | None = None,
) -> EquationErrorResult:
    """Regress the discretised equations (see module docs); Kt = Ke unless Kt or J given."""
    i0, w0, v0, s0, i1, w1, dts = _rows(segments)
    dt = float(np.median(dts))
    n = i0.size
    notes: list[str] = []
    direction = one_direction(w0)
    if coulomb and direction:
        # sign(w) is the constant column: Coulomb friction and a constant load are one term
        coulomb = False
        notes.append(ONE_DIRECTION_NOTE)
    ones = np.ones(n)
    regs = [i0, w0, v0] + ([s0] if coulomb else []) + [ones]
    X = np.column_stack(regs)
    if np.linalg.matrix_rank(X) < X.shape[1]:
        # e.g. one held voltage (a step already on at the first sample): V and the
        # constant are one column; the quasi-static equations still separate R and Ke
        if np.linalg.matrix_rank(np.column_stack([i1, w1])) < 2 or np.ptp(w0) == 0:
            msg = (
                "no excitation: voltage, current and speed do not vary enough to identify anything"
            )
            raise DataError(msg)
        values = _quasi_static(i0, w0, v0, s0, i1, w1, dt, coulomb, Kt, J)
        notes.append(
            "equation error: the voltage is one held value, so the discretised regression "
            "is singular; quasi-static equations used (L not estimated)"
        )
        return EquationErrorResult(_one_term(values, direction), "quasi-static", n, tuple(notes))
    ci, *_ = np.linalg.lstsq(X, i1, rcond=None)
    cw, *_ = np.linalg.lstsq(X, w1, rcond=None)
    phi = np.array([[ci[0], ci[1]], [cw[0], cw[1]]])
    gv = np.array([ci[2], cw[2]])
    gs = np.array([ci[3], cw[3]]) if coulomb else np.zeros(2)
    g1 = np.array([ci[-1], cw[-1]])
    values: dict[str, float] | None = None
    if phi[0, 0] > 0.05:
        values = _from_zoh(phi, gv, gs, g1, dt, Kt, J)
        method = "zoh-log"
    if values is None:
        values = _quasi_static(i0, w0, v0, s0, i1, w1, dt, coulomb, Kt, J)
        method = "quasi-static"
        why = (
            "the current settles within a sample"
            if phi[0, 0] <= 0.05
            else "the exact-discretisation regression was not physical (noisy or derived speed)"
        )
        notes.append(
            f"equation error: {why}; quasi-static electrical equation used, L not estimated"
        )
    return EquationErrorResult(_one_term(values, direction), method, n, tuple(notes))


ONE_DIRECTION_NOTE = (
    "the rotor turns one way only: Coulomb friction and a constant load torque act as one "
    "term (their sum is fitted); a run in reverse separates them"
)


def one_direction(w: FloatArray) -> float:
    """+1 or -1 when the speed never turns the other way (beyond 2 % of its peak), else 0."""
    peak = float(np.max(np.abs(w))) if w.size else 0.0
    if peak == 0.0:
        return 0.0
    if np.all(w >= -0.02 * peak):
        return 1.0
    if np.all(w <= 0.02 * peak):
        return -1.0
    return 0.0


def _one_term(values: dict[str, float], direction: float) -> dict[str, float]:
    """One direction: the constant torque is reported as the Coulomb term (their sum)."""
    if not direction:
        return values
    out = dict(values)
    total = out.pop("load_torque.torque_nm", 0.0) * direction
    out["coulomb_friction.torque_nm"] = out.get("coulomb_friction.torque_nm", 0.0) + total
    return out


def _scale(values: dict[str, float], Kt: float | None, J: float | None, kt_over_j: float) -> None:
    if Kt is not None:
        kt = Kt
    elif J is not None:
        kt = kt_over_j * J
    else:
        kt = values["Ke"]  # closure Kt = Ke
    values["Kt"] = kt
    values["J"] = kt / kt_over_j


def logm_2x2(phi: FloatArray) -> FloatArray | None:
    """The principal logarithm of a real 2x2 matrix, ``None`` when it is not real (an
    eigenvalue on the negative real axis or zero).

    With eigenvalues s +- d: log(phi) = log sqrt(s^2 - d^2) I + f (phi - s I), f the
    divided difference of log, atanh(d/s)/d for real d and atan(|d|/s)/|d| for
    imaginary d (a pair of complex eigenvalues), 1/s at d = 0. Closed form, so no
    scipy.linalg import for the 2x2 state matrix of the discretised motor.
    """
    e = phi - np.eye(2)
    if float(np.max(np.abs(e))) < 0.5:
        # near the identity (phi = exp(A dt), dt small) in terms of E = phi - I: the
        # logarithm is small and log det = log1p(tr E + det E) keeps its digits
        half_tr = 0.5 * float(e[0, 0] + e[1, 1])
        det_e = float(e[0, 0] * e[1, 1] - e[0, 1] * e[1, 0])
        s, d2 = 1.0 + half_tr, half_tr * half_tr - det_e
        log_det = math.log1p(2.0 * half_tr + det_e) if 2.0 * half_tr + det_e > -1.0 else None
    else:
        s = 0.5 * float(phi[0, 0] + phi[1, 1])
        det = float(phi[0, 0] * phi[1, 1] - phi[0, 1] * phi[1, 0])
        d2 = s * s - det
        log_det = math.log(det) if det > 0.0 else None
    # s +- sqrt(d2) are the eigenvalues
    if log_det is None or not (math.isfinite(s) and math.isfinite(d2)):
        return None
    if d2 >= 0.0:
        d = math.sqrt(d2)
        if s - d <= 0.0:  # an eigenvalue on the closed negative real axis
            return None
        f = math.atanh(d / s) / d if d > 1e-8 * s else (1.0 + d2 / (3.0 * s * s)) / s
    else:
        im = math.sqrt(-d2)
        f = math.atan2(im, s) / im
    return 0.5 * log_det * np.eye(2) + f * (phi - s * np.eye(2))


def _from_zoh(phi, gv, gs, g1, dt, Kt, J) -> dict[str, float] | None:
    log_phi = logm_2x2(np.asarray(phi, dtype=float))
    if log_phi is None:
        return None
    A = log_phi / dt
    try:
        M = A @ np.linalg.inv(phi - np.eye(2))
    except np.linalg.LinAlgError:
        return None
    bv = M @ gv
    bs = M @ gs
    b1 = M @ g1
    if not (bv[0] > 0 and A[1, 0] > 0 and A[0, 0] < 0 and A[0, 1] < 0):
        return None
    L = 1.0 / bv[0]
    vals = {"R": -A[0, 0] * L, "L": L, "Ke": -A[0, 1] * L}
    kt_over_j = A[1, 0]
    _scale(vals, Kt, J, kt_over_j)
    vals["B"] = max(-A[1, 1] * vals["J"], 0.0)
    vals["coulomb_friction.torque_nm"] = -bs[1] * vals["J"]
    vals["load_torque.torque_nm"] = -b1[1] * vals["J"]
    if min(vals["R"], vals["Ke"], vals["J"]) <= 0:
        return None
    return {k: float(v) for k, v in vals.items()}


def _quasi_static(i0, w0, v0, s0, i1, w1, dt, coulomb, Kt, J) -> dict[str, float]:
    # electrical: the current at k+1 is already settled: V[k] = R i[k+1] + Ke w[k+1]
    Xe = np.column_stack([i1, w1])
    (R, Ke), *_ = np.linalg.lstsq(Xe, v0, rcond=None)
    if R <= 0 or Ke <= 0:
        msg = "equation error: non-physical R or Ke (check the voltage and current signs)"
        raise DataError(msg)
    mech = _mechanical_regression(w0, w1, 0.5 * (i0 + i1), s0, dt, coulomb)
    kt_over_j, a, c_s, c_1 = mech
    vals = {"R": float(R), "Ke": float(Ke)}
    _scale(vals, Kt, J, kt_over_j)
    vals["B"] = max(a * vals["J"], 0.0)
    vals["coulomb_friction.torque_nm"] = c_s * vals["J"]
    vals["load_torque.torque_nm"] = c_1 * vals["J"]
    return {k: float(v) for k, v in vals.items()}


def _mechanical_regression(w0, w1, i_avg, s0, dt, coulomb):
    """dw/dt = (Kt/J) i - a w - c_s sign(w) - c_1, regressed on one-step differences."""
    dw = (w1 - w0) / dt
    wm = 0.5 * (w0 + w1)
    cols = [i_avg, -wm] + ([-s0] if coulomb else []) + [-np.ones_like(wm)]
    beta, *_ = np.linalg.lstsq(np.column_stack(cols), dw, rcond=None)
    kt_over_j, a = float(beta[0]), float(beta[1])
    c_s = float(beta[2]) if coulomb else 0.0
    c_1 = float(beta[-1])
    if kt_over_j <= 0:
        msg = "equation error: current does not accelerate the rotor (check the signs)"
        raise DataError(msg)
    return kt_over_j, a, c_s, c_1


def fit_mechanical_equation_error(
    segments: Sequence[Segment],
    *,
    Kt: float | None = None,
    J: float | None = None,
    coulomb: bool = True,
) -> EquationErrorResult:
    """Current-driven data: ``J dw/dt = Kt i - B w - Tc sign(w) - T_load`` given ``Kt``
    or ``J`` (the data show only their ratio)."""
    if (Kt is None) == (J is None):
        msg = "the mechanical-only fit needs exactly one of Kt and J"
        raise ValueError(msg)
    parts = [[], [], [], [], []]
    for s in segments:
        if s.current is None or s.n < 4:
            continue
        w = s.speed_or_derivative()
        if s.speed is None:
            # smooth the differentiated position a little: central differences
            w = np.gradient(s.position, s.t)
        parts[0].append(w[:-1])
        parts[1].append(w[1:])
        parts[2].append(0.5 * (s.current[:-1] + s.current[1:]))
        parts[3].append(np.sign(w[:-1]))
        parts[4].append(np.diff(s.t))
    if not parts[0]:
        msg = "mechanical-only fit needs current and speed or position"
        raise DataError(msg)
    w0, w1, ia, s0, dts = (np.concatenate(p) for p in parts)
    if np.ptp(w0) <= 0:
        msg = "no excitation: the speed never changes"
        raise DataError(msg)
    # per-sample dt (non-uniform data are fine here)
    dw = (w1 - w0) / dts
    wm = 0.5 * (w0 + w1)
    direction = one_direction(w0)
    coulomb = coulomb and not direction  # one way only: sign(w) is the constant column
    cols = [ia, -wm] + ([-s0] if coulomb else []) + [-np.ones_like(wm)]
    beta, *_ = np.linalg.lstsq(np.column_stack(cols), dw, rcond=None)
    if beta[0] <= 0:
        msg = "equation error: current does not accelerate the rotor (check the signs)"
        raise DataError(msg)
    if J is None:
        J = Kt / float(beta[0])
    else:
        Kt = float(beta[0]) * J
    vals = {"Kt": Kt, "J": J, "B": max(float(beta[1]) * J, 0.0)}
    if coulomb:
        vals["coulomb_friction.torque_nm"] = float(beta[2]) * J
    vals["load_torque.torque_nm"] = float(beta[-1]) * J
    notes = (ONE_DIRECTION_NOTE,) if direction else ()
    return EquationErrorResult(_one_term(vals, direction), "mechanical", int(w0.size), notes)
