"""The PMDC motor model: exact ZOH discretisation and simulation with effects.

State ``x = [i (A), w (rad/s), theta (rad)]``. Sample convention (zero-order
hold): ``voltage[k]`` is held over ``[t_k, t_k + dt)`` and the outputs at index
``k`` are the state at ``t_k``, so ``current[0]`` is the initial current.
A NaN voltage means the armature is open over that interval: no current flows
and the rotor coasts (docs/design.md §2: commanding 0 V would brake it instead).

Two simulators share this convention:

* :func:`simulate_linear` - the seeds' linear model, one exact ZOH step per
  sample (the fast path used inside fits);
* :func:`simulate` - the model with any effects of :mod:`pmdc_ident.core.effects`,
  with sub-steps per sample. The linear part of every sub-step is again exact
  (so a stiff L/R far below the sample period is stable and accurate) and the
  nonlinear torques and voltages are held over the sub-step; a rotor at rest is
  held by static friction until the drive torque exceeds it (stiction).

:class:`Plant` advances the same kernel one sample at a time for the simulated
driver.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from pmdc_ident.core._jit import njit
from pmdc_ident.core.effects import EFFECT_TYPES, Effect
from pmdc_ident.core.effects.layout import (
    CQ,
    DELAY,
    DS,
    I_OFF,
    IB,
    ISAT,
    KE,
    KF,
    KR,
    KT,
    LAG,
    MU,
    N_COEF,
    NCOG,
    PHCOG,
    TAUQ,
    TC,
    TCOG,
    TL,
    TS,
    V_DZ,
    VB,
    WS,
    B,
    J,
    L,
    R,
)
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.params import MotorParams

__all__ = [
    "Model",
    "Plant",
    "SimResult",
    "apply_dead_zone",
    "apply_delay",
    "apply_lag",
    "continuous_state_space",
    "discretize_zoh",
    "heat_time_constant",
    "effect_coefficients",
    "effects_kernel",
    "expm_small",
    "lagged",
    "simulate",
    "simulate_linear",
    "substeps_for",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Model:
    """The linear motor plus a tuple of effects (at most one of each kind)."""

    params: MotorParams
    effects: tuple[Effect, ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.params, MotorParams):
            msg = f"a model needs MotorParams, got {type(self.params).__name__}"
            raise ParameterError(msg)
        bad = [repr(e) for e in self.effects if not isinstance(e, Effect)]
        if bad:
            msg = f"model effects must be Effect objects (see core.effects), got {', '.join(bad)}"
            raise ParameterError(msg)
        names = [e.NAME for e in self.effects]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            msg = f"each effect may appear once in a model; repeated: {', '.join(dupes)}"
            raise ParameterError(msg)
        object.__setattr__(self, "effects", tuple(self.effects))

    def effect(self, name: str) -> Effect | None:
        for e in self.effects:
            if e.NAME == name:
                return e
        return None

    @property
    def effect_names(self) -> tuple[str, ...]:
        return tuple(e.NAME for e in self.effects)

    def with_effects(self, *effects: Effect) -> Model:
        """A copy with these effects added (replacing effects of the same kind)."""
        new = {e.NAME: e for e in self.effects}
        new.update({e.NAME: e for e in effects})
        return Model(self.params, tuple(new.values()))

    def without(self, *names: str) -> Model:
        return Model(self.params, tuple(e for e in self.effects if e.NAME not in names))


@dataclass(frozen=True)
class SimResult:
    """Sampled simulation output; arrays have one entry per input sample."""

    t: FloatArray
    current: FloatArray  # measured current, A (includes a current_offset effect)
    speed: FloatArray  # rad/s
    position: FloatArray  # rad
    applied_voltage: FloatArray  # V at the armature after dead zone and delay (NaN = open)
    final_state: FloatArray = field(repr=False)  # [i, w, theta, heat state q, stuck]


# ---------------------------------------------------------------------------
# Linear model
# ---------------------------------------------------------------------------
def continuous_state_space(params: MotorParams) -> tuple[FloatArray, FloatArray]:
    """``dx/dt = A x + B u`` with ``x = [i, w]``, ``u = [V, T_load]`` (seed 000 eq. 5)."""
    p = params
    a = np.array([[-p.R / p.L, -p.Ke / p.L], [p.Kt / p.J, -p.B / p.J]])
    b = np.array([[1.0 / p.L, 0.0], [0.0, -1.0 / p.J]])
    return a, b


def discretize_zoh(params: MotorParams, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact zero-order-hold discretisation including the shaft angle.

    Returns ``(Phi, Gamma)`` with ``x[k+1] = Phi x[k] + Gamma [V, T][k]`` for
    ``x = [i, w, theta]``; ``T`` is a torque opposing positive rotation (load,
    friction) in N*m.
    """
    _check_dt(dt_s)
    a2, b2 = continuous_state_space(params)
    m = np.zeros((5, 5))
    m[:2, :2] = a2
    m[2, 1] = 1.0
    m[:2, 3:] = b2
    e = expm_small(m * dt_s)
    return np.ascontiguousarray(e[:3, :3]), np.ascontiguousarray(e[:3, 3:])


@njit
def expm_small(a):  # pragma: no cover - jitted
    """exp(a) of a small matrix: scaling and squaring with an 18-term Taylor series.

    Plain loops, no BLAS: scipy's expm calls threaded BLAS, which on a busy
    machine costs milliseconds per 5x5 matrix (simulate calls this per segment;
    the output-error engine for its 5x5 and 10x10 Van Loan blocks). Relative
    accuracy ~1e-15 after scaling. Kept by hand on a measurement
    (``benchmarks/bench_scipy_imports.py``): scipy's is 20-50 times slower per call
    here, and importing ``scipy.linalg`` alone adds about 60 % to the CPU of an
    ``identify`` of a staircase table.
    """
    n = a.shape[0]
    norm = 0.0
    for i in range(n):
        row = 0.0
        for j in range(n):
            row += abs(a[i, j])
        norm = max(norm, row)
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    b = a * 0.5**s
    result = np.eye(n)
    term = np.eye(n)
    tmp = np.empty((n, n))
    for k in range(1, 19):
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for m in range(n):
                    acc += term[i, m] * b[m, j]
                tmp[i, j] = acc / k
        term[:, :] = tmp
        result += term
    for _ in range(s):
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for m in range(n):
                    acc += result[i, m] * result[m, j]
                tmp[i, j] = acc
        result[:, :] = tmp
    return result


def simulate_linear(
    params: MotorParams,
    voltage: ArrayLike,
    dt_s: float,
    x0: ArrayLike | None = None,
    load_torque_nm: ArrayLike | float = 0.0,
) -> SimResult:
    """Simulate the seeds' linear model, one exact ZOH step per sample.

    NaN voltage samples (open armature) force the current to zero and let the
    rotor coast under viscous friction and the load torque.
    """
    v = _as_voltage(voltage)
    n = v.size
    tl = np.broadcast_to(np.asarray(load_torque_nm, dtype=float), (n,)).copy()
    phi, gam = discretize_zoh(params, dt_s)
    a_mech = params.B / params.J
    decay = math.exp(-a_mech * dt_s)
    x = _initial_state(x0)
    out = _linear_kernel(v, tl, phi, gam, decay, a_mech, params.J, dt_s, x)
    return SimResult(
        t=np.arange(n) * dt_s,
        current=out[:, 0],
        speed=out[:, 1],
        position=out[:, 2],
        applied_voltage=v,
        final_state=np.array([x[0], x[1], x[2], 0.0, 0.0]),
    )


@njit
def _coast_step(w, th, torque, a_mech, j, h):  # pragma: no cover - jitted
    """Exact step of J dw/dt = -B w - torque over h; returns (w, theta)."""
    if a_mech * h > 1e-9:
        e = math.exp(-a_mech * h)
        w_inf = -torque / (a_mech * j)
        w_new = w_inf + (w - w_inf) * e
        th_new = th + w_inf * h + (w - w_inf) * (1.0 - e) / a_mech
    else:
        acc = -torque / j
        w_new = w + acc * h
        th_new = th + w * h + 0.5 * acc * h * h
    return w_new, th_new


@njit
def _linear_kernel(v, tl, phi, gam, decay, a_mech, j, dt, x):  # pragma: no cover - jitted
    n = v.shape[0]
    out = np.empty((n, 3))
    i, w, th = x[0], x[1], x[2]
    for k in range(n):
        out[k, 0] = i
        out[k, 1] = w
        out[k, 2] = th
        if math.isnan(v[k]):
            i = 0.0
            w, th = _coast_step(w, th, tl[k], a_mech, j, dt)
        else:
            i_n = phi[0, 0] * i + phi[0, 1] * w + gam[0, 0] * v[k] + gam[0, 1] * tl[k]
            w_n = phi[1, 0] * i + phi[1, 1] * w + gam[1, 0] * v[k] + gam[1, 1] * tl[k]
            th = phi[2, 0] * i + phi[2, 1] * w + th + gam[2, 0] * v[k] + gam[2, 1] * tl[k]
            i, w = i_n, w_n
    x[0], x[1], x[2] = i, w, th
    return out


# ---------------------------------------------------------------------------
# Model with effects
# ---------------------------------------------------------------------------
def effect_coefficients(model: Model) -> FloatArray:
    """The coefficient vector the kernels read (:mod:`pmdc_ident.core.effects.layout`):
    R..B, then every effect's numbers in its slots, written by the effect itself
    (:meth:`~pmdc_ident.core.effects.base.Effect.write_coefficients`); an absent
    effect's slots hold their neutral value (zero unless the effect declares one)."""
    p = model.params
    c = np.zeros(N_COEF)
    c[[R, L, KE, KT, J, B]] = p.R, p.L, p.Ke, p.Kt, p.J, p.B
    for cls in EFFECT_TYPES.values():
        for slot, value in cls.KERNEL_NEUTRAL.items():
            c[slot] = value
    for e in model.effects:
        e.write_coefficients(c)
    return c


def heat_time_constant(model: Model) -> float:
    """The winding's thermal time constant of the model's resistance drift (s);
    infinite without cooling or without the effect (then the heat is the integral)."""
    tau = float(effect_coefficients(model)[TAUQ])
    return tau if tau > 0.0 else math.inf


def substeps_for(model: Model, substeps: int) -> int:
    """``substeps``, or 1 when every effect of ``model`` leaves the motor linear between
    samples (``LINEAR_BETWEEN_SAMPLES``: it acts on the command, adds a constant torque
    or offsets the measured current): each sub-step is then an exact zero-order-hold
    step of one linear system under one input, so one step over the whole sample gives
    the same states (to rounding) for a fraction of the cost. The fits simulate
    candidates this way."""
    if all(e.LINEAR_BETWEEN_SAMPLES for e in model.effects):
        return 1
    return substeps


def apply_dead_zone(voltage: FloatArray, dead_zone_v: float) -> FloatArray:
    """``sign(V) max(|V| - Vdz, 0)``; NaN (open armature) passes through."""
    if dead_zone_v <= 0.0:
        return voltage
    with np.errstate(invalid="ignore"):
        return np.sign(voltage) * np.maximum(np.abs(voltage) - dead_zone_v, 0.0)


def apply_delay(
    voltage: FloatArray, delay_s: float, dt_s: float, initial_v: float = 0.0
) -> FloatArray:
    """Delay a sampled (ZOH) voltage by ``delay_s``, with fractional-sample interpolation.

    Before the first command arrives the motor sees ``initial_v``. An open-armature
    interval is delayed by the rounded number of samples.
    """
    if delay_s <= 0.0:
        return voltage
    n = voltage.size
    shift = delay_s / dt_s
    whole = int(math.floor(shift))
    frac = shift - whole
    padded = np.concatenate([np.full(whole + 1, initial_v), voltage])
    idx = np.arange(n) + 1  # padded[idx + whole] is voltage[k - whole]
    cur = padded[idx]  # voltage[k - whole]
    prev = padded[idx - 1]  # voltage[k - whole - 1]
    out = (1.0 - frac) * cur + frac * prev
    # Where an open-armature (NaN) sample is involved, take the nearer sample
    # instead of mixing: open intervals are delayed by the rounded shift.
    near = prev if frac >= 0.5 else cur
    return np.where(np.isnan(out), near, out)


def apply_lag(
    voltage: FloatArray, lag_s: float, dt_s: float, initial_v: float = 0.0
) -> FloatArray:
    """A first-order lag ``tau dVa/dt = V - Va`` of a sampled (ZOH) voltage, as the mean
    of ``Va`` over each sample (the value the motor's step holds). ``initial_v`` is
    ``Va`` before the first sample; an open armature (NaN) passes through and the lag
    restarts from 0 V after it."""
    return lagged(voltage, lag_s, dt_s, initial_v)[0]


def lagged(
    voltage: FloatArray, lag_s: float, dt_s: float, initial_v: float = 0.0
) -> tuple[FloatArray, float]:
    """:func:`apply_lag`'s output and the lag's state ``Va`` after the last sample (where
    a run cut here goes on from: a stepper's next sample, a replay's next segment)."""
    if lag_s <= 0.0:
        last = float(voltage[-1]) if voltage.size else float(initial_v)
        return voltage, last if math.isfinite(last) else 0.0
    a = math.exp(-dt_s / lag_s)
    out, x = _lag_kernel(voltage, a, lag_s / dt_s * (1.0 - a), float(initial_v))
    return out, float(x)


@njit
def _lag_kernel(v, a, g, x0):  # pragma: no cover - jitted
    out = np.empty_like(v)
    x = x0
    for k in range(v.size):
        vk = v[k]
        if math.isnan(vk):
            out[k] = vk
            x = 0.0
            continue
        out[k] = vk + (x - vk) * g
        x = vk + (x - vk) * a
    return out, x


def simulate(
    model: Model,
    voltage: ArrayLike,
    dt_s: float,
    x0: ArrayLike | None = None,
    substeps: int = 8,
    *,
    pre_voltage: ArrayLike | None = None,
    heat0_a2s: float = 0.0,
) -> SimResult:
    """Simulate the motor with all effects of ``model`` under a ZOH voltage command.

    ``x0`` is ``[i, w, theta]`` (default at rest; when given, a delay effect sees the
    first command as the command before the segment). ``substeps`` sub-steps per
    sample resolve friction reversals and stiction; the linear part of each
    sub-step is exact.

    For a segment cut from a longer record: ``pre_voltage`` (V, oldest first, NaN =
    open) are the commands of the samples just before it, which fill a delay line
    (commands older than those given are taken as the oldest one given);
    ``heat0_a2s`` (A^2*s) is the heat state a resistance drift starts from (the
    ``int i^2 dt`` before the segment, decayed by cooling: ``core.data.heat_state``).
    """
    _check_dt(dt_s)
    if substeps < 1:
        msg = f"substeps must be >= 1, got {substeps}"
        raise ParameterError(msg)
    v_cmd = _as_voltage(voltage)
    c = effect_coefficients(model)
    dead_zone_v, delay_s, lag_s = float(c[V_DZ]), float(c[DELAY]), float(c[LAG])
    v_app = apply_dead_zone(v_cmd, dead_zone_v)
    # From a given state x0 (a segment cut from a longer run) the command before the
    # first sample is taken as the first command: the lag then does not inject a
    # spurious 0 V interval at every segment start. From rest (x0 None) it is 0 V.
    pre_v = float(v_app[0]) if x0 is not None and v_app.size else 0.0
    pre = _as_voltage(pre_voltage) if pre_voltage is not None else np.zeros(0)
    if pre.size and (delay_s > 0.0 or lag_s > 0.0):
        pre = apply_dead_zone(pre, dead_zone_v)
        both = apply_delay(np.concatenate([pre, v_app]), delay_s, dt_s, float(pre[0]))
        p0 = float(pre[0]) if math.isfinite(pre[0]) else 0.0
        v_app = apply_lag(both, lag_s, dt_s, p0)[pre.size :]
    else:
        v_app = apply_lag(apply_delay(v_app, delay_s, dt_s, pre_v), lag_s, dt_s, pre_v)
    if not (math.isfinite(heat0_a2s) and heat0_a2s >= 0.0):
        msg = f"initial heat integral must be >= 0 A^2*s, got {heat0_a2s}"
        raise ParameterError(msg)
    state = np.zeros(5)
    state[:3] = _initial_state(x0)
    state[3] = heat0_a2s
    out = _run_effects(model, c, v_app, dt_s, state, substeps)
    current = out[:, 0] + float(c[I_OFF])
    return SimResult(
        t=np.arange(v_cmd.size) * dt_s,
        current=current,
        speed=out[:, 1],
        position=out[:, 2],
        applied_voltage=v_app,
        final_state=state,
    )


def _varying(model: Model) -> bool:
    """Whether the electrical step changes within a sample (an effect's
    ``varies_within_sample``: R heats, L saturates, a smooth brush drop's slope), so the
    kernel re-discretises every sub-step."""
    return any(e.varies_within_sample() for e in model.effects)


def _run_effects(
    model: Model, c: FloatArray, v_app: FloatArray, dt_s: float, state: FloatArray, substeps: int
) -> FloatArray:
    h = dt_s / substeps
    varying = _varying(model)
    phi, gam = discretize_zoh(model.params, h)
    if state[4] == 0.0 and state[1] == 0.0 and c[TC] + c[TS] > 0.0:
        state[4] = 1.0  # starts at rest: held by static friction until it breaks away
    return effects_kernel(v_app, c, phi, gam, h, substeps, varying, state)


@njit
def _zoh2(a11, a12, a21, a22, h):  # pragma: no cover - jitted
    """Closed-form exp(A h) and int_0^h exp(A s) ds for a 2x2 matrix with det(A) != 0."""
    s = 0.5 * (a11 + a22)
    d = 0.5 * (a11 - a22)
    q2 = d * d + a12 * a21
    es = math.exp(s * h)
    if q2 > 1e-300 and math.sqrt(q2) * h > 20.0:
        # stiff (a knee's slope, a hot winding at a long step): e^(sh) cosh(qh) as the
        # sum of the two modes' decays, not 0 * inf
        q = math.sqrt(q2)
        fast, slow = math.exp((s - q) * h), math.exp((s + q) * h)
        es, ch, sh = 1.0, 0.5 * (slow + fast), 0.5 * (slow - fast) / q
    elif q2 > 1e-300:
        q = math.sqrt(q2)
        ch = math.cosh(q * h)
        sh = math.sinh(q * h) / q
    elif q2 < -1e-300:
        q = math.sqrt(-q2)
        ch = math.cos(q * h)
        sh = math.sin(q * h) / q
    else:
        ch = 1.0
        sh = h
    e11 = es * (ch + sh * (a11 - s))
    e12 = es * sh * a12
    e21 = es * sh * a21
    e22 = es * (ch + sh * (a22 - s))
    det = a11 * a22 - a12 * a21
    # int = A^-1 (E - I)
    m11, m12, m21, m22 = e11 - 1.0, e12, e21, e22 - 1.0
    g11 = (a22 * m11 - a12 * m21) / det
    g12 = (a22 * m12 - a12 * m22) / det
    g21 = (-a21 * m11 + a11 * m21) / det
    g22 = (-a21 * m12 + a11 * m22) / det
    return e11, e12, e21, e22, g11, g12, g21, g22


@njit
def _from_rest(i, th, v, t_opp, r, ind, ke, kt, j, b, h):  # pragma: no cover - jitted
    """Exact ZOH step of length ``h`` from speed 0 (current ``i``) with the opposing
    torque ``t_opp`` held; returns (i, w, theta), theta by the trapezoid."""
    e11, e12, e21, e22, g11, g12, g21, g22 = _zoh2(-r / ind, -ke / ind, kt / j, -b / j, h)
    u1 = v / ind
    u2 = -t_opp / j
    i_new = e11 * i + g11 * u1 + g12 * u2
    w_new = e21 * i + g21 * u1 + g22 * u2
    return i_new, w_new, th + 0.5 * w_new * h


@njit
def stribeck_fall(w, ws, ds):  # pragma: no cover - jitted
    """exp(-(|w|/ws)^ds): the Stribeck curve's fall with speed (ds 2: Gaussian)."""
    x = abs(w) / ws
    return math.exp(-(x * x if ds == 2.0 else x**ds))


@njit
def effects_kernel(v, c, phi, gam, h, nsub, varying, st):  # pragma: no cover - jitted
    """Simulate ``v`` (one value per sample) with every effect, ``nsub`` sub-steps of ``h``
    per sample; ``c`` from :func:`effect_coefficients`, ``phi``/``gam`` the sub-step ZOH
    matrices (``varying``: R or L change with the state, so the step is re-discretised);
    ``st`` = [i, w, th, heat, stuck] is the state, updated in place (heat: the winding
    heat state q of :class:`~pmdc_ident.core.effects.ResistanceDrift`). Returns the states
    (n, 3) at the sample instants."""
    r0, l0, ke0, kt0, j, b = c[R], c[L], c[KE], c[KT], c[J], c[B]
    ke, kt = ke0, kt0
    kf = c[KF]  # magnets' flux falling with the heat: Ke (1 - kf q), Kt likewise
    tc, ts, ws, cq, tl, vb = c[TC], c[TS], c[WS], c[CQ], c[TL], c[VB]
    tcog, ncog, phcog, kr, isat = c[TCOG], c[NCOG], c[PHCOG], c[KR], c[ISAT]
    ds = c[DS]  # Stribeck shape exponent
    ib = c[IB]  # brush drop knee current (0: the hard sign)
    mu = c[MU]  # torque-dependent friction: mu |Kt i| against the motion
    # winding heat q: dq/dt = i^2 - q/tau (tau = c[TAUQ]; 0 = no cooling, the integral)
    cool = math.exp(-h / c[TAUQ]) if c[TAUQ] > 0.0 else 1.0
    t_static = tc + ts
    a_mech = b / j
    n = v.shape[0]
    out = np.empty((n, 3))
    i, w, th, q, stuck = st[0], st[1], st[2], st[3], st[4] > 0.5
    r, lcur, v_eff = r0, l0, 0.0
    for k in range(n):
        out[k, 0] = i
        out[k, 1] = w
        out[k, 2] = th
        vk = v[k]
        is_open = math.isnan(vk)
        for _ in range(nsub):
            q *= cool
            if kf > 0.0:
                flux = max(1.0 - kf * q, 0.0)
                ke, kt = ke0 * flux, kt0 * flux
            # Torques that do not depend on the sign of w (opposing +w when positive).
            t_pos = tl
            if tcog > 0.0:
                t_pos += tcog * math.sin(ncog * th + phcog)
            if is_open:
                i = 0.0
                drive = -t_pos
            else:
                # Brush drop: a dead band on the voltage that drives current (hard), or
                # vb tanh(i/ib) (smooth contact film), linearised about the sub-step's
                # start current: its slope is a resistance in the exact step (stable).
                e_drive = vk - ke * w
                r_brush = 0.0
                if vb > 0.0 and ib > 0.0:
                    tb = math.tanh(i / ib)
                    r_brush = vb / ib * (1.0 - tb * tb)
                    v_eff = vk - vb * tb + r_brush * i
                elif vb > 0.0:
                    if e_drive > vb:
                        v_eff = vk - vb
                    elif e_drive < -vb:
                        v_eff = vk + vb
                    else:
                        v_eff = ke * w  # no net voltage to drive current through brushes
                else:
                    v_eff = vk
                r = (r0 * (1.0 + kr * q) if kr > 0.0 else r0) + r_brush
                lcur = l0 / (1.0 + (i / isat) ** 2) if isat > 0.0 else l0
                drive = kt * i - t_pos
            if stuck:
                if is_open:
                    if abs(drive) <= t_static:
                        continue
                else:
                    # Electrical step with the rotor held: exact first-order decay.
                    i_inf = v_eff / r
                    i_held = i_inf + (i - i_inf) * math.exp(-r * h / lcur)
                    i_avg = i_inf + (i - i_inf) * (1.0 - math.exp(-r * h / lcur)) * lcur / (r * h)
                    hold = t_static + (mu * abs(kt * i_avg) if mu > 0.0 else 0.0)
                    if abs(kt * i_avg - t_pos) <= hold:
                        q += i_held * i_held * h
                        i = i_held
                        continue
                    drive = kt * i_avg - t_pos
                stuck = False
                sgn = 1.0 if drive > 0.0 else -1.0
            else:
                sgn = 1.0 if w > 0.0 else (-1.0 if w < 0.0 else (1.0 if drive > 0.0 else -1.0))
            # (ts = 0: ts * exp(.) is 0 exactly, so the exp is skipped, same numbers)
            fric = sgn * (tc + ts * stribeck_fall(w, ws, ds)) if ts > 0.0 else sgn * tc
            if mu > 0.0:
                fric += sgn * mu * abs(kt * i)
            t_opp = t_pos + fric + cq * w * abs(w)
            if is_open:
                w_new, th_new = _coast_step(w, th, t_opp, a_mech, j, h)
                i_new = 0.0
            elif varying:
                e11, e12, e21, e22, g11, g12, g21, g22 = _zoh2(
                    -r / lcur, -ke / lcur, kt / j, -b / j, h
                )
                u1 = v_eff / lcur
                u2 = -t_opp / j
                i_new = e11 * i + e12 * w + g11 * u1 + g12 * u2
                w_new = e21 * i + e22 * w + g21 * u1 + g22 * u2
                th_new = th + 0.5 * (w + w_new) * h
            else:
                i_new = phi[0, 0] * i + phi[0, 1] * w + gam[0, 0] * v_eff + gam[0, 1] * t_opp
                w_new = phi[1, 0] * i + phi[1, 1] * w + gam[1, 0] * v_eff + gam[1, 1] * t_opp
                th_new = phi[2, 0] * i + phi[2, 1] * w + th + gam[2, 0] * v_eff + gam[2, 1] * t_opp
            if t_static > 0.0 and w_new * sgn < 0.0:
                # The speed crossed zero within the sub-step: the rotor stops there and
                # stays unless the drive breaks it away; then it turns the other way for
                # the rest of the sub-step, friction reversed (clamping w to 0 lost that
                # motion: at 50 Hz a reversing drive lost most of each crossing sample).
                frac = w / (w - w_new)
                i_c = i + frac * (i_new - i)
                th_c = th + 0.5 * w * frac * h
                held = -t_pos if is_open else kt * i_c - t_pos
                hold = t_static + (mu * abs(kt * i_c) if mu > 0.0 and not is_open else 0.0)
                if abs(held) <= hold:
                    stuck = True
                    w_new, th_new = 0.0, th_c
                elif is_open:
                    t_rev = t_pos + (t_static if held > 0.0 else -t_static)
                    w_new, th_new = _coast_step(0.0, th_c, t_rev, a_mech, j, (1.0 - frac) * h)
                else:
                    i_new, w_new, th_new = _from_rest(
                        i_c,
                        th_c,
                        v_eff,
                        t_pos + (hold if held > 0.0 else -hold),
                        r,
                        lcur,
                        ke,
                        kt,
                        j,
                        b,
                        (1.0 - frac) * h,
                    )
            if not is_open:
                q += 0.5 * (i * i + i_new * i_new) * h
            i, w, th = i_new, w_new, th_new
    st[0], st[1], st[2], st[3] = i, w, th, q
    st[4] = 1.0 if stuck else 0.0
    return out


# ---------------------------------------------------------------------------
# Streaming plant for the simulated driver
# ---------------------------------------------------------------------------
class Plant:
    """The motor model advanced one sample at a time on an exact grid.

    ``step(v)`` holds ``v`` (volts, or ``None``/NaN for an open armature) over
    one sample period; the properties then read the state at the end of it. Dead zone and
    delay act on the command stream exactly as in :func:`simulate`, so a
    sequence of ``step`` calls reproduces :func:`simulate` sample by sample.
    """

    def __init__(self, model: Model, dt_s: float, substeps: int = 8) -> None:
        _check_dt(dt_s)
        self.model = model
        self.dt_s = float(dt_s)
        self.substeps = int(substeps)
        self._coef = c = effect_coefficients(model)
        self._dead_zone_v = float(c[V_DZ])
        self._delay_s = float(c[DELAY])
        self._lag_s = float(c[LAG])
        self._lag_v = 0.0  # the lag's output before the next sample (from rest: 0 V)
        self._offset_a = float(c[I_OFF])
        self._history = np.zeros(int(math.floor(self._delay_s / self.dt_s)) + 2)
        self._varying = _varying(model)
        self._phi, self._gam = discretize_zoh(model.params, self.dt_s / self.substeps)
        self._state = np.zeros(5)
        self._state[4] = 1.0 if c[TC] + c[TS] > 0.0 else 0.0
        self.samples = 0
        # Load (or compile) the kernel now, not inside the first step a real-time caller
        # waits for: a driver's clock is running by then (a late first poll was a
        # 'host stall' of ~1.4 s at start-up under ros2 launch).
        self._run(np.zeros(0), self._state.copy())

    @property
    def time_s(self) -> float:
        return self.samples * self.dt_s

    @property
    def current_a(self) -> float:
        """Measured current (true current plus any sensor offset)."""
        return float(self._state[0]) + self._offset_a

    @property
    def speed_rad_s(self) -> float:
        return float(self._state[1])

    @property
    def position_rad(self) -> float:
        return float(self._state[2])

    @property
    def resistance_ohm(self) -> float:
        """The winding resistance now: ``R (1 + k q)`` with a resistance drift."""
        return float(self._coef[R] * (1.0 + self._coef[KR] * self._state[3]))

    def step(self, voltage_v: float | None) -> None:
        v = math.nan if voltage_v is None else float(voltage_v)
        v_arr = apply_dead_zone(np.array([v]), self._dead_zone_v)
        if self._delay_s > 0.0:
            self._history = np.roll(self._history, -1)
            self._history[-1] = v_arr[0]
            delayed = apply_delay(self._history, self._delay_s, self.dt_s)
            v_arr = delayed[-1:]
        if self._lag_s > 0.0:
            v_arr, self._lag_v = lagged(v_arr, self._lag_s, self.dt_s, self._lag_v)
        self._run(v_arr, self._state)
        self.samples += 1

    def _run(self, v: FloatArray, state: FloatArray) -> None:
        h = self.dt_s / self.substeps
        effects_kernel(v, self._coef, self._phi, self._gam, h, self.substeps, self._varying, state)


# ---------------------------------------------------------------------------
def _check_dt(dt_s: float) -> None:
    if not (math.isfinite(dt_s) and dt_s > 0.0):
        msg = f"sample period dt_s must be a positive number of seconds, got {dt_s}"
        raise ParameterError(msg)


def _as_voltage(voltage: ArrayLike) -> FloatArray:
    v = np.ascontiguousarray(np.asarray(voltage, dtype=float).ravel())
    if np.isinf(v).any():
        msg = "voltage contains infinite values (NaN marks an open armature; inf is refused)"
        raise ParameterError(msg)
    return v


def _initial_state(x0: ArrayLike | None) -> FloatArray:
    if x0 is None:
        return np.zeros(3)
    x = np.asarray(x0, dtype=float).ravel()
    if x.size == 2:
        x = np.append(x, 0.0)
    if x.size != 3 or not np.isfinite(x).all():
        msg = "initial state x0 must be finite [current_a, speed_rad_s(, position_rad)]"
        raise ParameterError(msg)
    return x.copy()
