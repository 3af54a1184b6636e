"""Output-error identification: simulation residuals over all segments at once.

Seed 001's method done properly. The model is simulated free-running on every
segment from its own (estimated) initial state and, for a segment cut from a
longer record, its history (``Segment.history_voltage`` fills a delay line,
``Segment.history_heat_a2s`` starts a resistance drift), and the residuals on current
and speed (or position, when speed is absent) are scaled per signal by the
noise level, so the cost is the negative log-likelihood of white Gaussian
measurement noise. Parameters:

* the motor parameters ``R, L, Ke, Kt, J, B`` (positive, fitted in log space);
* effect parameters ``"<effect>.<field>"`` of the effects present in the model
  (only fields whose :class:`~pmdc_ident.core.effects.ParamSpec` is ``fitted``);
* per segment, the initial current, speed and (when position is fitted) angle.

Two simulators share one Levenberg-Marquardt solver:

* the **fast path** (the linear model plus ``coulomb_friction``, ``stribeck_friction``,
  ``quadratic_drag``, ``load_torque``,
  ``current_offset``): one exact zero-order-hold step per sample, with the
  sensitivity equations propagated alongside the state in a numba kernel (the
  sensitivity equations are themselves linear ZOH systems; their matrices come
  from Van Loan block exponentials), so the Jacobian is analytic;
* the **general path** (any other effect): :func:`pmdc_ident.core.model.simulate`
  with sub-steps and a forward-difference Jacobian.

Scale ambiguity (DESIGN.md §2): from voltage, current and speed only, ``(Kt, J,
B)`` are known up to a common factor. ``closure="Kt=Ke"`` (the default) ties
``Kt`` to ``Ke``; fixing ``Kt`` or ``J`` replaces the closure. Without voltage
(a current-controlled drive) only the mechanical side is fitted, given ``Kt``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit
from pmdc_ident.core.data import Segment
from pmdc_ident.core.effects import EFFECT_TYPES, Effect
from pmdc_ident.core.errors import DataError, ParameterError
from pmdc_ident.core.model import (
    Model,
    _coefficients,
    _effects_kernel,
    _expm_small,
    discretize_zoh,
    simulate,
)
from pmdc_ident.core.params import PARAMETER_NAMES, PARAMETER_UNITS, MotorParams

__all__ = [
    "CLOSURE_KT_KE",
    "FitResult",
    "Prediction",
    "fit_output_error",
    "parameter_unit",
]

FloatArray = NDArray[np.float64]
CLOSURE_KT_KE = "Kt=Ke"
FAST_EFFECTS = frozenset(
    {"coulomb_friction", "stribeck_friction", "quadratic_drag", "load_torque", "current_offset"}
)
SIGNALS = ("current", "speed", "position")
# Sensitivity column layout of the fast kernel.
_NS = 14
_COL = {"R": 0, "L": 1, "Ke": 2, "Kt": 3, "J": 4, "B": 5}
_COL_TC, _COL_TL, _COL_I0, _COL_W0, _COL_TH0 = 6, 7, 8, 9, 10
_COL_TS, _COL_WS, _COL_CQ = 11, 12, 13
# sub-steps for samples where friction acts at zero speed (as core.model.simulate)
_SUBSTEPS = 8
# L is not identifiable from dynamic data when the current settles within a sample.
_MIN_TAU_E_SAMPLES = 1.0
_NEEDED_TAU_E_SAMPLES = 5.0


def parameter_unit(name: str) -> str:
    """Unit of a motor or ``effect.field`` parameter name."""
    if name in PARAMETER_UNITS:
        return PARAMETER_UNITS[name]
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    if cls is None or fld not in cls.SPECS:
        msg = f"unknown parameter {name!r}"
        raise ParameterError(msg)
    return cls.SPECS[fld].unit


# ---------------------------------------------------------------------------
# Results
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Prediction:
    """Free-run simulation of one segment (arrays per sample, SI units)."""

    label: str
    t: FloatArray
    current: FloatArray
    speed: FloatArray
    position: FloatArray


@dataclass(frozen=True)
class FitResult:
    """Result of :func:`fit_output_error`.

    ``values`` holds every model parameter (free and fixed); ``ci95``/``stderr``
    are ``None`` for fixed or non-identifiable ones. ``covariance`` is over
    ``covariance_names`` (the free parameters, physical units). ``rms`` is the
    free-run residual RMS per fitted signal in its own unit; ``noise`` the
    per-signal noise level the residuals were scaled by.
    """

    model: Model
    values: dict[str, float]
    ci95: dict[str, tuple[float, float] | None]
    stderr: dict[str, float | None]
    covariance: FloatArray
    covariance_names: tuple[str, ...]
    identifiable: dict[str, bool]
    reasons: dict[str, str]
    cost: float
    n_samples: int
    rms: dict[str, float]
    noise: dict[str, float]
    free: tuple[str, ...]
    fixed: dict[str, float]
    closure: str | None
    initial_states: dict[str, tuple[float, float, float]]
    nfev: int
    iterations: int
    converged: bool
    message: str
    elapsed_s: float
    fast_path: bool
    warnings: tuple[str, ...] = ()
    added_inertia: dict[str, float] = field(default_factory=dict)
    _fitted_segments: dict[str, int] = field(default_factory=dict, repr=False)

    def simulate_segments(
        self,
        segments: Sequence[Segment],
        *,
        use_fitted_initial_states: bool = True,
        added_inertia: Mapping[str, float] | None = None,
    ) -> list[Prediction]:
        """Free-run predictions of the fitted model on (possibly held-out) segments.

        The initial state is the fitted one for a segment of the fit (same label
        and length) and otherwise taken from the segment's first samples. A
        segment recorded with a known added inertia (``added_inertia``, by label;
        default: the fit's) is simulated with it.
        """
        out: list[Prediction] = []
        for seg in segments:
            x0 = _x0_from_data(seg)
            key = seg.label
            if (
                use_fitted_initial_states
                and key in self.initial_states
                and self._fitted_segments.get(key) == seg.n
            ):
                x0 = np.array(self.initial_states[key], dtype=float)
            added = self.added_inertia if added_inertia is None else added_inertia
            x = _predict(self.model, seg, x0, self.fast_path, float(added.get(key, 0.0)))
            out.append(Prediction(seg.label, seg.t.copy(), x[:, 0], x[:, 1], x[:, 2]))
        return out

    def summary(self) -> str:
        lines = [f"{'parameter':<28} {'value':>12}  {'95 % interval':<28} unit"]
        for name, value in self.values.items():
            ci = self.ci95.get(name)
            if name in self.fixed:
                ci_s = "(fixed)"
            elif not self.identifiable.get(name, True):
                ci_s = "not identifiable"
            elif ci is None:
                ci_s = "-"
            else:
                ci_s = f"[{ci[0]:.5g}, {ci[1]:.5g}]"
            lines.append(f"{name:<28} {value:>12.6g}  {ci_s:<28} {parameter_unit(name)}")
        return "\n".join(lines)


# ---------------------------------------------------------------------------
# Parameters
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class _Par:
    name: str
    lower: float
    upper: float
    log: bool


def _model_values(model: Model) -> dict[str, float]:
    vals = dict(model.params.as_dict())
    for e in model.effects:
        for fname, v in e.as_dict().items():
            vals[f"{e.NAME}.{fname}"] = float(v)
    return vals


def _param_info(name: str) -> _Par:
    if name in PARAMETER_NAMES:
        return _Par(name, 0.0, math.inf, True)
    eff, _, fld = name.partition(".")
    spec = EFFECT_TYPES[eff].SPECS[fld]
    return _Par(name, spec.lower, spec.upper, spec.lower > 0.0)


def _build_model(base: Model, values: Mapping[str, float]) -> Model:
    params = MotorParams(**{n: values[n] for n in PARAMETER_NAMES})
    effects: list[Effect] = []
    for e in base.effects:
        data = {f: values[f"{e.NAME}.{f}"] for f in e.as_dict()}
        effects.append(type(e)(**data))
    return Model(params, tuple(effects))


# ---------------------------------------------------------------------------
# Segments prepared for fitting
# ---------------------------------------------------------------------------
@dataclass
class _Seg:
    seg: Segment
    dt: float
    voltage: FloatArray | None  # None: current-driven (mechanical only)
    current_in: FloatArray  # measured current (input in current mode)
    outputs: list[tuple[int, FloatArray]]  # (state index 0/1/2, measured)
    nuis: list[int]  # state indices of the free initial states
    x0: FloatArray
    dJ: float = 0.0  # known inertia added for this segment (kg*m^2)


def _x0_from_data(seg: Segment) -> FloatArray:
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


def _prepare(
    segments: Sequence[Segment],
    warnings: list[str],
    added_inertia: Mapping[str, float] | None = None,
) -> list[_Seg]:
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
    out: list[_Seg] = []
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
            _Seg(
                s,
                s.dt_s,
                s.voltage,
                cur,
                outputs,
                nuis,
                _x0_from_data(s),
                float(added.get(s.label, 0.0)),
            )
        )
    if jittery:
        warnings.append(
            "sample period not uniform (timestamp jitter above 1 %) in "
            f"{', '.join(jittery)}: each simulated on its median period"
        )
    return out


def _noise_level(signal: int, y: FloatArray, seg: Segment) -> float:
    """Robust white-noise level from second differences, floored by resolution."""
    if y.size < 8:
        return max(1e-9, float(np.std(y)))
    d2 = np.diff(y, 2)
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / math.sqrt(6.0)
    scale = float(np.max(np.abs(y))) or 1.0
    step = float(np.min(np.abs(np.diff(np.unique(y))))) if np.unique(y).size > 1 else 0.0
    floor = max(1e-4 * scale, step / math.sqrt(12.0), 1e-12)
    return max(sigma, floor)


# ---------------------------------------------------------------------------
# Fast kernel: exact ZOH with sensitivities
# ---------------------------------------------------------------------------
def _system(p: MotorParams, closed: bool) -> tuple[FloatArray, list[FloatArray]]:
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


def _zoh_with_derivatives(
    p: MotorParams, dt: float, closed: bool
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Phi (3x3), Gamma (3x2) and their derivatives (6,3,3), (6,3,2) by Van Loan.

    The derivatives are with respect to ``log(p)`` (``p dPhi/dp``) for R..B.
    """
    m, dms = _system(p, closed)
    e = _expm_small(m * dt)
    dphi = np.zeros((6, 3, 3))
    dgam = np.zeros((6, 3, 2))
    big = np.zeros((10, 10))
    big[:5, :5] = m
    big[5:, 5:] = m
    for j, dm in enumerate(dms):
        if not dm.any():
            continue
        big[:5, 5:] = dm
        de = _expm_small(big * dt)[:5, 5:]
        dphi[j] = de[:3, :3]
        dgam[j] = de[:3, 3:]
    phi = np.ascontiguousarray(e[:3, :3])
    gam = np.ascontiguousarray(e[:3, 3:])
    if not closed:
        phi[0, :] = 0.0  # open armature: no current
        phi[:, 0] = 0.0
        gam[0, :] = 0.0
    return phi, gam, dphi, dgam


@njit
def _fast_kernel(
    v,
    imeas,
    cmode,
    phc,
    gac,
    dphc,
    dgac,
    pho,
    gao,
    dpho,
    dgao,
    el,
    tc,
    tl,
    kt,
    fx,
    x0,
    want_s,
    nc,
    y,
    oidx,
    osc,
    mx,
    off,
    cur_off,
    coef,
    phs,
    gas,
    nsub,
    hs,
):  # pragma: no cover - jitted
    """Simulate one segment; returns the states (n,3) and, with ``want_s``, the
    normal-equation blocks ``A = J^T J`` and ``g = J^T r`` of its residuals.

    Sensitivities (14 columns: R..B per log p, Tc, T_load, i0, w0, th0, Ts, ws,
    Cq) are propagated for the columns ``nc`` only and mapped to the Jacobian
    columns by ``mx`` (plus ``off`` on current rows, the current-offset
    column); residuals are ``(x[oidx] (+ cur_off) - y) * osc`` per output.

    Samples where friction acts at zero speed (a stuck rotor, a start from rest, a
    zero crossing) are re-simulated with ``nsub`` sub-steps by the effects kernel of
    :mod:`pmdc_ident.core.model` (coefficients ``coef``, sub-step matrices ``phs``,
    ``gas``), so breakaway and stopping are timed as in ``simulate``; the
    sensitivities there keep the one-step approximation.

    Torques opposing +w are held over each sample at their value for w[k]:
    ``T = T_load + sign(w) (Tc + Ts exp(-(w/ws)^2)) + Cq w|w|`` (``fx`` = [Ts, ws,
    Cq]); their dependence on w enters the sensitivity recursion.

    ``cmode``: current-driven (mechanical only; ``imeas`` is the input).
    ``el``: rotor-held electrical step [a, b, da/dR, da/dL, db/dR, db/dL].
    """
    n = v.shape[0]
    X = np.empty((n, 3))
    ts, ws, cq = fx[0], fx[1], fx[2]
    t_static = tc + ts
    m = mx.shape[1]
    no = oidx.shape[0]
    A = np.zeros((m, m))
    g = np.zeros(m)
    jr = np.zeros(m)
    s = np.zeros((3, 14))
    sn = np.zeros((3, 14))
    need6 = np.zeros(6, dtype=np.bool_)
    for c in nc:
        if c < 6:
            need6[c] = True
    x = np.empty(3)
    xn = np.empty(3)
    st5 = np.zeros(5)
    vbuf = np.zeros(1)
    refine = nsub > 1 and not cmode and t_static > 0.0
    x[0], x[1], x[2] = x0[0], x0[1], x0[2]
    if cmode:
        x[0] = imeas[0]
    s[0, 8] = 1.0
    s[1, 9] = 1.0
    s[2, 10] = 1.0
    if cmode:
        s[0, 8] = 0.0
    stuck = t_static > 0.0 and x[1] == 0.0
    for k in range(n):
        X[k, 0] = x[0]
        X[k, 1] = x[1]
        X[k, 2] = x[2]
        if want_s:
            for o in range(no):
                idx = oidx[o]
                val = x[idx] + (cur_off if idx == 0 else 0.0)
                r = (val - y[k, o]) * osc[o]
                for c2 in range(m):
                    acc = off[c2] if idx == 0 else 0.0
                    for c in nc:
                        acc += s[idx, c] * mx[c, c2]
                    jr[c2] = acc * osc[o]
                for c2 in range(m):
                    g[c2] += jr[c2] * r
                    for c3 in range(c2 + 1):
                        A[c2, c3] += jr[c2] * jr[c3]
        if k == n - 1:
            break
        vk = v[k]
        is_open = cmode or math.isnan(vk)
        if cmode:
            x[0] = imeas[k]
        if stuck:
            if is_open:
                xn[0] = imeas[k + 1] if cmode else 0.0
                xn[1] = 0.0
                xn[2] = x[2]
                if want_s:
                    for c in nc:
                        sn[0, c] = 0.0
                        sn[1, c] = 0.0
                        sn[2, c] = s[2, c]
                drive = kt * xn[0] - tl if cmode else -tl
            else:
                xn[0] = el[0] * x[0] + el[1] * vk
                xn[1] = 0.0
                xn[2] = x[2]
                if want_s:
                    for c in nc:
                        sn[0, c] = el[0] * s[0, c]
                        sn[1, c] = 0.0
                        sn[2, c] = s[2, c]
                    sn[0, 0] += el[2] * x[0] + el[4] * vk
                    sn[0, 1] += el[3] * x[0] + el[5] * vk
                drive = kt * xn[0] - tl
            if abs(drive) > t_static:
                stuck = False
            if refine:
                st5[0], st5[1], st5[2], st5[3], st5[4] = x[0], x[1], x[2], 0.0, 1.0
                vbuf[0] = vk
                _effects_kernel(vbuf, coef, phs, gas, hs, nsub, False, st5)
                xn[0], xn[1], xn[2] = st5[0], st5[1], st5[2]
                stuck = st5[4] > 0.5
            for a in range(3):
                x[a] = xn[a]
                if want_s:
                    for c in nc:
                        s[a, c] = sn[a, c]
            continue
        if x[1] > 0.0:
            sg = 1.0
        elif x[1] < 0.0:
            sg = -1.0
        else:
            if is_open:
                drive = kt * x[0] - tl if cmode else -tl
            else:
                drive = kt * x[0] - tl
            sg = 1.0 if drive > 0.0 else -1.0
        w = x[1]
        ex = math.exp(-((w / ws) ** 2)) if ts > 0.0 else 0.0
        torque = tl + sg * (tc + ts * ex) + cq * w * abs(w)
        dt_dw = -2.0 * sg * ts * ex * w / (ws * ws) + 2.0 * cq * abs(w)
        i_in = 0.5 * (imeas[k] + imeas[k + 1]) if cmode else 0.0
        if is_open:
            ph, ga, dph, dga = pho, gao, dpho, dgao
            u0 = 0.0
            u1 = torque - kt * i_in if cmode else torque
        else:
            ph, ga, dph, dga = phc, gac, dphc, dgac
            u0 = vk
            u1 = torque
        for a in range(3):
            xn[a] = ph[a, 0] * x[0] + ph[a, 1] * x[1] + ph[a, 2] * x[2] + ga[a, 0] * u0
            xn[a] += ga[a, 1] * u1
        if want_s:
            for a in range(3):
                for c in nc:
                    sn[a, c] = ph[a, 0] * s[0, c] + ph[a, 1] * s[1, c] + ph[a, 2] * s[2, c]
                for j in range(6):
                    if not need6[j]:
                        continue
                    sn[a, j] += (
                        dph[j, a, 0] * x[0]
                        + dph[j, a, 1] * x[1]
                        + dph[j, a, 2] * x[2]
                        + dga[j, a, 0] * u0
                        + dga[j, a, 1] * u1
                    )
                sn[a, 6] += ga[a, 1] * sg
                sn[a, 7] += ga[a, 1]
                if ts > 0.0:
                    sn[a, 11] += ga[a, 1] * sg * ex
                    sn[a, 12] += ga[a, 1] * sg * ts * ex * 2.0 * w * w / (ws * ws * ws)
                sn[a, 13] += ga[a, 1] * w * abs(w)
                if dt_dw != 0.0:
                    for c in nc:
                        sn[a, c] += ga[a, 1] * dt_dw * s[1, c]
                if cmode:
                    sn[a, 3] -= ga[a, 1] * kt * i_in
        if cmode:
            xn[0] = imeas[k + 1]
            if want_s:
                for c in nc:
                    sn[0, c] = 0.0
        if refine and (xn[1] * sg < 0.0 or x[1] == 0.0):
            st5[0], st5[1], st5[2], st5[3], st5[4] = x[0], x[1], x[2], 0.0, 0.0
            vbuf[0] = vk
            _effects_kernel(vbuf, coef, phs, gas, hs, nsub, False, st5)
            xn[0], xn[1], xn[2] = st5[0], st5[1], st5[2]
            stuck = st5[4] > 0.5
            if stuck and want_s:
                for c in nc:
                    sn[1, c] = 0.0
        elif t_static > 0.0 and xn[1] * sg < 0.0:
            # Crossed zero within the sample: friction holds the rotor if the drive
            # cannot break it away; otherwise it passes through (friction sign flips
            # from the next sample on).
            if is_open and not cmode:
                held = -tl
            else:
                held = kt * xn[0] - tl
            if abs(held) <= t_static:
                stuck = True
                xn[1] = 0.0
                if want_s:
                    for c in nc:
                        sn[1, c] = 0.0
        for a in range(3):
            x[a] = xn[a]
            if want_s:
                for c in nc:
                    s[a, c] = sn[a, c]
    for c2 in range(m):
        for c3 in range(c2):
            A[c3, c2] = A[c2, c3]
    return X, A, g


class _FastSim:
    """Caches discretisations per sample period for one parameter point."""

    def __init__(self, model: Model) -> None:
        self.model = model
        self.p = model.params
        tc = model.effect("coulomb_friction")
        tl = model.effect("load_torque")
        off = model.effect("current_offset")
        st = model.effect("stribeck_friction")
        qd = model.effect("quadratic_drag")
        self.fx = np.array(
            [
                float(getattr(st, "torque_nm", 0.0)) if st is not None else 0.0,
                float(getattr(st, "speed_rad_s", 1.0)) if st is not None else 1.0,
                float(getattr(qd, "coeff_nm_s2", 0.0)) if qd is not None else 0.0,
            ]
        )
        self.tc = float(getattr(tc, "torque_nm", 0.0)) if tc is not None else 0.0
        self.tl = float(getattr(tl, "torque_nm", 0.0)) if tl is not None else 0.0
        self.off = float(getattr(off, "offset_a", 0.0)) if off is not None else 0.0
        self._cache: dict[float, tuple[FloatArray, ...]] = {}
        self.coef = _coefficients(model)

    def mats(self, dt: float, dJ: float = 0.0) -> tuple[FloatArray, ...]:
        key = (float(f"{dt:.9g}"), dJ)  # segments of one run share one period
        dt = key[0]
        got = self._cache.get(key)
        if got is None:
            p = self.p if dJ == 0.0 else self.p.replace(J=self.p.J + dJ)
            phc, gac, dphc, dgac = _zoh_with_derivatives(p, dt, True)
            pho, gao, dpho, dgao = _zoh_with_derivatives(p, dt, False)
            R, L = p.R, p.L
            a = math.exp(-R * dt / L)
            b = (1.0 - a) / R
            da_dR = -dt / L * a
            da_dL = R * dt / L**2 * a
            db_dR = -da_dR / R - (1.0 - a) / R**2
            db_dL = -da_dL / R
            # per log(R), log(L), as the other motor-parameter sensitivities
            el = np.array([a, b, R * da_dR, L * da_dL, R * db_dR, L * db_dL])
            phs, gas = discretize_zoh(p, dt / _SUBSTEPS)
            coef = self.coef.copy()
            coef[4] = p.J
            got = (phc, gac, dphc, dgac, pho, gao, dpho, dgao, el, phs, gas, coef)
            self._cache[key] = got
        return got

    def run(
        self,
        ps: _Seg | Segment,
        x0: FloatArray,
        acc: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray] | None = None,
        dJ: float = 0.0,
    ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
        """States (current includes the offset); with ``acc = (y, oidx, osc, mx, off)``
        also the normal-equation blocks of this segment's residuals."""
        seg = ps.seg if isinstance(ps, _Seg) else ps
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
        X, A, g = _fast_kernel(
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
            _SUBSTEPS,
            dt / _SUBSTEPS,
        )
        if self.off != 0.0 and not cmode:
            X[:, 0] += self.off
        if acc is None:
            return X, None, None
        return X, A, g


_NO_ACC = (
    np.zeros((1, 1)),
    np.zeros(1, dtype=np.int64),
    np.zeros(1),
    np.zeros((_NS, 1)),
    np.zeros(1),
)
_NO_COLS = np.zeros(0, dtype=np.int64)


def _predict(
    model: Model, seg: Segment, x0: FloatArray, fast: bool, dJ: float = 0.0
) -> FloatArray:
    if fast:
        X, _, _ = _FastSim(model).run(seg, x0, dJ=dJ)
        return X
    return _general_sim(model, seg, x0, dJ)


def _with_inertia(model: Model, dJ: float) -> Model:
    if dJ == 0.0:
        return model
    return Model(model.params.replace(J=model.params.J + dJ), model.effects)


def _general_sim(model: Model, seg: Segment, x0: FloatArray, dJ: float = 0.0) -> FloatArray:
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
        pre_voltage=seg.history_voltage,
        heat0_a2s=seg.history_heat_a2s or 0.0,
    )
    return np.column_stack([sim.current, sim.speed, sim.position])


# ---------------------------------------------------------------------------
# The fit
# ---------------------------------------------------------------------------
def fit_output_error(
    segments: Sequence[Segment],
    model: Model,
    *,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    closure: str | None = CLOSURE_KT_KE,
    weights: Mapping[str, float] | None = None,
    max_nfev: int = 200,
    progress: Callable[[int, float], None] | None = None,
    refine_noise: bool = True,
    check_inductance: bool = True,
    added_inertia: Mapping[str, float] | None = None,
) -> FitResult:
    """Fit ``model`` to ``segments`` by output error (see the module docs).

    ``free`` lists the parameters to fit (default: all identifiable ones);
    ``fixed`` pins values (``{"L": 3e-4}``); ``closure`` ``"Kt=Ke"`` ties Kt to
    Ke unless Kt or J is fixed (``None``: no closure). ``weights`` multiplies
    the per-signal residual weights (``{"current": 0.5}``). ``progress(it,
    cost)`` is called after every iteration. ``added_inertia`` maps segment
    labels to a known inertia added for them (kg*m^2): runs with and without it
    fix the (Kt, J, B) scale, so the Kt = Ke closure is dropped.
    """
    t_start = time.perf_counter()
    warnings: list[str] = []
    segs = _prepare(segments, warnings, added_inertia)
    has_added = any(ps.dJ > 0 for ps in segs)
    current_mode = segs[0].voltage is None
    fixed = {str(k): float(v) for k, v in (fixed or {}).items()}
    if closure not in (None, CLOSURE_KT_KE):
        msg = f"unknown closure {closure!r}; use {CLOSURE_KT_KE!r} or None"
        raise ParameterError(msg)
    values = _model_values(model)
    for name, v in fixed.items():
        if name not in values:
            msg = f"cannot fix {name!r}: not a parameter of this model (known: {list(values)})"
            raise ParameterError(msg)
        info = _param_info(name)
        if not (info.lower <= v <= info.upper) or (info.log and v <= 0.0):
            msg = f"fixed value {name}={v:g} is outside its range"
            raise ParameterError(msg)
        values[name] = v

    reasons: dict[str, str] = {}
    tie_kt = closure == CLOSURE_KT_KE and "Kt" not in fixed and "J" not in fixed
    if has_added:
        # a known added inertia on some segments fixes the (Kt, J, B) scale
        tie_kt = False
    if current_mode:
        tie_kt = False
        for n in ("R", "L", "Ke"):
            reasons[n] = "no voltage in the data: electrical parameters are not observable"
        if "Kt" not in fixed:
            reasons["Kt"] = "given (current-driven data fix the scale through Kt)"
    if tie_kt:
        values["Kt"] = values["Ke"]
    candidates = [
        n
        for n in values
        if n not in fixed
        and not (current_mode and n in ("R", "L", "Ke", "Kt"))
        and not (tie_kt and n == "Kt")
        and (n in PARAMETER_NAMES or _fitted_field(n))
    ]
    if free is None:
        free_names = candidates
    else:
        free_names = []
        for n in free:
            if n not in values:
                msg = f"cannot fit {n!r}: not a parameter of this model (known: {list(values)})"
                raise ParameterError(msg)
            if n in fixed:
                continue
            if tie_kt and n == "Kt":
                continue
            free_names.append(n)
    if not tie_kt and "Kt" in free_names and "J" in free_names and "B" in free_names:
        warnings.append(
            "Kt, J and B are all free without a closure: only their ratios are identifiable"
        )
    fast = set(model.effect_names) <= FAST_EFFECTS
    base = _build_model(model, values)

    # Noise levels per signal (robust, from the data), then optional user weights.
    noise = _initial_noise(segs)
    if weights:
        for k in weights:
            if k not in SIGNALS:
                msg = f"weights keys must be among {SIGNALS}, got {k!r}"
                raise ParameterError(msg)

    prob = _Problem(segs, base, values, free_names, tie_kt, fast, noise, weights or {})
    z, lm = _levenberg_marquardt(prob, prob.z0(), max_nfev, progress)
    if refine_noise:
        # Maximum likelihood with unknown noise levels: reweight by the residual RMS
        # and refit, unless the weights barely change (then the optimum does not move
        # beyond a small fraction of its standard error).
        new_noise = prob.residual_noise(z)
        moved = any(not 0.9 < new_noise[k] / prob.noise[k] < 1.1 for k in new_noise)
        prob.noise = new_noise
        if moved:
            z, lm2 = _levenberg_marquardt(prob, z, max_nfev, progress)
            lm = _LMState(lm2.cost, lm.nfev + lm2.nfev, lm.it + lm2.it, lm2.converged, lm2.message)

    result = _finish(prob, z, lm, reasons, fixed, closure if tie_kt else None, warnings, t_start)
    scale = ("Kt", "J", "B")
    if all(n in result.free and not result.identifiable[n] for n in scale):
        why = (
            "scale ambiguity: voltage, current and speed fix (Kt, J, B) only up to a common "
            "factor; use the Kt = Ke closure, fix Kt or J, or add a known inertia"
        )
        result = _replace(result, reasons={**result.reasons, **dict.fromkeys(scale, why)})
    if check_inductance and not current_mode and "L" in result.free:
        tau_e = result.values["L"] / result.values["R"]
        dt_min = min(s.dt for s in segs)
        if tau_e < _MIN_TAU_E_SAMPLES * dt_min:
            # Keep the fitted (rough) value: holding L at a guess would add nothing.
            result = _flag_inductance(result, tau_e, dt_min, t_start)
    return result


def _inductance_reason(tau_e: float, dt_min: float) -> str:
    need_hz = _NEEDED_TAU_E_SAMPLES / tau_e
    return (
        f"L/R ~ {tau_e * 1e3:.2g} ms is below the sample period "
        f"{dt_min * 1e3:.3g} ms: the current settles within one sample, so L is "
        f"not identifiable from these data; sample at >= {need_hz / 1e3:.3g} kHz "
        f"or fix L from an LCR meter (--fix L=...)"
    )


def _flag_inductance(res: FitResult, tau_e: float, dt_min: float, t_start: float) -> FitResult:
    reason = _inductance_reason(tau_e, dt_min)
    reasons = dict(res.reasons)
    reasons["L"] = reason + " (the value is the fit's rough estimate)"
    ident = dict(res.identifiable)
    ident["L"] = False
    ci95 = dict(res.ci95)
    ci95["L"] = None
    stderr = dict(res.stderr)
    stderr["L"] = None
    return _replace(
        res,
        reasons=reasons,
        identifiable=ident,
        ci95=ci95,
        stderr=stderr,
        warnings=(*res.warnings, "L: " + reason),
        elapsed_s=time.perf_counter() - t_start,
    )


def _replace(res: FitResult, **changes: object) -> FitResult:
    from dataclasses import replace

    return replace(res, **changes)  # type: ignore[arg-type]


def _fitted_field(name: str) -> bool:
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    return cls is not None and cls.SPECS[fld].fitted


def _initial_noise(segs: list[_Seg]) -> dict[str, float]:
    per: dict[str, list[float]] = {}
    for ps in segs:
        for idx, y in ps.outputs:
            per.setdefault(SIGNALS[idx], []).append(_noise_level(idx, y, ps.seg))
    return {k: float(np.median(v)) for k, v in per.items()}


class _Problem:
    """Residuals and Jacobian blocks over transformed parameters z."""

    def __init__(
        self,
        segs: list[_Seg],
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
        self.info = [_param_info(n) for n in free]
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
        return _build_model(self.base, self.values_at(z))

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
        sim = _FastSim(model) if self.fast else None
        fd_cache: list[FloatArray] = []
        if want_jac and not self.fast:
            fd_cache = self._fd_global(z, model)
        for q, ps in enumerate(self.segs):
            x0 = self.x0_of(z, q)
            idxs = list(range(self.n_global)) + [self.offsets[q] + k for k in range(len(ps.nuis))]
            ii = np.array(idxs)
            A_loc = g_loc = None
            if self.fast:
                assert sim is not None
                acc = None
                if want_jac:
                    mx, off = self._mixing(z, model, ps)
                    acc = (
                        np.column_stack([y for _i, y in ps.outputs]),
                        np.array([i for i, _y in ps.outputs], dtype=np.int64),
                        np.array([self.scale(i) for i, _y in ps.outputs]),
                        mx,
                        off,
                    )
                X, A_loc, g_loc = sim.run(ps, x0, acc, ps.dJ)
            else:
                X = _general_sim(model, ps.seg, x0, ps.dJ)
            r_seg = []
            for idx, y in ps.outputs:
                raw_parts.append((idx, X[:, idx] - y))
                r_seg.append(raw_parts[-1][1] * self.scale(idx))
            r_q = np.concatenate(r_seg)
            r_parts.append(r_q)
            if not want_jac:
                continue
            if A_loc is None:
                cols = self._local_jac(q, ps, X, z, model, fd_cache)
                A_loc = cols.T @ cols
                g_loc = cols.T @ r_q
            A[np.ix_(ii, ii)] += A_loc  # type: ignore[index]
            g[ii] += g_loc  # type: ignore[index]
        r = np.concatenate(r_parts)
        self._last = (z.copy(), raw_parts, r, A, g, dict(self.noise))
        return r, A, g

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

    def _mixing(self, z: FloatArray, model: Model, ps: _Seg) -> tuple[FloatArray, FloatArray]:
        """Kernel sensitivities (11 columns) -> local Jacobian columns; offset column mask."""
        vals = _model_values(model)
        dvdz = self.dvalue_dz(z)
        m_loc = self.n_global + len(ps.nuis)
        mx = np.zeros((_NS, m_loc))
        off = np.zeros(m_loc)
        for j, name in enumerate(self.free):
            if name in _COL:
                # kernel columns are per log of the value the segment sees (J + dJ)
                seen = vals[name] + (ps.dJ if name == "J" else 0.0)
                mx[_COL[name], j] = dvdz[j] / seen
                if name == "Ke" and self.tie_kt:
                    mx[_COL["Kt"], j] = dvdz[j] / vals[name]
            elif name == "coulomb_friction.torque_nm":
                mx[_COL_TC, j] = dvdz[j]
            elif name == "load_torque.torque_nm":
                mx[_COL_TL, j] = dvdz[j]
            elif name == "stribeck_friction.torque_nm":
                mx[_COL_TS, j] = dvdz[j]
            elif name == "stribeck_friction.speed_rad_s":
                mx[_COL_WS, j] = dvdz[j]
            elif name == "quadratic_drag.coeff_nm_s2":
                mx[_COL_CQ, j] = dvdz[j]
            elif name == "current_offset.offset_a":
                off[j] = dvdz[j]
            else:
                msg = f"parameter {name} has no analytic sensitivity"
                raise ParameterError(msg)
        for k, sidx in enumerate(ps.nuis):
            mx[_COL_I0 + sidx, self.n_global + k] = 1.0
        return mx, off

    def _local_jac(self, q, ps, X, z, model, fd_cache) -> FloatArray:
        """Forward-difference Jacobian block of one segment (general path)."""
        n = ps.seg.n
        m_loc = self.n_global + len(ps.nuis)
        cols = np.zeros((n * len(ps.outputs), m_loc))
        for o, (idx, _y) in enumerate(ps.outputs):
            rows = slice(o * n, (o + 1) * n)
            sc = self.scale(idx)
            for j in range(self.n_global):
                cols[rows, j] = fd_cache[j][q][:, idx] * sc
        for k, sidx in enumerate(ps.nuis):
            h = 1e-6 * max(1.0, abs(z[self.offsets[q] + k]))
            x0 = self.x0_of(z, q)
            x0[sidx] += h
            Xp = _general_sim(model, ps.seg, x0, ps.dJ)
            for o, (idx, _y) in enumerate(ps.outputs):
                rows = slice(o * n, (o + 1) * n)
                cols[rows, self.n_global + k] = (Xp[:, idx] - X[:, idx]) / h * self.scale(idx)
        return cols

    def _fd_global(self, z: FloatArray, model: Model) -> list[list[FloatArray]]:
        """Forward differences of every segment's states w.r.t. each global z."""
        base = [
            _general_sim(model, ps.seg, self.x0_of(z, q), ps.dJ) for q, ps in enumerate(self.segs)
        ]
        out: list[list[FloatArray]] = []
        for j in range(self.n_global):
            h = 1e-6 * max(1.0, abs(z[j]))
            zp = z.copy()
            zp[j] += h
            mp = self.model_at(zp)
            out.append(
                [
                    (_general_sim(mp, ps.seg, self.x0_of(z, q), ps.dJ) - base[q]) / h
                    for q, ps in enumerate(self.segs)
                ]
            )
        return out

    def residual_noise(self, z: FloatArray) -> dict[str, float]:
        out = {}
        for k, res in self.raw_residuals(z).items():
            rms = float(np.sqrt(np.mean(res**2)))
            out[k] = max(rms, 1e-3 * self.noise[k], 1e-12)
        return out


@dataclass(frozen=True)
class _LMState:
    cost: float
    nfev: int
    it: int
    converged: bool
    message: str


def _levenberg_marquardt(
    prob: _Problem,
    z: FloatArray,
    max_nfev: int,
    progress: Callable[[int, float], None] | None,
) -> tuple[FloatArray, _LMState]:
    """Levenberg-Marquardt on the normal equations with box bounds.

    Trial points cost one simulation without sensitivities; the Jacobian is
    computed only where a step is accepted. A parameter at a bound whose step
    points outwards is held for that step (active set), so a friction torque
    that wants to be zero converges instead of chattering on its bound.
    """
    z = prob.clip(z)
    r, A, g = prob.evaluate(z, True)
    cost = 0.5 * float(r @ r)
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
            M = A + lam * np.diag(d)
            active = np.ones(prob.n_total, dtype=bool)
            for _ in range(3):
                step = np.zeros(prob.n_total)
                sub = np.ix_(active, active)
                try:
                    step[active] = -np.linalg.solve(M[sub], g[active])
                except np.linalg.LinAlgError:
                    step[active] = -np.linalg.lstsq(M[sub], g[active], rcond=None)[0]
                out = ((z <= lo) & (step < 0)) | ((z >= hi) & (step > 0))
                if not (out & active).any():
                    break
                active &= ~out
            z_new = prob.clip(z + prob.limit_step(step))
            # After an accepted step the next trial is usually accepted too: compute
            # its Jacobian at once; after a rejection, try residuals only.
            r_new, A_new, g_new = prob.evaluate(z_new, last_ok)
            nfev += 1
            cost_new = 0.5 * float(r_new @ r_new)
            if math.isfinite(cost_new) and cost_new <= cost:
                rel = (cost - cost_new) / max(cost, 1e-300)
                small_step = np.all(np.abs(z_new - z) <= 1e-9 * (1.0 + np.abs(z)))
                decrease = cost - cost_new
                z, cost = z_new, cost_new
                lam = max(lam / 5.0, 1e-12)
                improved = True
                last_ok = True
                # residuals are noise-normalised: a decrease below 0.01 moves no
                # parameter combination by more than 0.15 of its standard error
                if rel < 1e-12 or decrease < 1e-2 or small_step:
                    converged = True
                    message = "cost no longer decreases"
                elif A_new is not None:
                    r, A, g = r_new, A_new, g_new
                else:
                    r, A, g = prob.evaluate(z, True)
                break
            last_ok = False
            lam *= 6.0
            if lam > 1e12:
                converged = True
                message = "no further decrease possible (local minimum)"
                break
        if progress is not None:
            progress(it, cost)
        if converged or not improved:
            break
    return z, _LMState(cost, nfev, it, converged, message)


def _finish(
    prob: _Problem,
    z: FloatArray,
    lm: _LMState,
    reasons: dict[str, str],
    fixed: dict[str, float],
    closure: str | None,
    warnings: list[str],
    t_start: float,
) -> FitResult:
    r, A, _g = prob.cached(z, True)
    assert A is not None
    n_rows = r.size
    dof = max(n_rows - prob.n_total, 1)
    s2 = float(r @ r) / dof
    # Covariance of z (globals and nuisances), then the globals in physical units.
    w, V = np.linalg.eigh(A)
    wmax = float(w.max()) if w.size else 1.0
    tol = wmax * 1e-13
    inv_w = np.where(w > tol, 1.0 / np.maximum(w, tol), np.inf)
    cov_z = (V * np.where(np.isfinite(inv_w), inv_w, 0.0)) @ V.T * s2
    null_dirs = V[:, w <= tol]
    vals = prob.values_at(z)
    ng = prob.n_global
    dvdz = prob.dvalue_dz(z)
    cov = cov_z[:ng, :ng] * np.outer(dvdz, dvdz)
    ci95: dict[str, tuple[float, float] | None] = {}
    stderr: dict[str, float | None] = {}
    ident: dict[str, bool] = {}
    reasons = dict(reasons)
    for j, info in enumerate(prob.info):
        name = info.name
        in_null = null_dirs.size and float(np.max(np.abs(null_dirs[j, :]))) > 1e-3
        sz = math.sqrt(max(cov_z[j, j], 0.0))
        rel = sz if info.log else sz / max(abs(vals[name]), 1e-300)
        if in_null or not math.isfinite(sz):
            ident[name] = False
            reasons[name] = "the data do not constrain it (singular information matrix)"
            ci95[name] = None
            stderr[name] = None
            continue
        stderr[name] = math.sqrt(max(cov[j, j], 0.0))
        if info.log:
            ci95[name] = (
                math.exp(max(min(z[j] - 1.96 * sz, 700.0), -700.0)),
                math.exp(max(min(z[j] + 1.96 * sz, 700.0), -700.0)),
            )
        else:
            ci95[name] = (vals[name] - 1.96 * sz, vals[name] + 1.96 * sz)
        if rel > 0.5:
            ident[name] = False
            reasons[name] = (
                f"the 95 % interval spans more than a factor {math.exp(1.96 * 0.5):.1f} "
                "(relative standard error above 50 %)"
            )
        else:
            ident[name] = True
    if closure:
        ci95["Kt"] = ci95.get("Ke")
        stderr["Kt"] = stderr.get("Ke")
        ident["Kt"] = ident.get("Ke", True)
        reasons["Kt"] = "assumed equal to Ke (closure Kt = Ke in SI units)"
    for name in vals:
        ci95.setdefault(name, None)
        stderr.setdefault(name, None)
        if name in fixed:
            ident.setdefault(name, True)
            reasons.setdefault(name, "fixed by the user")
        elif name not in ident:
            ident[name] = name not in reasons
            reasons.setdefault(name, "not fitted (held at its initial value)")
    model = prob.model_at(z)
    # Free-run RMS per signal in physical units.
    x0s: dict[str, tuple[float, float, float]] = {}
    nseg: dict[str, int] = {}
    for q, ps in enumerate(prob.segs):
        x0 = prob.x0_of(z, q)
        x0s[ps.seg.label] = (float(x0[0]), float(x0[1]), float(x0[2]))
        nseg[ps.seg.label] = ps.seg.n
    rms = {k: float(np.sqrt(np.mean(v**2))) for k, v in prob.raw_residuals(z).items()}
    return FitResult(
        model=model,
        values=vals,
        ci95=ci95,
        stderr=stderr,
        covariance=cov,
        covariance_names=tuple(prob.free),
        identifiable=ident,
        reasons=reasons,
        cost=0.5 * float(r @ r),
        n_samples=int(sum(ps.seg.n for ps in prob.segs)),
        rms=rms,
        noise=dict(prob.noise),
        free=tuple(prob.free),
        fixed=dict(fixed),
        closure=closure,
        initial_states=x0s,
        nfev=lm.nfev,
        iterations=lm.it,
        converged=lm.converged,
        message=lm.message,
        elapsed_s=time.perf_counter() - t_start,
        fast_path=prob.fast,
        warnings=tuple(warnings),
        added_inertia={ps.seg.label: ps.dJ for ps in prob.segs if ps.dJ > 0},
        _fitted_segments=nseg,
    )
