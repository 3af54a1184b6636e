"""The output-error problem: residuals and normal-equation blocks over the
transformed parameter vector ``z`` (log scale for positive parameters, then every
segment's free initial states)."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.effects import EFFECT_TYPES
from pmdc_ident.core.effects.layout import COL_I0, COL_MEASURED_CURRENT, N_SENS
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.estimators.output_error.kernel import COL
from pmdc_ident.core.estimators.output_error.parameters import (
    build_model,
    model_values,
    parameter_info,
)
from pmdc_ident.core.estimators.output_error.segments import SIGNALS, PreparedSegment
from pmdc_ident.core.estimators.output_error.simulators import (
    FastSim,
    general_sim,
    map_simulations,
    run_segments,
)
from pmdc_ident.core.model import Model

__all__ = ["Problem"]

FloatArray = NDArray[np.float64]


@dataclass
class _GeneralRuns:
    """The simulations of one general-path evaluation (see Problem._general_runs)."""

    base: list[FloatArray]  # per segment, at z
    plus_global: list[list[FloatArray]]  # [global j][segment]
    h_global: list[float]
    plus_nuis: list[list[FloatArray]]  # [segment][free initial state]
    h_nuis: list[list[float]]


class Problem:
    """Residuals and Jacobian blocks over transformed parameters z."""

    def __init__(
        self,
        segs: list[PreparedSegment],
        base: Model,
        values: dict[str, float],
        free: list[str],
        tie_kt: bool,
        fast: bool,
        noise: dict[str, float],
        weights: Mapping[str, float],
    ) -> None:
        self.segs = segs
        self.base = base
        self.values = dict(values)
        self.free = free
        self.info = [parameter_info(n) for n in free]
        self.tie_kt = tie_kt
        self.fast = fast
        self.noise = noise
        self.weights = dict(weights)
        self.n_global = len(free)
        self.offsets: list[int] = []
        k = self.n_global
        for ps in segs:
            self.offsets.append(k)
            k += len(ps.nuis)
        self.n_total = k
        self.n_rows = sum(len(ps.outputs) * ps.seg.n for ps in segs)
        self._out_cache: dict[int, tuple[FloatArray, NDArray[np.int64]]] = {}
        z0 = self.z0()
        self.bounds: list[tuple[float, float]] = []
        for j, info in enumerate(self.info):
            if info.log:
                lo = math.log(info.lower) if info.lower > 0 else -math.inf
                hi = math.log(info.upper) if math.isfinite(info.upper) else math.inf
                # Stay within six decades of the start (keeps the model finite).
                self.bounds.append((max(lo, z0[j] - 14.0), min(hi, z0[j] + 14.0)))
            else:
                self.bounds.append((info.lower, info.upper))

    # z <-> values
    def z0(self) -> FloatArray:
        z = np.empty(self.n_total)
        for j, info in enumerate(self.info):
            v = self.values[info.name]
            if info.log:
                z[j] = math.log(max(v, 1e-300))
            else:
                z[j] = v
        for ps, off in zip(self.segs, self.offsets, strict=True):
            for q, idx in enumerate(ps.nuis):
                z[off + q] = ps.x0[idx]
        return z

    def clip(self, z: FloatArray) -> FloatArray:
        z = z.copy()
        for j, (lo, hi) in enumerate(self.bounds):
            z[j] = min(max(z[j], lo), hi)
        return z

    def limit_step(self, step: FloatArray) -> FloatArray:
        """At most a factor e^2 per iteration on log-scaled parameters."""
        out = step.copy()
        for j, info in enumerate(self.info):
            if info.log:
                out[j] = min(max(out[j], -2.0), 2.0)
        return out

    def values_at(self, z: FloatArray) -> dict[str, float]:
        vals = dict(self.values)
        for j, info in enumerate(self.info):
            v = math.exp(min(z[j], 700.0)) if info.log else float(z[j])
            # exp(log(upper)) can exceed upper by one ulp; effects refuse that
            vals[info.name] = min(max(v, info.lower), info.upper)
        if self.tie_kt:
            vals["Kt"] = vals["Ke"]
        return vals

    def dvalue_dz(self, z: FloatArray) -> FloatArray:
        return np.array([math.exp(z[j]) if info.log else 1.0 for j, info in enumerate(self.info)])

    def model_at(self, z: FloatArray) -> Model:
        return build_model(self.base, self.values_at(z))

    def x0_of(self, z: FloatArray, q: int) -> FloatArray:
        ps = self.segs[q]
        x0 = ps.x0.copy()
        off = self.offsets[q]
        for k, idx in enumerate(ps.nuis):
            x0[idx] = z[off + k]
        return x0

    def scale(self, idx: int) -> float:
        sig = SIGNALS[idx]
        return self.weights.get(sig, 1.0) / self.noise[sig]

    # evaluation
    def evaluate(self, z: FloatArray, want_jac: bool):
        """Residual vector and, when asked, normal-equation blocks (A, g)."""
        model = self.model_at(z)
        r_parts: list[FloatArray] = []
        raw_parts: list[tuple[int, FloatArray]] = []
        A = np.zeros((self.n_total, self.n_total)) if want_jac else None
        g = np.zeros(self.n_total) if want_jac else None
        sim = FastSim(model) if self.fast else None
        fast_runs = self._fast_runs(z, model, sim, want_jac) if self.fast else None
        general = None if self.fast else self._general_runs(z, model, want_jac)
        for q, ps in enumerate(self.segs):
            idxs = list(range(self.n_global)) + [self.offsets[q] + k for k in range(len(ps.nuis))]
            ii = np.array(idxs)
            A_loc = g_loc = None
            if fast_runs is not None:
                X, A_loc, g_loc = fast_runs[q]
            else:
                assert general is not None
                X = general.base[q]
            r_seg = []
            for idx, y in ps.outputs:
                raw_parts.append((idx, X[:, idx] - y))
                r_seg.append(raw_parts[-1][1] * self.scale(idx))
            r_q = np.concatenate(r_seg)
            r_parts.append(r_q)
            if not want_jac:
                continue
            if A_loc is None:
                assert general is not None
                cols = self._local_jac(q, ps, X, general)
                if _bounded(cols) and _bounded(r_q):
                    A_loc = cols.T @ cols
                    g_loc = cols.T @ r_q
                else:  # a diverged simulation: the solver refuses this point
                    A_loc = np.full((ii.size, ii.size), np.nan)
                    g_loc = np.full(ii.size, np.nan)
            A[np.ix_(ii, ii)] += A_loc  # type: ignore[index]
            g[ii] += g_loc  # type: ignore[index]
        r = np.concatenate(r_parts)
        self._last = (z.copy(), raw_parts, r, A, g, dict(self.noise))
        return r, A, g

    def _outputs(self, q: int) -> tuple[FloatArray, NDArray[np.int64]]:
        """Measured outputs (n, k) and their state indices of segment q (built once)."""
        got = self._out_cache.get(q)
        if got is None:
            ps = self.segs[q]
            got = (
                np.column_stack([y for _i, y in ps.outputs]),
                np.array([i for i, _y in ps.outputs], dtype=np.int64),
            )
            self._out_cache[q] = got
        return got

    def _fast_runs(
        self, z: FloatArray, model: Model, sim: FastSim | None, want_jac: bool
    ) -> list[tuple[FloatArray, FloatArray | None, FloatArray | None]]:
        """Every segment through the fast kernel, in worker threads when it pays.

        The kernel releases the GIL; each segment's states and normal-equation blocks
        are its own, and the caller sums them in segment order as before, so the result
        does not depend on the threads.
        """
        assert sim is not None
        jobs = []
        for q, ps in enumerate(self.segs):
            acc = None
            if want_jac:
                y, oidx = self._outputs(q)
                mx, off = self._mixing(z, model, ps)
                acc = (y, oidx, np.array([self.scale(i) for i in oidx.tolist()]), mx, off)
            sim.mats(ps.seg.dt_s, ps.dJ)  # fill the cache here, not in the threads
            jobs.append((ps.seg, self.x0_of(z, q), acc, ps.dJ))
        return run_segments(sim, jobs)

    def cached(self, z: FloatArray, want_jac: bool):
        """The last evaluation if it was at ``z`` with the current weights, else a new one."""
        last = getattr(self, "_last", None)
        if (
            last is not None
            and np.array_equal(last[0], z)
            and (last[3] is not None or not want_jac)
            and last[5] == self.noise
        ):
            return last[2], last[3], last[4]
        return self.evaluate(z, want_jac)

    def raw_residuals(self, z: FloatArray) -> dict[str, FloatArray]:
        """Unscaled residuals per signal at ``z``."""
        last = getattr(self, "_last", None)
        if last is None or not np.array_equal(last[0], z):
            self.evaluate(z, False)
            last = self._last
        acc: dict[str, list[FloatArray]] = {}
        for idx, res in last[1]:
            acc.setdefault(SIGNALS[idx], []).append(res)
        return {k: np.concatenate(v) for k, v in acc.items()}

    def _mixing(
        self, z: FloatArray, model: Model, ps: PreparedSegment
    ) -> tuple[FloatArray, FloatArray]:
        """Kernel sensitivities (N_SENS columns) -> local Jacobian columns; offset column mask."""
        vals = model_values(model)
        dvdz = self.dvalue_dz(z)
        m_loc = self.n_global + len(ps.nuis)
        mx = np.zeros((N_SENS, m_loc))
        off = np.zeros(m_loc)
        for j, name in enumerate(self.free):
            if name in COL:
                # kernel columns are per log of the value the segment sees (J + dJ)
                seen = vals[name] + (ps.dJ if name == "J" else 0.0)
                mx[COL[name], j] = dvdz[j] / seen
                if name == "Ke" and self.tie_kt:
                    mx[COL["Kt"], j] = dvdz[j] / vals[name]
            else:
                col = _fast_column(name)
                if col == COL_MEASURED_CURRENT:
                    off[j] = dvdz[j]
                else:
                    mx[col, j] = dvdz[j]
        for k, sidx in enumerate(ps.nuis):
            mx[COL_I0 + sidx, self.n_global + k] = 1.0
        return mx, off

    def _local_jac(self, q: int, ps: PreparedSegment, X: FloatArray, runs: _GeneralRuns):
        """Forward-difference Jacobian block of one segment (general path)."""
        n = ps.seg.n
        m_loc = self.n_global + len(ps.nuis)
        cols = np.zeros((n * len(ps.outputs), m_loc))
        for o, (idx, _y) in enumerate(ps.outputs):
            rows = slice(o * n, (o + 1) * n)
            sc = self.scale(idx)
            for j in range(self.n_global):
                cols[rows, j] = (
                    (runs.plus_global[j][q] - runs.base[q])[:, idx] / runs.h_global[j] * sc
                )
        for k in range(len(ps.nuis)):
            h = runs.h_nuis[q][k]
            Xp = runs.plus_nuis[q][k]
            for o, (idx, _y) in enumerate(ps.outputs):
                rows = slice(o * n, (o + 1) * n)
                cols[rows, self.n_global + k] = (Xp[:, idx] - X[:, idx]) / h * self.scale(idx)
        return cols

    def _general_runs(self, z: FloatArray, model: Model, want_jac: bool) -> _GeneralRuns:
        """Every simulation of one evaluation on the general path, as one batch.

        The states at ``z`` and, for the Jacobian, forward differences: each global
        ``z`` stepped on every segment, each segment's free initial states stepped on
        that segment. The states at ``z`` serve both the residuals and the differences
        (they were simulated twice before). The batch runs in the worker threads; each
        simulation is computed alone, so the numbers do not depend on them.
        """
        jobs: list[tuple[Model, int, FloatArray]] = [
            (model, q, self.x0_of(z, q)) for q in range(len(self.segs))
        ]
        h_global: list[float] = []
        h_nuis: list[list[float]] = []
        if want_jac:
            for j in range(self.n_global):
                h = 1e-6 * max(1.0, abs(z[j]))
                zp = z.copy()
                zp[j] += h
                mp = self.model_at(zp)
                h_global.append(h)
                jobs += [(mp, q, self.x0_of(z, q)) for q in range(len(self.segs))]
            for q, ps in enumerate(self.segs):
                hs = []
                for k, sidx in enumerate(ps.nuis):
                    h = 1e-6 * max(1.0, abs(z[self.offsets[q] + k]))
                    x0 = self.x0_of(z, q)
                    x0[sidx] += h
                    hs.append(h)
                    jobs.append((model, q, x0))
                h_nuis.append(hs)
        segs = self.segs
        states = map_simulations(
            lambda job: general_sim(job[0], segs[job[1]].seg, job[2], segs[job[1]].dJ),
            jobs,
            sum(segs[q].seg.n for _m, q, _x in jobs),
        )
        nq = len(segs)
        base = states[:nq]
        plus_global = [states[nq * (1 + j) : nq * (2 + j)] for j in range(len(h_global))]
        rest = iter(states[nq * (1 + len(h_global)) :])
        plus_nuis = [[next(rest) for _ in hs] for hs in h_nuis]
        return _GeneralRuns(base, plus_global, h_global, plus_nuis, h_nuis)

    def residual_noise(self, z: FloatArray) -> dict[str, float]:
        out = {}
        for k, res in self.raw_residuals(z).items():
            rms = float(np.sqrt(np.mean(res**2)))
            out[k] = max(rms, 1e-3 * self.noise[k], 1e-12)
        return out


def _fast_column(name: str) -> int:
    """The fast kernel's sensitivity column of an ``"<effect>.<field>"`` (the effect's
    ``FAST_COLUMNS``), or :data:`COL_MEASURED_CURRENT` for one added to the current."""
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    col = cls.FAST_COLUMNS.get(fld) if cls is not None else None
    if col is None:
        msg = f"parameter {name} has no analytic sensitivity"
        raise ParameterError(msg)
    return col


def _bounded(a: FloatArray, cap: float = 1e100) -> bool:
    """Finite and small enough that products of two entries summed cannot overflow."""
    return bool(np.isfinite(a).all()) and (a.size == 0 or float(np.max(np.abs(a))) <= cap)
