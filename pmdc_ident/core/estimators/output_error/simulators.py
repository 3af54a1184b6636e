"""The two simulators of the output-error fit.

* the **fast path** (:data:`FAST_EFFECTS`): :class:`FastSim` caches the exact ZOH
  matrices and their Van Loan derivatives per sample period and runs
  :func:`~.kernel.fast_kernel`, which also returns the normal equations;
* the **general path** (any other effect): :func:`general_sim`, i.e.
  :func:`pmdc_ident.core.model.simulate` with sub-steps (the Jacobian is then a
  forward difference, see :class:`~.problem.Problem`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment, heat_state
from pmdc_ident.core.effects import EFFECT_TYPES, SimPath
from pmdc_ident.core.effects.layout import CQ, DS, I_OFF, TC, TL, TS, WS
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.estimators.output_error.kernel import N_SENS, fast_kernel
from pmdc_ident.core.model import (
    Model,
    discretize_zoh,
    effect_coefficients,
    expm_small,
    heat_time_constant,
    simulate,
    substeps_for,
)
from pmdc_ident.core.params import MotorParams

__all__ = [
    "FAST_EFFECTS",
    "SUBSTEPS",
    "FastSim",
    "general_sim",
    "map_simulations",
    "predict",
    "run_segments",
    "system_matrices",
    "zoh_with_derivatives",
]

FloatArray = NDArray[np.float64]
_T = TypeVar("_T")
_R = TypeVar("_R")
#: effects the fast kernel simulates with analytic sensitivities (``SimPath.FAST``)
FAST_EFFECTS = frozenset(n for n, cls in EFFECT_TYPES.items() if cls.SIM_PATH is SimPath.FAST)
# sub-steps for samples where friction acts at zero speed (as core.model.simulate)
SUBSTEPS = 8


# ---------------------------------------------------------------------------
# Fast kernel: exact ZOH with sensitivities
# ---------------------------------------------------------------------------
def system_matrices(p: MotorParams, closed: bool) -> tuple[FloatArray, list[FloatArray]]:
    """Continuous augmented matrix M (5x5: x=[i,w,th], u=[V,T]) and dM/dp for R..B."""
    R, L, Ke, Kt, J, B = p.R, p.L, p.Ke, p.Kt, p.J, p.B
    m = np.zeros((5, 5))
    d = [np.zeros((5, 5)) for _ in range(6)]
    m[1, 1] = -B / J
    m[2, 1] = 1.0
    m[1, 4] = -1.0 / J
    d[4][1, 1] = B / J**2
    d[4][1, 4] = 1.0 / J**2
    d[5][1, 1] = -1.0 / J
    if closed:
        m[0, 0] = -R / L
        m[0, 1] = -Ke / L
        m[1, 0] = Kt / J
        m[0, 3] = 1.0 / L
        d[0][0, 0] = -1.0 / L
        d[1][0, 0] = R / L**2
        d[1][0, 1] = Ke / L**2
        d[1][0, 3] = -1.0 / L**2
        d[2][0, 1] = -1.0 / L
        d[3][1, 0] = 1.0 / J
        d[4][1, 0] = -Kt / J**2
    # Derivatives with respect to log(p): well scaled for the block exponential.
    for k, val in enumerate((R, L, Ke, Kt, J, B)):
        d[k] *= val
    return m, d


def zoh_with_derivatives(
    p: MotorParams, dt: float, closed: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Phi (3x3), Gamma (3x2) and their derivatives (6,3,3), (6,3,2) by Van Loan.

    The derivatives are with respect to ``log(p)`` (``p dPhi/dp``) for R..B.
    """
    m, dms = system_matrices(p, closed)
    e = expm_small(m * dt)
    dphi = np.zeros((6, 3, 3))
    dgam = np.zeros((6, 3, 2))
    big = np.zeros((10, 10))
    big[:5, :5] = m
    big[5:, 5:] = m
    for j, dm in enumerate(dms):
        if not dm.any():
            continue
        big[:5, 5:] = dm
        de = expm_small(big * dt)[:5, 5:]
        dphi[j] = de[:3, :3]
        dgam[j] = de[:3, 3:]
    phi = np.ascontiguousarray(e[:3, :3])
    gam = np.ascontiguousarray(e[:3, 3:])
    if not closed:
        phi[0, :] = 0.0  # open armature: no current
        phi[:, 0] = 0.0
        gam[0, :] = 0.0
    return phi, gam, dphi, dgam


class FastSim:
    """Caches discretisations per sample period for one parameter point."""

    def __init__(self, model: Model) -> None:
        self.model = model
        self.p = model.params
        # the fast kernel's numbers, from the slots every effect writes (core.effects.layout)
        self.coef = c = effect_coefficients(model)
        self.fx = np.array([c[TS], c[WS], c[CQ], c[DS]])
        self.tc = float(c[TC])
        self.tl = float(c[TL])
        self.off = float(c[I_OFF])
        self._cache: dict[float, tuple[FloatArray, ...]] = {}

    def mats(self, dt: float, dJ: float = 0.0) -> tuple[FloatArray, ...]:
        key = (float(f"{dt:.9g}"), dJ)  # segments of one run share one period
        dt = key[0]
        got = self._cache.get(key)
        if got is None:
            p = self.p if dJ == 0.0 else self.p.replace(J=self.p.J + dJ)
            phc, gac, dphc, dgac = zoh_with_derivatives(p, dt, True)
            pho, gao, dpho, dgao = zoh_with_derivatives(p, dt, False)
            R, L = p.R, p.L
            a = math.exp(-R * dt / L)
            b = (1.0 - a) / R
            da_dR = -dt / L * a
            da_dL = R * dt / L**2 * a
            db_dR = -da_dR / R - (1.0 - a) / R**2
            db_dL = -da_dL / R
            # per log(R), log(L), as the other motor-parameter sensitivities
            el = np.array([a, b, R * da_dR, L * da_dL, R * db_dR, L * db_dL])
            phs, gas = discretize_zoh(p, dt / SUBSTEPS)
            coef = self.coef.copy()
            coef[4] = p.J
            got = (phc, gac, dphc, dgac, pho, gao, dpho, dgao, el, phs, gas, coef)
            self._cache[key] = got
        return got

    def run(
        self,
        seg: Segment,
        x0: FloatArray,
        acc: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | None = None,
        dJ: float = 0.0,
    ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
        """States (current includes the offset); with ``acc = (y, oidx, osc, mx, off)``
        also the normal-equation blocks of this segment's residuals."""
        dt = seg.dt_s
        cmode = seg.voltage is None
        v = np.zeros(seg.n) if cmode else seg.voltage
        imeas = seg.current if seg.current is not None else np.zeros(seg.n)
        mats = self.mats(dt, dJ)
        m, phs, gas, coef = mats[:9], mats[9], mats[10], mats[11]
        if acc is None:
            y, oidx, osc, mx, off = _NO_ACC
            nc = _NO_COLS
        else:
            y, oidx, osc, mx, off = acc
            nc = np.nonzero(np.any(mx != 0.0, axis=1))[0].astype(np.int64)
        X, A, g = fast_kernel(
            v,
            imeas,
            cmode,
            *m,
            self.tc,
            self.tl,
            self.p.Kt,
            self.fx,
            np.asarray(x0, float),
            acc is not None,
            nc,
            y,
            oidx,
            osc,
            mx,
            off,
            0.0 if cmode else self.off,
            coef,
            phs,
            gas,
            SUBSTEPS,
            dt / SUBSTEPS,
        )
        if self.off != 0.0 and not cmode:
            X[:, 0] += self.off
        if acc is None:
            return X, None, None
        return X, A, g


# Below this many samples in all segments together, threads cost more than they save.
THREADED_MIN_SAMPLES = 20_000
_POOL: list[ThreadPoolExecutor] = []


def _pool() -> ThreadPoolExecutor:
    if not _POOL:
        workers = max(1, min(4, os.cpu_count() or 1))
        _POOL.append(ThreadPoolExecutor(max_workers=workers, thread_name_prefix="pmdc-fit"))
    return _POOL[0]


def map_simulations(fn: Callable[[_T], _R], jobs: Sequence[_T], n_samples: int) -> list[_R]:
    """``[fn(job) for job in jobs]``, in the worker threads when there is enough work
    (``n_samples`` in all) and more than one CPU; the numba simulators release the GIL."""
    if len(jobs) < 2 or n_samples < THREADED_MIN_SAMPLES or (os.cpu_count() or 1) < 2:
        return [fn(job) for job in jobs]
    return list(_pool().map(fn, jobs))


def run_segments(
    sim: FastSim, jobs: list[tuple[Segment, FloatArray, tuple | None, float]]
) -> list[tuple[FloatArray, FloatArray | None, FloatArray | None]]:
    """``sim.run(seg, x0, acc, dJ)`` for every job, results in job order.

    On a machine with more than one CPU and enough samples, the segments run in
    worker threads (the kernel releases the GIL): the wall time of a fit falls, its
    numbers do not change (each segment's result is computed alone).
    """
    return map_simulations(lambda job: sim.run(*job), jobs, sum(job[0].n for job in jobs))


_NO_ACC = (
    np.zeros((1, 1)),
    np.zeros(1, dtype=np.int64),
    np.zeros(1),
    np.zeros((N_SENS, 1)),
    np.zeros(1),
)
_NO_COLS = np.zeros(0, dtype=np.int64)


def predict(model: Model, seg: Segment, x0: FloatArray, fast: bool, dJ: float = 0.0) -> FloatArray:
    """States (n, 3) of ``model`` free-running on ``seg`` from ``x0`` (``dJ``: added inertia)."""
    if fast:
        X, _, _ = FastSim(model).run(seg, x0, dJ=dJ)
        return X
    return general_sim(model, seg, x0, dJ)


def _with_inertia(model: Model, dJ: float) -> Model:
    if dJ == 0.0:
        return model
    return Model(model.params.replace(J=model.params.J + dJ), model.effects)


def general_sim(model: Model, seg: Segment, x0: FloatArray, dJ: float = 0.0) -> FloatArray:
    model = _with_inertia(model, dJ)
    if seg.voltage is None:
        msg = "current-driven (no voltage) fits support only coulomb_friction and load_torque"
        raise ParameterError(msg)
    # A segment cut from a longer record starts with the commands still in a delay
    # line and the heat already dissipated (see Segment.history_*).
    sim = simulate(
        model,
        seg.voltage,
        seg.dt_s,
        x0=x0,
        substeps=substeps_for(model, SUBSTEPS),
        pre_voltage=seg.history_voltage,
        heat0_a2s=heat_state(seg, heat_time_constant(model)),
    )
    return np.column_stack([sim.current, sim.speed, sim.position])
