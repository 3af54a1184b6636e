"""The package's one Levenberg-Marquardt solver, for every least-squares fit it makes.

Two kinds of problem use it:

* the output-error fit (:class:`~pmdc_ident.core.estimators.output_error.problem.
  Problem`): thousands of residuals, normalised by the noise, whose normal equations
  (``A = J^T J``, ``g = J^T r``) the simulation kernel assembles itself; box bounds;
* the classical chain's curve fits (a coast-down curve: two or three parameters), given
  as a residual function and its Jacobian (:func:`least_squares`, through
  :class:`DenseProblem`).

Both go through :func:`levenberg_marquardt`: Marquardt's scaling (the normal matrix's
diagonal), the damping divided by 5 after an accepted step and multiplied by 6 after a
rejected one, an active set for parameters at a bound, trial points costing one
evaluation without the Jacobian after a rejection. What differs is when a fit has
converged (:class:`LMSettings`), because the two measure their residuals differently:
noise-normalised residuals make an absolute cost decrease meaningful (below 0.01 no
parameter combination moves by 0.15 of its standard error), residuals in physical
units do not (a relative step of 1e-12 then).

scipy's ``least_squares`` would serve the classical fits, but importing
``scipy.optimize`` costs more CPU than an identification of a staircase table takes
(``benchmarks/bench_scipy_imports.py``); the output-error fit needs normal equations
the kernel assembles, which no scipy solver takes.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.errors import DataError

__all__ = [
    "DenseProblem",
    "LMSettings",
    "LMState",
    "LsqSolution",
    "NormalEquations",
    "least_squares",
    "levenberg_marquardt",
]

FloatArray = NDArray[np.float64]

# Residuals beyond this are a diverged simulation: their cost is infinite, and they
# never reach a product that could overflow.
RESIDUAL_CAP = 1e100
# Output-error residuals are noise-normalised: a decrease of the cost below this moves
# no parameter combination by more than 0.15 of its standard error (converged).
CONVERGED_DECREASE = 1e-2


class NormalEquations(Protocol):
    """A least-squares problem as the solver sees it: the parameter vector ``z`` (its
    first ``n_global`` entries boxed by ``bounds``, the rest free), the residuals and
    the normal equations at a point, and how far a step may go."""

    n_total: int
    n_global: int
    bounds: list[tuple[float, float]]

    def evaluate(
        self, z: FloatArray, want_jac: bool
    ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]: ...

    def clip(self, z: FloatArray) -> FloatArray: ...

    def limit_step(self, step: FloatArray) -> FloatArray: ...


@dataclass(frozen=True)
class LMSettings:
    """When the solver stops: after ``max_nfev`` evaluations, or after an accepted step
    that decreased the cost by less than ``ftol`` (relative) or ``cost_tol`` (absolute;
    None: never), or moved no parameter by more than ``xtol`` (1 + |z|). With
    ``cost_tol``, a rejected step that promised less than it ends the fit as well (the
    smaller steps of a larger damping promise less still)."""

    max_nfev: int
    ftol: float = 1e-12
    cost_tol: float | None = CONVERGED_DECREASE
    xtol: float = 1e-9
    # the one line a start whose residuals are not finite gets
    start_error: str = "the fit cannot start: its residuals at the start are not finite"


@dataclass(frozen=True)
class LMState:
    """How the solver ended: cost, evaluations, iterations, converged and why."""

    cost: float
    nfev: int
    it: int
    converged: bool
    message: str


def half_squared(r: FloatArray) -> float:
    """0.5 |r|^2, or inf when ``r`` holds a non-finite or diverged entry."""
    if r.size and not (np.isfinite(r).all() and float(np.max(np.abs(r))) <= RESIDUAL_CAP):
        return math.inf
    return 0.5 * float(r @ r)


def _finite(*arrays: FloatArray | None) -> bool:
    return all(a is not None and bool(np.isfinite(a).all()) for a in arrays)


def levenberg_marquardt(
    prob: NormalEquations,
    z: FloatArray,
    settings: LMSettings,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[FloatArray, LMState]:
    """Levenberg-Marquardt on the normal equations with box bounds.

    Trial points cost one evaluation without the Jacobian after a rejected step; after
    an accepted one the next trial is usually accepted too, so its Jacobian is computed
    at once. A parameter at a bound whose step points outwards is held for that step
    (active set), so a friction torque that wants to be zero converges instead of
    chattering on its bound.
    """
    max_nfev = settings.max_nfev
    z = prob.clip(z)
    r, A, g = prob.evaluate(z, True)
    cost = half_squared(r)
    if not (math.isfinite(cost) and _finite(A, g)):
        raise DataError(settings.start_error)
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
                small_step = np.all(np.abs(z_new - z) <= settings.xtol * (1.0 + np.abs(z)))
                done = small_step or _decreased_little(cost, cost_new, settings)
                z, cost = z_new, cost_new
                lam = max(lam / 5.0, 1e-12)
                improved = True
                last_ok = True
                if done:
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
            if settings.cost_tol is not None and _promised(step, A, g) < settings.cost_tol:
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


def _decreased_little(cost: float, cost_new: float, settings: LMSettings) -> bool:
    """Whether an accepted step's decrease says the fit has converged."""
    decrease = cost - cost_new
    rel = decrease / max(cost, 1e-300)
    return (
        cost_new == 0.0
        or rel < settings.ftol
        or (settings.cost_tol is not None and decrease < settings.cost_tol)
    )


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


# ---------------------------------------------------------------------------
# Small dense problems: a residual function and its Jacobian
# ---------------------------------------------------------------------------
class DenseProblem:
    """``min |fun(x)|^2`` with the Jacobian ``jac(x)`` (rows: residuals), unbounded, as
    :class:`NormalEquations` for :func:`levenberg_marquardt`."""

    def __init__(
        self,
        fun: Callable[[FloatArray], FloatArray],
        jac: Callable[[FloatArray], FloatArray],
        n: int,
    ) -> None:
        self.fun, self.jac = fun, jac
        self.n_total = self.n_global = n
        self.bounds = [(-math.inf, math.inf)] * n

    def evaluate(
        self, z: FloatArray, want_jac: bool
    ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
        r = np.asarray(self.fun(z), dtype=float)
        if not want_jac:
            return r, None, None
        J = np.asarray(self.jac(z), dtype=float)
        return r, J.T @ J, J.T @ r

    def clip(self, z: FloatArray) -> FloatArray:
        return z

    def limit_step(self, step: FloatArray) -> FloatArray:
        return step


@dataclass(frozen=True)
class LsqSolution:
    """The minimiser ``x``, the residuals ``fun`` and the Jacobian ``jac`` there."""

    x: FloatArray
    fun: FloatArray
    jac: FloatArray
    nfev: int
    state: LMState


def least_squares(
    fun: Callable[[FloatArray], FloatArray],
    jac: Callable[[FloatArray], FloatArray],
    x0: FloatArray | list[float],
    *,
    max_nfev: int = 500,
    xtol: float = 1e-12,
) -> LsqSolution:
    """Minimise ``|fun(x)|^2`` from ``x0`` with :func:`levenberg_marquardt`; ``jac(x)``
    is d fun / d x (rows: residuals). Residuals in physical units: converged when no
    parameter moves by more than ``xtol`` (1 + |x|) (no absolute cost threshold)."""
    x = np.asarray(x0, dtype=float).copy()
    settings = LMSettings(max_nfev=max_nfev, ftol=0.0, cost_tol=None, xtol=xtol)
    z, state = levenberg_marquardt(DenseProblem(fun, jac, x.size), x, settings)
    return LsqSolution(z, np.asarray(fun(z), dtype=float), np.asarray(jac(z), dtype=float),
                       state.nfev, state)  # fmt: skip
