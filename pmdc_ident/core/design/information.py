"""Expected information of a planned segment: the Fisher information of the fitted model.

The model is the one ``identify`` fits: the seeds' linear motor with ``Kt = Ke`` plus
a Coulomb torque (when the prior has one), states ``[i, w, theta]``, each segment
from its own free initial state (``i0``, ``w0``, and ``theta0`` when the fit uses the
position). The parameters are taken in logarithms, so the inverse information gives
relative standard deviations directly.

The sensitivities are the exact derivatives of the zero-order-hold discretisation
(Van Loan blocks of the matrix exponential) propagated along the prior's own
trajectory (:func:`pmdc_ident.core.model.simulate`, with every effect of the prior and
the rotor held by static friction where it sticks): ``S[k+1] = Phi S[k] + dPhi x[k] +
dGamma u[k]``. Where the prior's rotor sticks, speed and angle carry nothing about the
mechanical parameters, and their sensitivities are held at zero there. Each
segment's initial state is profiled out (the Schur complement), as the fit estimates
it: information of separate segments adds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit
from pmdc_ident.core.quality.linsim import expm

__all__ = [
    "DESIGN_PARAMETERS",
    "InformationModel",
    "Noise",
    "lag_bias",
    "relative_sd",
    "segment_information",
    "segment_lag_terms",
    "systematic_rsd",
    "with_systematic",
]

FloatArray = NDArray[np.float64]
DESIGN_PARAMETERS: tuple[str, ...] = ("R", "L", "Ke", "J", "B", "Tc")
# how late a current reading may be, at most, where the rig does not say (in sample
# periods): the lag of a first-order anti-alias filter at the sample rate, 1/(2 pi)
CURRENT_LAG_SAMPLES = 1.0 / (2.0 * math.pi)


@dataclass(frozen=True)
class Noise:
    """What the rig measures and how well: per-sample standard deviations.

    ``speed_sd``: a measured speed (tachometer or the driver's velocity); 0 when the
    fit uses the encoder's position, whose quantisation ``position_sd`` (q / sqrt 12)
    is then the noise."""

    current_sd: float
    speed_sd: float = 0.0
    position_sd: float = 0.0
    # how late the current reading may be, at most (anti-alias filter, ADC timing; the
    # fitted model has no lag); None: unknown, up to CURRENT_LAG_SAMPLES of a sample
    current_lag_s: float | None = None

    def current_lag(self, dt_s: float) -> float:
        """The largest lag of the current reading to allow for (s)."""
        lag = self.current_lag_s
        return CURRENT_LAG_SAMPLES * dt_s if lag is None else max(float(lag), 0.0)

    @property
    def uses_speed(self) -> bool:
        return self.speed_sd > 0.0 or self.position_sd <= 0.0

    def describe(self) -> str:
        mech = (
            f"speed {self.speed_sd:.3g} rad/s"
            if self.uses_speed
            else f"position {self.position_sd:.3g} rad (quantisation)"
        )
        return f"current {self.current_sd:.3g} A, {mech}"


def _driven(p: Mapping[str, float]) -> tuple[FloatArray, FloatArray]:
    r, ind, ke, j, b = p["R"], p["L"], p["Ke"], p["J"], p["B"]
    a = np.array([[-r / ind, -ke / ind, 0.0], [ke / j, -b / j, 0.0], [0.0, 1.0, 0.0]])
    bm = np.array([[1.0 / ind, 0.0], [0.0, -1.0 / j], [0.0, 0.0]])
    return a, bm


def _open(p: Mapping[str, float]) -> tuple[FloatArray, FloatArray]:
    j, b = p["J"], p["B"]
    return np.array([[-b / j, 0.0], [1.0, 0.0]]), np.array([[-1.0 / j], [0.0]])


def _zoh_and_derivatives(
    system, p: Mapping[str, float], names: Sequence[str], dt: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # type: ignore[no-untyped-def]
    """``Phi, Gamma`` and their derivatives with respect to ``log p[name]`` (exact:
    the upper-right block of the exponential of ``[[M, dM], [0, M]]``)."""
    a, bm = system(p)
    n, m = bm.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = a, bm
    e = expm(big * dt)
    phi, gam = e[:n, :n].copy(), e[:n, n:].copy()
    dphi = np.zeros((len(names), n, n))
    dgam = np.zeros((len(names), n, m))
    for k, name in enumerate(names):
        if name == "Tc":
            continue  # enters through the input (Tc s), not the matrices
        h = 1e-6 * p[name]
        q = dict(p)
        q[name] = p[name] + h
        a2, b2 = system(q)
        d = np.zeros((n + m, n + m))
        d[:n, :n], d[:n, n:] = (a2 - a) / h, (b2 - bm) / h
        # exact derivative of expm along d (Van Loan); d itself is a finite difference
        # of rational functions of p, accurate to ~1e-6 relative
        vl = np.zeros((2 * (n + m), 2 * (n + m)))
        vl[: n + m, : n + m] = big * dt
        vl[: n + m, n + m :] = d * dt
        vl[n + m :, n + m :] = big * dt
        de = expm(vl)[: n + m, n + m :] * p[name]  # d/dlog p
        dphi[k], dgam[k] = de[:n, :n], de[:n, n:]
    return phi, gam, dphi, dgam


@njit
def _accumulate(
    v,
    fric,
    stuck,
    traj,
    phi,
    gam,
    dphi,
    dgam,
    phio,
    gamo,
    dphio,
    dgamo,
    tc_col,
    tc,
    outs,
    wts,
    nuis,
    res,
):  # pragma: no cover - jitted
    """Information matrix (params + initial states) of one segment, and the gradient
    ``S' W r`` of the residuals ``res`` (samples x outputs; an empty array: none); see
    the module."""
    n = v.shape[0]
    npar = dphi.shape[0]
    ncol = npar + nuis.shape[0]
    s = np.zeros((3, ncol))
    for q in range(nuis.shape[0]):
        s[nuis[q], npar + q] = 1.0
    m = np.zeros((ncol, ncol))
    gv = np.zeros(ncol)
    with_res = res.shape[0] == n
    new = np.zeros((3, ncol))
    g = np.zeros(ncol)
    for k in range(n):
        for o in range(outs.shape[0]):
            row = outs[o]
            for c in range(ncol):
                g[c] = s[row, c] * wts[o]
            for a in range(ncol):
                ga = g[a]
                if ga != 0.0:
                    for b in range(ncol):
                        m[a, b] += ga * g[b]
            if with_res:
                r = res[k, o] * wts[o]
                for a in range(ncol):
                    gv[a] += g[a] * r
        if k == n - 1:
            break
        x0, x1, x2 = traj[k, 0], traj[k, 1], traj[k, 2]
        f = fric[k]
        if math.isnan(v[k]):
            for c in range(ncol):
                new[0, c] = 0.0
                new[1, c] = phio[0, 0] * s[1, c] + phio[0, 1] * s[2, c]
                new[2, c] = phio[1, 0] * s[1, c] + phio[1, 1] * s[2, c]
            for c in range(npar):
                new[1, c] += dphio[c, 0, 0] * x1 + dphio[c, 0, 1] * x2 + dgamo[c, 0, 0] * tc * f
                new[2, c] += dphio[c, 1, 0] * x1 + dphio[c, 1, 1] * x2 + dgamo[c, 1, 0] * tc * f
            if tc_col >= 0:
                new[1, tc_col] += gamo[0, 0] * tc * f
                new[2, tc_col] += gamo[1, 0] * tc * f
        else:
            vk = v[k]
            for r in range(3):
                for c in range(ncol):
                    new[r, c] = phi[r, 0] * s[0, c] + phi[r, 1] * s[1, c] + phi[r, 2] * s[2, c]
                for c in range(npar):
                    new[r, c] += (
                        dphi[c, r, 0] * x0
                        + dphi[c, r, 1] * x1
                        + dphi[c, r, 2] * x2
                        + dgam[c, r, 0] * vk
                        + dgam[c, r, 1] * tc * f
                    )
                if tc_col >= 0:
                    new[r, tc_col] += gam[r, 1] * tc * f
        if stuck[k + 1]:
            for c in range(ncol):
                new[1, c] = 0.0
                new[2, c] = s[2, c]
        for r in range(3):
            for c in range(ncol):
                s[r, c] = new[r, c]
    return m, gv


@dataclass(frozen=True)
class InformationModel:
    """The discretised model and its derivatives at the prior, built once per design.

    ``values``: R, L, Ke, J, B (``Kt = Ke``: J, B and Tc are those of the closure) and
    Tc (0: no Coulomb term); ``names``: the free parameters (logarithms)."""

    values: dict[str, float]
    names: tuple[str, ...]
    dt_s: float
    noise: Noise
    _mats: tuple[FloatArray, ...]

    @classmethod
    def build(
        cls, values: Mapping[str, float], names: Sequence[str], dt_s: float, noise: Noise
    ) -> InformationModel:
        p = {k: float(values[k]) for k in ("R", "L", "Ke", "J", "B")}
        p["Tc"] = float(values.get("Tc", 0.0))
        names = tuple(n for n in DESIGN_PARAMETERS if n in names and (n != "Tc" or p["Tc"] > 0))
        mech = [n for n in names]
        phi, gam, dphi, dgam = _zoh_and_derivatives(_driven, p, mech, dt_s)
        phio, gamo, dphio, dgamo = _zoh_and_derivatives(_open, p, mech, dt_s)
        for k, n in enumerate(mech):
            if n in ("R", "L", "Ke"):
                dphio[k] = 0.0
                dgamo[k] = 0.0
        return cls(
            dict(p), names, float(dt_s), noise, (phi, gam, dphi, dgam, phio, gamo, dphio, dgamo)
        )

    @property
    def n_par(self) -> int:
        return len(self.names)


def segment_information(
    model: InformationModel,
    voltage: FloatArray,
    current: FloatArray,
    speed: FloatArray,
    position: FloatArray,
) -> FloatArray:
    """The segment's parameter information (initial state profiled out), relative
    units: ``inv(I)`` holds relative variances. ``voltage`` NaN = armature open;
    ``current``, ``speed``, ``position`` the prior's trajectory on the same samples."""
    return _segment(model, voltage, current, speed, position, None)[0]


def segment_lag_terms(
    model: InformationModel,
    voltage: FloatArray,
    current: FloatArray,
    speed: FloatArray,
    position: FloatArray,
    lag_s: float,
) -> tuple[FloatArray, FloatArray]:
    """The segment's information and the gradient ``S' W r`` of what a current reading
    ``lag_s`` late leaves in the fit's residuals, both with the initial state profiled
    out: summed over a record's segments, ``solve(I, g)`` is the fit's bias (relative,
    per parameter; :func:`lag_bias`).

    The residual is ``r[k] = -lag di/dt`` at each sample's instant, from the left (the
    voltage held over the sample before it): ``L di/dt = v[k-1] - R i[k] - Ke w[k]``.
    Not a difference across samples: where L/R is below a sample the current's step has
    settled long before the next sample (a filter's lag does not show there), while the
    slow decay that follows it, on tau_m, is read ``lag / tau_m`` high (the gearmotor of
    the independent generator at 500 Hz, a first-order filter at 1.5 kHz: R -0.55 %,
    J +0.52 %; those errors follow the filter's lag)."""
    vals = model.values
    v_before = np.concatenate([[math.nan], np.asarray(voltage, float)[:-1]])
    didt = (v_before - vals["R"] * current - vals["Ke"] * speed) / vals["L"]
    ok = np.isfinite(v_before) & np.isfinite(voltage)
    r = np.where(ok, -lag_s * np.where(ok, didt, 0.0), 0.0)
    return _segment(model, voltage, current, speed, position, r)


def _segment(
    model: InformationModel,
    voltage: FloatArray,
    current: FloatArray,
    speed: FloatArray,
    position: FloatArray,
    current_residual: FloatArray | None,
) -> tuple[FloatArray, FloatArray]:
    traj = np.ascontiguousarray(np.column_stack([current, speed, position]))
    nxt = np.concatenate([speed[1:], speed[-1:]])
    fric = np.sign(speed + nxt)  # the friction's sign over each sample
    fric = np.where(fric == 0.0, np.sign(speed), fric)
    stuck = (speed == 0.0) & (nxt == 0.0)
    stuck = np.concatenate([stuck[:1], stuck[:-1]])  # sample k+1 held: it and k at rest
    noise = model.noise
    outs, wts, nuis = [], [], []
    driven = bool(np.isfinite(voltage).any())
    if noise.current_sd > 0 and driven:
        outs.append(0)
        wts.append(1.0 / noise.current_sd)
    if noise.uses_speed:
        outs.append(1)
        wts.append(1.0 / max(noise.speed_sd, 1e-12))
    else:
        outs.append(2)
        wts.append(1.0 / noise.position_sd)
    nuis = [0, 1] if math.isfinite(voltage[0]) else [1]
    if not noise.uses_speed:
        nuis.append(2)
    res = np.zeros((0, len(outs)))
    if current_residual is not None:
        res = np.zeros((voltage.size, len(outs)))
        if outs[0] == 0:  # the current is read: its residual; the others' are 0
            res[:, 0] = current_residual
    tc_col = model.names.index("Tc") if "Tc" in model.names else -1
    phi, gam, dphi, dgam, phio, gamo, dphio, dgamo = model._mats
    m, gv = _accumulate(
        np.ascontiguousarray(voltage, dtype=float),
        np.ascontiguousarray(fric, dtype=float),
        np.ascontiguousarray(stuck),
        traj,
        phi,
        gam,
        dphi,
        dgam,
        phio,
        gamo,
        dphio,
        dgamo,
        tc_col,
        model.values["Tc"],
        np.asarray(outs, dtype=np.int64),
        np.asarray(wts, dtype=float),
        np.asarray(nuis, dtype=np.int64),
        np.ascontiguousarray(res),
    )
    k = model.n_par
    a, b, c = m[:k, :k], m[:k, k:], m[k:, k:]
    ga, gb = gv[:k], gv[k:]
    # the initial state profiled out; a state the outputs do not see carries nothing
    keep = np.diag(c) > 1e-12 * max(float(np.max(np.diag(c))), 1e-300)
    b, c, gb = b[:, keep], c[np.ix_(keep, keep)], gb[keep]
    try:
        cb = np.linalg.solve(c, np.column_stack([b.T, gb]))
    except np.linalg.LinAlgError:
        cb = np.linalg.pinv(c) @ np.column_stack([b.T, gb])
    return a - b @ cb[:, :-1], ga - b @ cb[:, -1]


def lag_bias(info: FloatArray, grad: FloatArray, names: Sequence[str]) -> dict[str, float]:
    """The relative bias per parameter a lagging current reading leaves in the fit
    (linearised: one Gauss-Newton step on the residual it adds), from the record's total
    information and gradient (:func:`segment_lag_terms`); 0 where undetermined."""
    k = len(names)
    if k == 0:
        return {}
    scale = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    try:
        x = np.linalg.lstsq(info / np.outer(scale, scale), grad / scale, rcond=1e-12)[0] / scale
    except np.linalg.LinAlgError:
        return dict.fromkeys(names, 0.0)
    return {n: float(x[i]) if math.isfinite(x[i]) else 0.0 for i, n in enumerate(names)}


def relative_sd(info: FloatArray, names: Sequence[str]) -> dict[str, float]:
    """Relative standard deviation of each parameter from the total information
    (``inf`` where the information leaves it undetermined)."""
    k = len(names)
    if k == 0:
        return {}
    scale = np.sqrt(np.clip(np.diag(info), 1e-300, None))
    norm = info / np.outer(scale, scale)
    try:
        w, vec = np.linalg.eigh(norm)
    except np.linalg.LinAlgError:
        return {n: math.inf for n in names}
    bad = w <= 1e-12 * max(float(w.max()), 1e-300)
    winv = np.where(bad, 0.0, 1.0 / np.where(bad, 1.0, w))
    cov = (vec * winv) @ vec.T / np.outer(scale, scale)
    out = {}
    for i, n in enumerate(names):
        # a direction the data do not see: that parameter is undetermined
        hidden = bool(np.any(bad & (np.abs(vec[i]) > 1e-3)))
        out[n] = math.inf if hidden or info[i, i] <= 0 else float(math.sqrt(max(cov[i, i], 0.0)))
    return out


def systematic_rsd(values: Mapping[str, float], noise: Noise, dt_s: float) -> dict[str, float]:
    """Relative errors the information cannot see, as standard deviations (half the
    95 % bound): a current read ``lag`` late is, below 1/tau_e, ``i - lag di/dt``, so
    the fit's ``L di/dt`` takes ``R lag`` into L (relative ``lag / tau_e``; measured on
    the independent generator, first-order anti-alias filters at 3x the rate: L biased
    1.2 % on the servo and 2.4 % on the scooter motor, 1.8 % and 3.0 % by this bound),
    whatever the plan. Added in quadrature to the information's sd, the predicted 95 %
    interval covers a bias up to the bound."""
    if noise.current_sd <= 0:
        return {}
    lag = noise.current_lag(dt_s)
    r, ind = float(values.get("R", 0.0)), float(values.get("L", 0.0))
    if lag <= 0 or r <= 0 or ind <= 0:
        return {}
    return {"L": lag * r / ind / 1.96}


def with_systematic(rsd: Mapping[str, float], floor: Mapping[str, float]) -> dict[str, float]:
    """Each relative sd with its systematic part added in quadrature."""
    return {n: math.hypot(v, floor.get(n, 0.0)) for n, v in rsd.items()}
