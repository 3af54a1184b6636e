"""The benchmark's own motor simulator: fine-step RK4 with switching-aware friction.

Independent of :mod:`pmdc_ident.core.model`. The state is integrated with the
classical fourth-order Runge-Kutta method on sub-steps small enough for every
time constant present (L/R at the smallest inductance, a brush-drop knee, a
smoothed-friction knee, bristle and coupling stiffness, sensor filters). Dry
friction with a sign law is switching-aware (Karnopp): a rotor whose speed
crosses zero sticks when the other torques cannot overcome the breakaway
torque, and breaks free when they can. A LuGre-like bristle state is advanced
by its exact exponential solution over each sub-step (it is far stiffer than
the rest), and its force is held over the sub-step. The parameter vector ``P``
is laid out by the ``P_*`` indices; the builders in :mod:`.truth` fill it.

Equations (measured-shaft units; ``s`` = sign; every term optional)::

    v   = dead_zone(cmd(t - t_delay)),  tau_lag dva/dt = v - va   (or va = v)
    va' = va - Rs (va/Vbus)^2 i                                    (supply sag)
    L(i) di/dt = va' - R(1 + alpha Tw) i - K(i, Th) w - Vb(i)
    J dw/dt    = K(i, Th) i - B w - F_fric(w, z) - F_drag(w) - T_load(w)
                 - T_cog(theta) - T_rip sin(2 pi f t) - T_couple
    JL dwL/dt  = T_couple - BL wL - T_gravity                      (load inertia)
    dTw/dt = kheat i^2 R(Tw) - (Tw - Th)/tau_w, dTh/dt = c (Tw - Th)/tau_w - Th/tau_h

An open armature (NaN command) carries no current.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit as jit  # compilation only (no model, no equation)

__all__ = ["NP", "SimOutput", "jit", "new_params", "simulate_plant"]

FloatArray = NDArray[np.float64]

# --- parameter vector layout -------------------------------------------------------
P_R, P_L, P_KE, P_KT, P_J, P_B = 0, 1, 2, 3, 4, 5
P_FRIC, P_TC, P_TS, P_WS, P_STRIB, P_WT, P_SIG0, P_SIG1 = 6, 7, 8, 9, 10, 11, 12, 13
P_DRAG, P_CQ, P_NEXP, P_WTR = 14, 15, 16, 17
P_LOAD, P_TL, P_ETA = 18, 19, 20
P_COUPLE, P_JL, P_KC, P_CC, P_GAP, P_BL = 21, 22, 23, 24, 25, 26
P_BRUSH, P_VB, P_I0, P_PW = 27, 28, 29, 30
P_DZ, P_VD = 31, 32
P_COG, P_TCOG, P_NP, P_PH, P_A2, P_A3, P_PH2, P_PH3, P_ECC, P_NECC = range(33, 43)
P_THERM, P_ALPHA, P_KHEAT, P_TAUW, P_TAUH, P_CRATIO, P_BETA = range(43, 50)
P_DELAY, P_LAG = 50, 51
P_LS, P_ISAT, P_LRHO, P_I2 = 52, 53, 54, 55
P_RIP_T, P_RIP_F, P_SAG_RS, P_VBUS, P_AR, P_AR_I = range(56, 62)
P_FC_I, P_ORD_I, P_FC_W, P_ORD_W = range(62, 66)
NP = 66

# --- state layout --------------------------------------------------------------------
S_I, S_W, S_TH, S_TW, S_TH2, S_VA, S_Z, S_WL, S_THL, S_IF1, S_IF2, S_WF1, S_WF2 = range(13)
NS = 13
GRAVITY_LOAD = 3.0  # P_LOAD code: gravity on the load inertia behind a compliant coupling


def new_params(r: float, ind: float, ke: float, kt: float, j: float, b: float) -> FloatArray:
    """A parameter vector with the linear motor only (no effect, ideal sensors)."""
    p = np.zeros(NP)
    p[[P_R, P_L, P_KE, P_KT, P_J, P_B]] = r, ind, ke, kt, j, b
    p[P_ALPHA] = 0.00393  # copper, 1/K
    p[P_ETA] = 1.0
    p[P_NEXP] = 2.0
    p[P_LRHO] = 1.0
    p[P_VBUS] = 1.0
    return p


@jit
def _sgn(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


@jit
def _inductance(i: float, p: FloatArray) -> float:
    mode = p[P_LS]
    l0 = p[P_L]
    if mode == 1.0:  # flux linkage Lmin i + (L0 - Lmin) Is tanh(i/Is): incremental sech^2
        c = 1.0 / math.cosh(min(abs(i) / p[P_ISAT], 30.0))
        return l0 * (p[P_LRHO] + (1.0 - p[P_LRHO]) * c * c)
    if mode == 2.0:  # Frohlich: psi = a i / (1 + |i|/Is)
        return l0 / (1.0 + abs(i) / p[P_ISAT]) ** 2
    if mode == 3.0:  # piecewise linear between I1 and I2
        a = abs(i)
        if a <= p[P_ISAT]:
            return l0
        if a >= p[P_I2]:
            return l0 * p[P_LRHO]
        f = (a - p[P_ISAT]) / (p[P_I2] - p[P_ISAT])
        return l0 * (1.0 - f * (1.0 - p[P_LRHO]))
    return l0


@jit
def _brush(i: float, p: FloatArray) -> float:
    mode = p[P_BRUSH]
    if mode == 1.0:
        return p[P_VB] * math.tanh(i / p[P_I0])
    if mode == 2.0:
        return p[P_VB] * (1.0 - math.exp(-abs(i) / p[P_I0])) * _sgn(i)
    if mode == 3.0:  # power law contact drop, linear below i0 (finite slope at zero)
        a = abs(i)
        if a < p[P_I0]:
            return p[P_VB] * (p[P_I0] ** p[P_PW]) * i / p[P_I0]
        return p[P_VB] * a ** p[P_PW] * _sgn(i)
    return 0.0


@jit
def _stribeck(w: float, p: FloatArray) -> float:
    shape = p[P_STRIB]
    x = abs(w) / p[P_WS] if p[P_WS] > 0.0 else 0.0
    if shape == 1.0:
        return p[P_TS] * math.exp(-x)
    if shape == 2.0:
        return p[P_TS] * math.exp(-x * x)
    if shape == 3.0:
        return p[P_TS] / (1.0 + x * x)
    return 0.0


@jit
def _drag(w: float, p: FloatArray) -> float:
    mode = p[P_DRAG]
    if mode == 1.0:
        return p[P_CQ] * abs(w) ** p[P_NEXP] * _sgn(w)
    if mode == 2.0:  # laminar -> turbulent: c w sqrt(w_tr^2 + w^2)
        return p[P_CQ] * w * math.sqrt(p[P_WTR] ** 2 + w * w)
    return 0.0


@jit
def _cogging(th: float, p: FloatArray) -> float:
    mode = p[P_COG]
    if mode == 0.0:
        return 0.0
    a = p[P_NP] * th + p[P_PH]
    if mode == 1.0:
        s = math.sin(a) + p[P_A2] * math.sin(2.0 * a + p[P_PH2])
        s += p[P_A3] * math.sin(3.0 * a + p[P_PH3])
    elif mode == 2.0:
        s = math.tanh(3.0 * math.sin(a)) / math.tanh(3.0)
    else:
        s = (1.0 + p[P_ECC] * math.sin(p[P_NECC] * th)) * math.sin(a) / (1.0 + p[P_ECC])
    return p[P_TCOG] * s


@jit
def _load(w: float, p: FloatArray) -> float:
    mode = p[P_LOAD]
    tl = p[P_TL]
    if mode == 1.0:
        return tl
    if mode == 2.0:  # lead screw: lifting costs T/eta, lowering gives back T*eta
        if w * tl > 0.0:
            return tl / p[P_ETA]
        if w * tl < 0.0:
            return tl * p[P_ETA]
        return tl
    return 0.0


@jit
def _flux(i: float, th_housing: float, p: FloatArray) -> float:
    k = p[P_KE] * (1.0 + p[P_BETA] * th_housing)
    if p[P_AR] > 0.0:  # armature reaction weakens the field at high current
        x = (i / p[P_AR_I]) ** 2
        k *= 1.0 - p[P_AR] * x / (1.0 + x)
    return k


@jit
def _coupling(x: FloatArray, p: FloatArray) -> float:
    if p[P_COUPLE] == 0.0:
        return 0.0
    d = x[S_TH] - x[S_THL]
    dv = x[S_W] - x[S_WL]
    if p[P_COUPLE] == 2.0:  # backlash: no torque inside the gap
        g = p[P_GAP]
        if abs(d) <= g:
            return 0.0
        d = d - g * _sgn(d)
    return p[P_KC] * d + p[P_CC] * dv


@jit
def _other_torque(x: FloatArray, t: float, p: FloatArray) -> float:
    """Every torque on the rotor except dry friction, as drive minus losses."""
    w = x[S_W]
    k = _flux(x[S_I], x[S_TH2], p)
    tq = k * x[S_I] - p[P_B] * w - _drag(w, p) - _load(w, p) - _cogging(x[S_TH], p)
    tq -= p[P_RIP_T] * math.sin(2.0 * math.pi * p[P_RIP_F] * t) + _coupling(x, p)
    return tq


@jit
def _friction(w: float, drive: float, f_bristle: float, p: FloatArray) -> float:
    mode = p[P_FRIC]
    if mode == 0.0:
        return 0.0
    if mode == 3.0:  # LuGre: the bristle force, held over the sub-step
        return f_bristle
    level = p[P_TC] + _stribeck(w, p)
    if mode == 2.0:
        return level * math.tanh(w / p[P_WT])
    if w != 0.0:
        return level * _sgn(w)
    return level * _sgn(drive)


@jit
def _bristles(x: FloatArray, h: float, p: FloatArray) -> float:
    """Advance the LuGre bristle state over a sub-step by its exact solution (speed
    held) and return the bristle force sigma0 z + sigma1 dz/dt over that step."""
    w = x[S_W]
    z0 = x[S_Z]
    g = p[P_TC] + _stribeck(w, p)
    if w == 0.0:
        z1 = z0
    elif g > 0.0:
        zss = g * _sgn(w) / p[P_SIG0]
        z1 = zss + (z0 - zss) * math.exp(-p[P_SIG0] * abs(w) * h / g)
    else:
        # no friction level left at this speed (a Stribeck torque alone, far beyond its
        # speed: the exponential underflows to 0): the bristles relax at once, the limit
        # g -> 0 of the line above (z0 + w h, an ever-stretching spring, is not LuGre)
        z1 = 0.0
    x[S_Z] = z1
    return p[P_SIG0] * 0.5 * (z0 + z1) + p[P_SIG1] * (z1 - z0) / h


@jit
def _deriv(
    x: FloatArray,
    va: float,
    open_: bool,
    t: float,
    p: FloatArray,
    stuck: bool,
    f_bristle: float,
    out: FloatArray,
) -> None:
    i = 0.0 if open_ else x[S_I]
    w = x[S_W]
    k = _flux(i, x[S_TH2], p)
    r = p[P_R] * (1.0 + p[P_ALPHA] * x[S_TW])
    if open_:
        out[S_I] = 0.0
    else:
        vs = va - p[P_SAG_RS] * (va / p[P_VBUS]) ** 2 * i
        out[S_I] = (vs - r * i - k * w - _brush(i, p)) / _inductance(i, p)
    drive = _other_torque(x, t, p)
    out[S_W] = 0.0 if stuck else (drive - _friction(w, drive, f_bristle, p)) / p[P_J]
    out[S_TH] = 0.0 if stuck else w
    # thermal network (P_THERM: 1 integral, 2 first order, 3 winding + housing)
    heat = p[P_KHEAT] * i * i * r
    tw, th2 = x[S_TW], x[S_TH2]
    mode = p[P_THERM]
    out[S_TW] = heat
    out[S_TH2] = 0.0
    if mode == 2.0:
        out[S_TW] = heat - tw / p[P_TAUW]
    elif mode == 3.0:
        out[S_TW] = heat - (tw - th2) / p[P_TAUW]
        out[S_TH2] = p[P_CRATIO] * (tw - th2) / p[P_TAUW] - th2 / p[P_TAUH]
    out[S_VA] = 0.0
    out[S_Z] = 0.0
    if p[P_COUPLE] != 0.0:
        tc = _coupling(x, p)
        grav = p[P_TL] if p[P_LOAD] == 3.0 else 0.0
        out[S_WL] = (tc - p[P_BL] * x[S_WL] - grav) / p[P_JL]
        out[S_THL] = x[S_WL]
    else:
        out[S_WL] = 0.0
        out[S_THL] = 0.0
    # analog sensor filters (cascaded first-order stages)
    ai = 2.0 * math.pi * p[P_FC_I]
    aw = 2.0 * math.pi * p[P_FC_W]
    out[S_IF1] = ai * (i - x[S_IF1]) if ai > 0.0 else 0.0
    out[S_IF2] = ai * (x[S_IF1] - x[S_IF2]) if ai > 0.0 else 0.0
    out[S_WF1] = aw * (w - x[S_WF1]) if aw > 0.0 else 0.0
    out[S_WF2] = aw * (x[S_WF1] - x[S_WF2]) if aw > 0.0 else 0.0


@jit
def _command(cmd: FloatArray, dt: float, t: float, p: FloatArray) -> float:
    """Commanded voltage reaching the motor at time t: transport delay, dead zone."""
    k = int(math.floor((t - p[P_DELAY]) / dt + 1e-9))
    v = 0.0 if k < 0 else cmd[min(k, cmd.size - 1)]
    if math.isnan(v):
        return v
    d = p[P_VD]
    if p[P_DZ] == 1.0:  # hard threshold, no shift above it
        return v if abs(v) > d else 0.0
    if p[P_DZ] == 2.0:  # soft knee: v - d tanh(v/d)
        return v - d * math.tanh(v / d)
    return v


@jit
def _run(cmd: FloatArray, dt: float, nsub: int, p: FloatArray, x: FloatArray, rec: FloatArray):  # type: ignore[no-untyped-def]
    n = cmd.size
    h = dt / nsub
    k1 = np.zeros(NS)
    k2 = np.zeros(NS)
    k3 = np.zeros(NS)
    k4 = np.zeros(NS)
    xs = np.zeros(NS)
    stuck = p[P_FRIC] == 1.0 and (p[P_TC] + p[P_TS]) > 0.0
    stuck = stuck and x[S_W] == 0.0
    t = 0.0
    for k in range(n):
        rec[k, 0] = x[S_I]
        rec[k, 1] = x[S_W]
        rec[k, 2] = x[S_TH]
        rec[k, 3] = x[S_IF2] if p[P_ORD_I] == 2.0 else x[S_IF1]
        rec[k, 4] = x[S_WF2] if p[P_ORD_W] == 2.0 else x[S_WF1]
        rec[k, 5] = x[S_TW]
        rec[k, 6] = x[S_TH2]
        for _ in range(nsub):
            v = _command(cmd, dt, t, p)
            open_ = math.isnan(v)
            vt = 0.0 if open_ else v
            if p[P_LAG] > 0.0:  # exact first-order lag over the sub-step
                x[S_VA] = vt + (x[S_VA] - vt) * math.exp(-h / p[P_LAG])
                va = x[S_VA]
            else:
                va = vt
            if open_:
                x[S_I] = 0.0
            if stuck:
                drive = _other_torque(x, t, p)
                if abs(drive) > p[P_TC] + p[P_TS]:
                    stuck = False
            w_old = x[S_W]
            fb = _bristles(x, h, p) if p[P_FRIC] == 3.0 else 0.0
            _deriv(x, va, open_, t, p, stuck, fb, k1)
            for m in range(NS):
                xs[m] = x[m] + 0.5 * h * k1[m]
            _deriv(xs, va, open_, t + 0.5 * h, p, stuck, fb, k2)
            for m in range(NS):
                xs[m] = x[m] + 0.5 * h * k2[m]
            _deriv(xs, va, open_, t + 0.5 * h, p, stuck, fb, k3)
            for m in range(NS):
                xs[m] = x[m] + h * k3[m]
            _deriv(xs, va, open_, t + h, p, stuck, fb, k4)
            for m in range(NS):
                x[m] += h / 6.0 * (k1[m] + 2.0 * k2[m] + 2.0 * k3[m] + k4[m])
            if open_:
                x[S_I] = 0.0
            if p[P_FRIC] == 1.0 and not stuck and (p[P_TC] + p[P_TS]) > 0.0:
                if w_old * x[S_W] < 0.0 or x[S_W] == 0.0:
                    xs[:] = x
                    xs[S_W] = 0.0
                    if abs(_other_torque(xs, t + h, p)) <= p[P_TC] + p[P_TS]:
                        stuck = True
                        x[S_W] = 0.0
            t += h
        t = (k + 1) * dt  # no drift of the sub-step clock


class SimOutput:
    """Sampled true and sensor-filtered signals (index k = state at t_k)."""

    def __init__(self, rec: FloatArray, dt_s: float) -> None:
        self.dt_s = dt_s
        self.current = rec[:, 0]
        self.speed = rec[:, 1]
        self.position = rec[:, 2]
        self.current_filtered = rec[:, 3]
        self.speed_filtered = rec[:, 4]
        self.winding_rise_k = rec[:, 5]
        self.housing_rise_k = rec[:, 6]

    @property
    def t(self) -> FloatArray:
        return np.arange(self.current.size) * self.dt_s


def substeps_for(p: FloatArray, dt_s: float) -> int:
    """Sub-steps per sample so that every time constant present is resolved."""
    limits = [dt_s / 8.0]
    l_min = p[P_L] * min(p[P_LRHO], 1.0)
    if p[P_LS] == 2.0:
        l_min = p[P_L] * 0.05
    limits.append(0.7 * l_min / p[P_R])
    if p[P_BRUSH] > 0 and p[P_VB] > 0:
        # the drop's steepest slope, at zero current: VB / I0 for tanh and the
        # saturating law; VB I0^n / I0 for the power law's linear stretch (its VB is
        # in volts per ampere^n: VB / I0 counted 1 / I0^n too many sub-steps)
        slope = p[P_VB] / p[P_I0]
        if p[P_BRUSH] == 3.0:
            slope *= p[P_I0] ** p[P_PW]
        limits.append(0.7 * l_min / slope)
    if p[P_FRIC] == 2.0:
        limits.append(0.7 * p[P_J] * p[P_WT] / (p[P_TC] + p[P_TS] + 1e-30))
    if p[P_FRIC] == 3.0:
        limits.append(0.3 / math.sqrt(p[P_SIG0] / p[P_J]))
    if p[P_COUPLE] != 0.0:
        limits.append(0.3 / math.sqrt(p[P_KC] * (1.0 / p[P_J] + 1.0 / p[P_JL])))
    for fc in (p[P_FC_I], p[P_FC_W]):
        if fc > 0:
            limits.append(0.3 / (2.0 * math.pi * fc))
    if p[P_LAG] > 0:
        limits.append(p[P_LAG])
    n = int(math.ceil(dt_s / min(limits)))
    return max(n, 8)


def simulate_plant(
    command_v: FloatArray, dt_s: float, p: FloatArray, *, max_substeps: int = 4000
) -> SimOutput:
    """Simulate a whole record from rest (NaN command = armature open)."""
    cmd = np.ascontiguousarray(command_v, dtype=np.float64)
    nsub = substeps_for(p, dt_s)
    if nsub > max_substeps:
        msg = f"plant too stiff for the sample period: {nsub} sub-steps per sample"
        raise ValueError(msg)
    x = np.zeros(NS)
    if p[P_COUPLE] != 0.0 and p[P_LOAD] == GRAVITY_LOAD:
        x[S_THL] = -p[P_TL] / p[P_KC]  # coupling pre-loaded by the hanging load
    rec = np.zeros((cmd.size, 7))
    _run(cmd, float(dt_s), int(nsub), np.ascontiguousarray(p), x, rec)
    return SimOutput(rec, dt_s)
