"""Seed 000's classical chain: steady-state staircase, then the coast-down.

* **Staircase** (no-load steady states at several voltages). With ``R`` known
  (multimeter), the back-EMF ``E = V - R i`` against ``w`` is a line whose slope
  is ``Ke`` (its intercept, a few tenths of a volt on real motors, is reported:
  it is what a brush drop looks like). Without ``R``, ``V = R i + Ke w`` is
  regressed instead (R is then weakly determined: the no-load current varies
  little). At steady state ``Kt i = Tc + B w``: Coulomb plus viscous friction,
  never viscous alone (seed 000's own Table 4 has an intercept of ~0.025 N*m).
* **Coast-down** (armature open): ``J dw/dt = -(Tc + B w)`` until the rotor
  stops. With the staircase friction, the whole curve is fitted for ``J`` and
  the initial speed (not one average slope), and the friction's uncertainty is
  propagated into ``J``'s interval. A free-shape fit (``Tc/J`` and ``B/J`` from
  the curve alone) shows whether the coast-down and the staircase agree.

Tables are read as segments (see :mod:`pmdc_ident.dataio.csvio`): each
staircase level a segment of constant rows, the retardation table a ``coast``
segment with empty voltage cells. Time series work the same way: the steady
part of a level is its last 30 %.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment, TestKind
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimators.solver import least_squares
from pmdc_ident.core.estimators.student_t import t_quantile

__all__ = [
    "ClassicalResult",
    "CoastFit",
    "StaircaseFit",
    "SteadyPoint",
    "classical_chain",
    "coast_speed",
    "fit_coastdown",
    "fit_staircase",
    "staircase_levels",
    "steady_state_points",
]

FloatArray = NDArray[np.float64]
STEADY_FRACTION = 0.3


@dataclass(frozen=True)
class SteadyPoint:
    label: str
    voltage_v: float
    current_a: float
    speed_rad_s: float


def steady_state_points(segments: Sequence[Segment]) -> list[SteadyPoint]:
    """Average of the last 30 % of each staircase level (a table's constant rows).

    A staircase segment is one level, or - a time series recorded as one labelled
    segment - several: each hold of its voltage (at least :data:`MIN_LEVEL_SAMPLES`
    samples) is a level of its own (the assumption register's ``staircase-levels``)."""
    pts: list[SteadyPoint] = []
    for s in segments:
        if s.kind is not TestKind.STAIRCASE:
            continue
        if s.voltage is None or s.current is None:
            msg = f"staircase segment {s.label!r} needs voltage and current columns"
            raise DataError(msg)
        levels = staircase_levels(s)
        for k, (a, b) in enumerate(levels):
            k0 = min(a + int((b - a) * (1.0 - STEADY_FRACTION)), b - 1)
            v = s.voltage[k0:b]
            if np.isnan(v).any():
                msg = f"staircase segment {s.label!r}: the armature is open in its steady part"
                raise DataError(msg)
            w = s.speed_or_derivative()[k0:b]
            label = s.label if len(levels) == 1 else f"{s.label}[{k + 1}]"
            pts.append(
                SteadyPoint(label, float(v.mean()), float(s.current[k0:b].mean()), float(w.mean()))
            )
    return pts


MIN_LEVEL_SAMPLES = 10  # a voltage hold this long inside a staircase segment is a level


def staircase_levels(s: Segment) -> list[tuple[int, int]]:
    """Sample ranges of the voltage levels a staircase segment holds (one when it holds
    one level, as a table's row group does)."""
    v = s.voltage
    if v is None or s.n < 2 * MIN_LEVEL_SAMPLES:
        return [(0, s.n)]
    finite = v[np.isfinite(v)]
    span = float(np.ptp(finite)) if finite.size else 0.0
    if span == 0.0:
        return [(0, s.n)]
    jumps = np.flatnonzero(np.abs(np.diff(np.nan_to_num(v))) > 0.02 * span) + 1
    bounds = [0, *jumps.tolist(), s.n]
    holds = [(a, b) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
    long_ = [(a, b) for a, b in holds if b - a >= MIN_LEVEL_SAMPLES]
    return long_ if len(long_) > 1 else [(0, s.n)]


@dataclass(frozen=True)
class StaircaseFit:
    """Ke and friction from steady states. Intervals are 95 % (Student t)."""

    n_points: int
    R: float
    R_fitted: bool
    R_ci95: tuple[float, float] | None
    Ke: float
    Ke_ci95: tuple[float, float]
    emf_offset_v: float  # intercept of E against w (0 when R is fitted)
    Kt: float
    Tc: float
    Tc_ci95: tuple[float, float]
    B: float
    B_ci95: tuple[float, float]
    friction_cov: FloatArray  # covariance of (Tc, B)
    rms_torque_nm: float


def _ols(X: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray, float]:
    beta, *_ = np.linalg.lstsq(X, y, rcond=None)
    res = y - X @ beta
    dof = max(len(y) - X.shape[1], 1)
    s2 = float(res @ res) / dof
    cov = s2 * np.linalg.pinv(X.T @ X)
    return beta, cov, math.sqrt(s2)


def _ci(value: float, var: float, dof: int) -> tuple[float, float]:
    q = t_quantile(0.975, max(dof, 1))
    half = q * math.sqrt(max(var, 0.0))
    return (value - half, value + half)


def fit_staircase(
    points: Sequence[SteadyPoint], *, R: float | None = None, Kt: float | None = None
) -> StaircaseFit:
    """Ke from the back-EMF line, then ``Kt i = Tc + B w`` (Kt = Ke unless given)."""
    n = len(points)
    if n < 3:
        msg = f"the staircase needs at least 3 steady levels, got {n}"
        raise DataError(msg)
    V = np.array([p.voltage_v for p in points])
    i = np.array([p.current_a for p in points])
    w = np.array([p.speed_rad_s for p in points])
    if np.ptp(w) <= 1e-9 * max(1.0, float(np.max(np.abs(w)))):
        msg = "the staircase levels all have the same speed: no excitation to fit Ke"
        raise DataError(msg)
    if R is None:
        beta, cov, _ = _ols(np.column_stack([i, w]), V)
        R_val, Ke = float(beta[0]), float(beta[1])
        R_ci = _ci(R_val, cov[0, 0], n - 2)
        Ke_ci = _ci(Ke, cov[1, 1], n - 2)
        offset = 0.0
    else:
        E = V - R * i
        beta, cov, _ = _ols(np.column_stack([w, np.ones(n)]), E)
        Ke, offset = float(beta[0]), float(beta[1])
        Ke_ci = _ci(Ke, cov[0, 0], n - 2)
        R_val, R_ci = float(R), None
    kt = Ke if Kt is None else float(Kt)
    beta_f, cov_f, s_f = _ols(np.column_stack([np.ones(n), w]), kt * i)
    return StaircaseFit(
        n_points=n,
        R=R_val,
        R_fitted=R is None,
        R_ci95=R_ci,
        Ke=Ke,
        Ke_ci95=Ke_ci,
        emf_offset_v=offset,
        Kt=kt,
        Tc=float(beta_f[0]),
        Tc_ci95=_ci(float(beta_f[0]), cov_f[0, 0], n - 2),
        B=float(beta_f[1]),
        B_ci95=_ci(float(beta_f[1]), cov_f[1, 1], n - 2),
        friction_cov=cov_f,
        rms_torque_nm=s_f,
    )


def coast_speed(t: FloatArray, w0: float, a: float, c: float) -> FloatArray:
    """Speed under ``dw/dt = -c - a w`` (``a = B/J``, ``c = Tc/J``), held at 0 once stopped."""
    t = np.asarray(t, dtype=float)
    if a > 1e-12:
        w = (w0 + c / a) * np.exp(-a * t) - c / a
    else:
        w = w0 - c * t
    if w0 >= 0:
        return np.maximum(w, 0.0)
    return w


@dataclass(frozen=True)
class CoastFit:
    """J from the coast-down with the staircase friction (and a free-shape check)."""

    J: float
    J_ci95: tuple[float, float]
    J_stderr: float
    J_stderr_fit: float  # from the curve's residuals alone
    w0_rad_s: float
    Tc: float
    B: float
    rms_speed_rad_s: float
    n_points: int
    # free shape: dw/dt = -c - a w fitted alone; J implied by Tc/c and B/a
    decel_c_rad_s2: float | None
    decel_a_per_s: float | None
    J_from_Tc: float | None
    J_from_B: float | None
    average_slope_rad_s2: float  # the seeds' "one average slope", for comparison


def _coast_data(seg: Segment) -> tuple[FloatArray, FloatArray]:
    mask = seg.open_mask if seg.voltage is not None else np.ones(seg.n, dtype=bool)
    if not mask.any():
        msg = f"coast segment {seg.label!r} has no open-armature samples (empty voltage cells)"
        raise DataError(msg)
    k0 = int(np.argmax(mask))
    k1 = k0 + int(np.argmin(mask[k0:])) if not mask[k0:].all() else seg.n
    t = seg.t[k0:k1] - seg.t[k0]
    w = seg.speed_or_derivative()[k0:k1]
    if t.size < 3:
        msg = f"coast segment {seg.label!r}: fewer than 3 open-armature samples"
        raise DataError(msg)
    return t, w


def coast_speed_jacobian(t: FloatArray, w0: float, a: float, c: float) -> FloatArray:
    """d :func:`coast_speed` / d (w0, a, c), one row per time (0 where it is held at 0)."""
    t = np.asarray(t, dtype=float)
    jac = np.empty((t.size, 3))
    if a > 1e-12:
        e = np.exp(-a * t)
        jac[:, 0] = e
        jac[:, 1] = -t * (w0 + c / a) * e - (c / a**2) * np.expm1(-a * t)
        jac[:, 2] = np.expm1(-a * t) / a
    else:
        jac[:, 0] = 1.0
        jac[:, 1] = 0.0
        jac[:, 2] = -t
    if w0 >= 0:
        jac[coast_speed(t, w0, a, c) <= 0.0] = 0.0
    return jac


def _fit_j(t: FloatArray, w: FloatArray, Tc: float, B: float) -> tuple[float, float, float, float]:
    """(J, w0, stderr of J from the fit, rms) with Tc, B given."""
    j_guess = max(Tc + B * abs(w[0]), 1e-12) / max(abs(w[0] - w[-1]) / max(t[-1], 1e-9), 1e-9)

    def resid(z: FloatArray) -> FloatArray:
        J = math.exp(z[0])
        return coast_speed(t, z[1], B / J, Tc / J) - w

    def jac(z: FloatArray) -> FloatArray:
        J = math.exp(z[0])
        d = coast_speed_jacobian(t, z[1], B / J, Tc / J)
        # a = B/J and c = Tc/J: d/d(log J) = -a d/da - c d/dc
        return np.column_stack([-(B / J) * d[:, 1] - (Tc / J) * d[:, 2], d[:, 0]])

    sol = least_squares(resid, jac, [math.log(j_guess), float(w[0])])
    r = sol.fun
    dof = max(t.size - 2, 1)
    s2 = float(r @ r) / dof
    cov = s2 * np.linalg.pinv(sol.jac.T @ sol.jac)
    J = math.exp(sol.x[0])
    return J, float(sol.x[1]), J * math.sqrt(max(cov[0, 0], 0.0)), math.sqrt(float(r @ r) / t.size)


def _free_shape(t: FloatArray, w: FloatArray, a0: float, c0: float) -> tuple[float, float]:
    """(a, c) of ``dw/dt = -c - a w`` fitted to the coast curve alone."""

    def unpack(z: FloatArray) -> tuple[float, float, float]:
        zz = np.clip(z[1:], -50.0, 50.0)
        return float(z[0]), math.exp(zz[0]), math.exp(zz[1])

    def resid(z: FloatArray) -> FloatArray:
        return coast_speed(t, *unpack(z)) - w

    def jac(z: FloatArray) -> FloatArray:
        w0, a, c = unpack(z)
        d = coast_speed_jacobian(t, w0, a, c)
        inside = np.abs(z[1:]) < 50.0  # the clip holds the log-rates at +-50
        return np.column_stack([d[:, 0], a * d[:, 1] * inside[0], c * d[:, 2] * inside[1]])

    sol = least_squares(resid, jac, [w[0], math.log(a0), math.log(c0)])
    _, a, c = unpack(sol.x)
    return a, c


def fit_coastdown(
    seg: Segment, *, Tc: float, B: float, friction_cov: FloatArray | None = None
) -> CoastFit:
    """Fit ``J`` to a coast-down with known friction ``Tc + B w`` (see module docs)."""
    if Tc < 0 or B < 0 or Tc + B <= 0:
        msg = f"coast-down needs positive friction (got Tc={Tc:.3g} N*m, B={B:.3g} N*m*s/rad)"
        raise DataError(msg)
    t, w = _coast_data(seg)
    if abs(w[0]) <= 0 or np.ptp(w) <= 0:
        msg = f"coast segment {seg.label!r}: the speed does not change (no coast-down)"
        raise DataError(msg)
    J, w0, se_fit, rms = _fit_j(t, w, Tc, B)
    var = se_fit**2
    if friction_cov is not None:
        g = np.zeros(2)
        for k, (dTc, dB) in enumerate(((1e-4 * max(Tc, 1e-9), 0.0), (0.0, 1e-4 * max(B, 1e-12)))):
            Jp, *_ = _fit_j(t, w, Tc + dTc, B + dB)
            g[k] = (Jp - J) / (dTc + dB)
        var += float(g @ friction_cov @ g)
    se = math.sqrt(var)
    dof = max(t.size - 2, 1)
    q = t_quantile(0.975, dof)
    # free shape (needs enough moving points)
    moving = w > 0.02 * abs(w[0])
    c = a = jtc = jb = None
    if moving.sum() >= 4:
        a, c = _free_shape(t, w, max(B, 1e-12) / J, max(Tc, 1e-12) / J)
        jtc = Tc / c if Tc > 0 else None
        jb = B / a if B > 0 else None
    stop = int(np.argmax(w <= 0)) if (w <= 0).any() else t.size - 1
    avg = float((w[0] - w[stop]) / max(t[stop], 1e-12))
    return CoastFit(
        J=J,
        J_ci95=(J - q * se, J + q * se),
        J_stderr=se,
        J_stderr_fit=se_fit,
        w0_rad_s=w0,
        Tc=Tc,
        B=B,
        rms_speed_rad_s=rms,
        n_points=int(t.size),
        decel_c_rad_s2=c,
        decel_a_per_s=a,
        J_from_Tc=jtc,
        J_from_B=jb,
        average_slope_rad_s2=avg,
    )


@dataclass(frozen=True)
class ClassicalResult:
    staircase: StaircaseFit | None
    coast: CoastFit | None
    values: dict[str, float]
    ci95: dict[str, tuple[float, float] | None]
    notes: tuple[str, ...]
    stderr: dict[str, float | None] = field(default_factory=dict)


def classical_chain(
    segments: Sequence[Segment], *, fixed: dict[str, float] | None = None
) -> ClassicalResult:
    """Run the staircase and coast-down steps on whatever of them the data hold."""
    fixed = fixed or {}
    notes: list[str] = []
    pts = steady_state_points(segments)
    stair = None
    values: dict[str, float] = {}
    ci95: dict[str, tuple[float, float] | None] = {}
    if pts:
        stair = fit_staircase(pts, R=fixed.get("R"), Kt=fixed.get("Kt"))
        values.update(
            R=stair.R,
            Ke=stair.Ke,
            Kt=stair.Kt,
            B=stair.B,
            **{"coulomb_friction.torque_nm": stair.Tc},
        )
        ci95.update(
            R=stair.R_ci95,
            Ke=stair.Ke_ci95,
            Kt=stair.Ke_ci95 if "Kt" not in fixed else None,
            B=stair.B_ci95,
            **{"coulomb_friction.torque_nm": stair.Tc_ci95},
        )
        if stair.R_fitted:
            notes.append(
                "classical: R regressed from the staircase (weakly determined: the no-load "
                f"current varies little); a multimeter value ({opt('fix')} R=...) is better"
            )
        else:
            notes.append(
                f"classical: back-EMF E = V - R*i with R = {stair.R:.4g} ohm; "
                f"intercept {stair.emf_offset_v:+.3g} V"
            )
        notes.append(
            f"classical: friction Kt*i = Tc + B*w with Kt = {stair.Kt:.4g}: "
            f"Tc = {stair.Tc:.4g} N*m, B = {stair.B:.3g} N*m*s/rad"
        )
        if stair.Tc_ci95[1] < 0:
            notes.append(
                "classical: the friction intercept is negative: the levels may not have "
                "reached steady state (hold each one several mechanical time constants)"
            )
    coasts = [s for s in segments if s.kind is TestKind.COAST]
    coast = None
    if coasts and stair is not None:
        if stair.Tc <= 0 and stair.B <= 0:
            notes.append("classical: staircase friction is not positive; J not computed")
        else:
            coast = fit_coastdown(
                coasts[0],
                Tc=max(stair.Tc, 0.0),
                B=max(stair.B, 0.0),
                friction_cov=stair.friction_cov,
            )
            values["J"] = coast.J
            ci95["J"] = coast.J_ci95
            notes.append(
                f"classical: coast-down fitted with Coulomb + viscous deceleration: "
                f"J = {coast.J:.4g} kg*m^2 (95 % [{coast.J_ci95[0]:.3g}, {coast.J_ci95[1]:.3g}])"
            )
            if coast.average_slope_rad_s2 > 0:
                j_avg = (coast.Tc + coast.B * coast.w0_rad_s) / coast.average_slope_rad_s2
                notes.append(
                    f"classical: one average slope ({coast.average_slope_rad_s2:.4g} rad/s^2) "
                    f"with the friction torque at the initial speed would give J = {j_avg:.3g}; "
                    "the deceleration is not uniform, so the curve fit is the estimate"
                )
            if coast.J_from_Tc is not None and coast.J_from_B is not None:
                notes.append(
                    "classical: the coast curve alone implies J = "
                    f"{coast.J_from_Tc:.3g} (from Tc) and {coast.J_from_B:.3g} (from B)"
                )
    elif coasts:
        notes.append("classical: a coast-down without a staircase gives J only up to friction")
    stderr: dict[str, float | None] = {}
    if stair is not None:
        q = t_quantile(0.975, max(stair.n_points - 2, 1))
        for name, ci in ci95.items():
            if ci is not None and name != "J":
                stderr[name] = (ci[1] - ci[0]) / (2.0 * q)
    if coast is not None:
        stderr["J"] = coast.J_stderr
    return ClassicalResult(stair, coast, values, ci95, tuple(notes), stderr)
