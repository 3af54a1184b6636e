"""Levenberg-Marquardt with box bounds on the normal equations of a
:class:`~.problem.Problem`."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.estimators.output_error.problem import Problem

__all__ = ["LMState", "levenberg_marquardt"]

FloatArray = NDArray[np.float64]

# Residuals (noise-normalised) beyond this are a diverged simulation: their cost is
# infinite, and they never reach a product that could overflow.
RESIDUAL_CAP = 1e100
# Residuals are noise-normalised: a decrease of the cost below this moves no parameter
# combination by more than 0.15 of its standard error (the fit has converged).
CONVERGED_DECREASE = 1e-2


def half_squared(r: FloatArray) -> float:
    """0.5 |r|^2, or inf when ``r`` holds a non-finite or diverged entry."""
    if r.size and not (np.isfinite(r).all() and float(np.max(np.abs(r))) <= RESIDUAL_CAP):
        return math.inf
    return 0.5 * float(r @ r)


def _finite(*arrays: FloatArray | None) -> bool:
    return all(a is not None and bool(np.isfinite(a).all()) for a in arrays)


@dataclass(frozen=True)
class LMState:
    """How the solver ended: cost, evaluations, iterations, converged and why."""

    cost: float
    nfev: int
    it: int
    converged: bool
    message: str


def levenberg_marquardt(
    prob: Problem,
    z: FloatArray,
    max_nfev: int,
    progress: Callable[[int, float], None] | None,
) -> tuple[FloatArray, LMState]:
    """Levenberg-Marquardt on the normal equations with box bounds.

    Trial points cost one simulation without sensitivities; the Jacobian is
    computed only where a step is accepted. A parameter at a bound whose step
    points outwards is held for that step (active set), so a friction torque
    that wants to be zero converges instead of chattering on its bound.
    """
    z = prob.clip(z)
    r, A, g = prob.evaluate(z, True)
    cost = half_squared(r)
    if not (math.isfinite(cost) and _finite(A, g)):
        msg = (
            "the fit cannot start: simulating the start model on these data diverges "
            "(are the signals in SI units, and is the voltage the armature's?)"
        )
        raise DataError(msg)
    nfev = 1
    lam = 1e-3
    it = 0
    last_ok = True
    converged = False
    message = "maximum number of evaluations reached"
    lo = np.array([b[0] for b in prob.bounds] + [-np.inf] * (prob.n_total - prob.n_global))
    hi = np.array([b[1] for b in prob.bounds] + [np.inf] * (prob.n_total - prob.n_global))
    while nfev < max_nfev:
        it += 1
        d = np.diag(A).copy()
        d[d <= 0] = 1.0
        improved = False
        while nfev < max_nfev:
            step = _bounded_step(A + lam * np.diag(d), g, z, lo, hi)
            z_new = prob.clip(z + prob.limit_step(step))
            # After an accepted step the next trial is usually accepted too: compute
            # its Jacobian at once; after a rejection, try residuals only.
            r_new, A_new, g_new = prob.evaluate(z_new, last_ok)
            nfev += 1
            cost_new = half_squared(r_new)
            # a point whose sensitivities diverge is no better than one that does
            usable = A_new is None or _finite(A_new, g_new)
            if math.isfinite(cost_new) and cost_new <= cost and usable:
                rel = (cost - cost_new) / max(cost, 1e-300)
                small_step = np.all(np.abs(z_new - z) <= 1e-9 * (1.0 + np.abs(z)))
                decrease = cost - cost_new
                z, cost = z_new, cost_new
                lam = max(lam / 5.0, 1e-12)
                improved = True
                last_ok = True
                # residuals are noise-normalised: a decrease below 0.01 moves no
                # parameter combination by more than 0.15 of its standard error
                if rel < 1e-12 or decrease < CONVERGED_DECREASE or small_step:
                    converged = True
                    message = "cost no longer decreases"
                elif A_new is not None:
                    r, A, g = r_new, A_new, g_new
                else:
                    r, A_try, g_try = prob.evaluate(z, True)
                    if not _finite(A_try, g_try):
                        converged = True
                        message = "sensitivities not finite beyond this point"
                        break
                    A, g = A_try, g_try
                break
            last_ok = False
            lam *= 6.0
            if _promised(step, A, g) < CONVERGED_DECREASE:
                # even the rejected step promised less than the convergence threshold: the
                # smaller steps of a larger lambda promise less still, so had one been
                # accepted the fit would have stopped there (same test, no more trials)
                converged = True
                message = "cost no longer decreases"
                break
            if lam > 1e12:
                converged = True
                message = "no further decrease possible (local minimum)"
                break
        if progress is not None:
            progress(it, cost)
        if converged or not improved:
            break
    return z, LMState(cost, nfev, it, converged, message)


def _promised(step: FloatArray, A: FloatArray, g: FloatArray) -> float:
    """The cost decrease the Gauss-Newton model promises for ``step`` (the solver's
    step before the per-iteration limit and the bounds shorten it)."""
    return -(float(g @ step) + 0.5 * float(step @ A @ step))


def _bounded_step(
    M: FloatArray, g: FloatArray, z: FloatArray, lo: FloatArray, hi: FloatArray
) -> FloatArray:
    """The damped step ``M step = -g``; a parameter at a bound whose step points
    outwards is held (active set, at most three passes); zero when not finite (a
    singular system: the caller damps harder)."""
    n = g.size
    active = np.ones(n, dtype=bool)
    for _ in range(3):
        step = np.zeros(n)
        sub = np.ix_(active, active)
        try:
            step[active] = -np.linalg.solve(M[sub], g[active])
        except np.linalg.LinAlgError:
            step[active] = -np.linalg.lstsq(M[sub], g[active], rcond=None)[0]
        out = ((z <= lo) & (step < 0)) | ((z >= hi) & (step > 0))
        if not (out & active).any():
            break
        active &= ~out
    if not np.isfinite(step).all():
        step = np.zeros(n)
    return step
