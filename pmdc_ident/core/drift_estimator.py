"""Recursive estimation of the slowly varying motor quantities from normal operation.

No test signal is needed: the motor's own equations are regressed on filtered
signals (a state-variable filter ``F(s) = 1/(tau s + 1)``, so no raw derivative
of a noisy signal is taken)::

    electrical  F[V] - L s F[i]               = R F[i] + Ke F[w] + d s F[V]
    mechanical  Kt F[i] - J s F[w] - B F[w]   = Tf F[sign w]

``d`` is the command delay (first-order Taylor of ``V(t - d)``, valid while ``d``
is well below ``tau``; the voltage is first shifted by the current delay estimate,
so the expansion is about that estimate, as in an extended Kalman filter), ``Tf``
the Coulomb-equivalent friction torque. ``L``,
``J`` and ``B`` are the identified values; ``Kt`` follows ``Ke`` (a weakening
magnet lowers both in proportion).

Each parameter vector is the state of a Kalman filter with random-walk dynamics
(process noise per second, :class:`EstimatorTuning`), so its covariance grows
where the data carry no information about it (a motor standing still, one
operating point) and shrinks where they do: an estimate is only as certain as
the recent excitation allows. The equation-error variance is learnt online (an
exponentially weighted mean of the innovations). Updates are made every ``2 tau``,
about the correlation time of the filtered noise, so the samples used are close
to independent and the intervals are honest. The voltage is a zero-order hold
(``V[k]`` over ``[t_k, t_k+1)``), current and speed are point samples: the filters
are discretised exactly for those two input shapes, so the sampling itself adds no
spurious delay. An open armature (NaN voltage) pauses the electrical equation until
its filter has settled again.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core._jit import njit

__all__ = ["OUT_COLUMNS", "EstimatorTuning", "new_state", "run_estimator"]

FloatArray = NDArray[np.float64]

# Columns of the rows the kernel writes (one row per filter update).
OUT_COLUMNS: tuple[str, ...] = (
    "t_s",
    "R",
    "Ke",
    "delay_s",
    "var_R",
    "var_Ke",
    "var_delay",
    "friction_nm",
    "var_friction",
    "electrical_updated",
    "mechanical_updated",
)
_NOUT = len(OUT_COLUMNS)
# Filter / bookkeeping state slots.
_VF, _IF, _WF, _SF, _VPREV, _IPREV, _WPREV, _TPREV, _ECOUNT, _SINCE, _SIG_E, _SIG_M, _INIT = range(
    13
)
_HEAD = 13  # index of the newest command in the ring buffer
_NSTATE = 14
_NBUF = 256  # commands kept to shift the voltage by the delay estimate


@dataclass(frozen=True)
class EstimatorTuning:
    """Filter and random-walk settings (SI; relative rates are per sqrt(s))."""

    filter_tau_s: float = 0.01
    r_rate_rel: float = 0.01  # R may wander 1 % per sqrt(s)
    ke_rate_rel: float = 0.002
    friction_rate_nm: float = 0.0  # 0: 1 % of the motor's rated torque per sqrt(s)
    delay_rate_s: float = 5e-4
    noise_time_s: float = 2.0  # memory of the equation-error variance
    speed_deadband_rad_s: float = 0.0  # 0: 2 % of the speed limit
    max_gap_s: float = 0.1  # a longer gap between samples restarts the filters


def new_state(theta_e: FloatArray, var_e: FloatArray, theta_m: float, var_m: float) -> dict:
    """Fresh estimator state from prior values and variances."""
    return {
        "st": np.zeros(_NSTATE),
        "buf": np.full(_NBUF, np.nan),
        "th_e": np.asarray(theta_e, dtype=float).copy(),
        "p_e": np.diag(np.asarray(var_e, dtype=float)),
        "th_m": np.array([theta_m], dtype=float),
        "p_m": np.array([[var_m]], dtype=float),
    }


def run_estimator(
    state: dict,
    t: FloatArray,
    v: FloatArray,
    i: FloatArray,
    w: FloatArray,
    consts: FloatArray,
) -> FloatArray:
    """Feed samples through the filters; return one row (:data:`OUT_COLUMNS`) per update.

    ``consts`` = ``[L, J, B, Kt0, Ke0, tau, q_R, q_Ke, q_d, q_Tf, noise_time, deadband,
    max_gap, var_cap_R, var_cap_Ke, var_cap_d, var_cap_Tf, current_gate]`` (q = variance
    per second; the gate is the filtered current below which R learns nothing).
    """
    n = t.size
    out = np.empty((n + 2, _NOUT))
    k = _kernel(
        np.ascontiguousarray(t, dtype=float),
        np.ascontiguousarray(v, dtype=float),
        np.ascontiguousarray(i, dtype=float),
        np.ascontiguousarray(w, dtype=float),
        state["st"],
        state["buf"],
        state["th_e"],
        state["p_e"],
        state["th_m"],
        state["p_m"],
        consts,
        out,
    )
    return out[:k]


@njit
def _kf_update(th, p, phi, y, sig2):  # pragma: no cover - jitted
    """Scalar-measurement Kalman update in place; returns the innovation."""
    n = th.shape[0]
    pphi = np.zeros(n)
    for a in range(n):
        acc = 0.0
        for b in range(n):
            acc += p[a, b] * phi[b]
        pphi[a] = acc
    s = sig2
    pred = 0.0
    for a in range(n):
        s += phi[a] * pphi[a]
        pred += phi[a] * th[a]
    e = y - pred
    lim = 5.0 * math.sqrt(s)  # Huber-style clip of outliers
    e_used = min(max(e, -lim), lim)
    for a in range(n):
        th[a] += pphi[a] / s * e_used
    for a in range(n):
        for b in range(n):
            p[a, b] -= pphi[a] * pphi[b] / s
    return e


@njit
def _filt_lin(xf, x0, x1, a, tau, h):  # pragma: no cover - jitted
    """First-order filter over one interval of a linearly interpolated input (exact)."""
    return a * xf + (1.0 - a) * x0 + (x1 - x0) * (1.0 - (1.0 - a) * tau / h)


@njit
def _sign(x, dead):  # pragma: no cover - jitted
    if x > dead:
        return 1.0
    if x < -dead:
        return -1.0
    return 0.0


@njit
def _shifted(buf, head, lag):  # pragma: no cover - jitted
    """The command ``lag`` samples before the newest in the ring buffer."""
    return buf[(head - lag) % buf.shape[0]]


@njit
def _kernel(t, v, i, w, st, buf, th_e, p_e, th_m, p_m, c, out):  # pragma: no cover - jitted
    el, jj, bb, kt0, ke0, tau = c[0], c[1], c[2], c[3], c[4], c[5]
    q_r, q_ke, q_d, q_tf, t_noise, dead, max_gap = c[6], c[7], c[8], c[9], c[10], c[11], c[12]
    i_gate = c[17]
    nbuf = buf.shape[0]
    phi_e = np.zeros(3)
    phi_m = np.zeros(1)
    n_out = 0
    for k in range(t.shape[0]):
        if np.isnan(i[k]) or np.isnan(w[k]):
            st[_INIT] = 0.0
            continue
        h = t[k] - st[_TPREV]
        if st[_INIT] < 0.5 or h <= 0.0 or h > max_gap:
            vk = v[k] if not np.isnan(v[k]) else 0.0
            st[_VF], st[_IF], st[_WF], st[_SF] = vk, i[k], w[k], _sign(w[k], dead)
            st[_VPREV], st[_IPREV], st[_WPREV], st[_TPREV] = v[k], i[k], w[k], t[k]
            st[_ECOUNT], st[_SINCE], st[_INIT] = 0.0, 0.0, 1.0
            buf[:] = v[k]
            continue
        a = math.exp(-h / tau)
        # The command held over the last interval, shifted by the delay estimate d:
        # part f of the interval still sees the older command.
        head = int(st[_HEAD])
        head = (head + 1) % nbuf
        buf[head] = st[_VPREV]
        st[_HEAD] = head
        d_hat = min(max(th_e[2], 0.0), (nbuf - 3) * h)
        lag = int(d_hat / h)
        f = d_hat / h - lag
        v_new = _shifted(buf, head, lag)
        v_old = _shifted(buf, head, lag + 1)
        if np.isnan(v_new) or np.isnan(v_old):
            st[_ECOUNT] = 0.0
            st[_VF] = 0.0
        else:
            if st[_ECOUNT] == 0.0:
                st[_VF] = v_old
            a1 = math.exp(-f * h / tau)
            vf = a1 * st[_VF] + (1.0 - a1) * v_old
            st[_VF] = (a / a1) * vf + (1.0 - a / a1) * v_new
            st[_ECOUNT] += h
        st[_IF] = _filt_lin(st[_IF], st[_IPREV], i[k], a, tau, h)
        st[_WF] = _filt_lin(st[_WF], st[_WPREV], w[k], a, tau, h)
        st[_SF] = _filt_lin(st[_SF], _sign(st[_WPREV], dead), _sign(w[k], dead), a, tau, h)
        st[_VPREV], st[_IPREV], st[_WPREV], st[_TPREV] = v[k], i[k], w[k], t[k]
        st[_SINCE] += h
        # random-walk growth of the covariances, capped at the prior's size
        p_e[0, 0] = min(p_e[0, 0] + q_r * h, c[13])
        p_e[1, 1] = min(p_e[1, 1] + q_ke * h, c[14])
        p_e[2, 2] = min(p_e[2, 2] + q_d * h, c[15])
        p_m[0, 0] = min(p_m[0, 0] + q_tf * h, c[16])
        if st[_SINCE] < 2.0 * tau:
            continue
        beta = min(1.0, st[_SINCE] / t_noise)
        st[_SINCE] = 0.0
        e_up = 0.0
        # Electrical equation: only where current or speed stand out of the noise
        # (regressing noise on noise would pull R and Ke towards zero).
        moving = abs(st[_WF]) > dead
        loaded = abs(st[_IF]) > i_gate
        if st[_ECOUNT] >= 5.0 * tau and (moving or loaded):
            dvf = (v_new - st[_VF]) / tau
            phi_e[0] = st[_IF] if loaded else 0.0
            phi_e[1] = st[_WF] if moving else 0.0
            phi_e[2] = dvf
            # linearised about d_hat: V(t - d) ~ V(t - d_hat) - (d - d_hat) dV/dt
            y = st[_VF] + d_hat * dvf - el * (i[k] - st[_IF]) / tau
            y -= (0.0 if loaded else th_e[0] * st[_IF]) + (0.0 if moving else th_e[1] * st[_WF])
            if st[_SIG_E] <= 0.0:
                st[_SIG_E] = (y - phi_e[0] * th_e[0] - phi_e[1] * th_e[1]) ** 2 + 1e-12
            e = _kf_update(th_e, p_e, phi_e, y, st[_SIG_E])
            st[_SIG_E] += beta * (e * e - st[_SIG_E])
            e_up = 1.0
        m_up = 0.0
        if abs(st[_SF]) > 0.99:
            kt = kt0 * th_e[1] / ke0
            phi_m[0] = st[_SF]
            y = kt * st[_IF] - jj * (w[k] - st[_WF]) / tau - bb * st[_WF]
            if st[_SIG_M] <= 0.0:
                st[_SIG_M] = (y - phi_m[0] * th_m[0]) ** 2 + 1e-18
            e = _kf_update(th_m, p_m, phi_m, y, st[_SIG_M])
            st[_SIG_M] += beta * (e * e - st[_SIG_M])
            m_up = 1.0
        row = out[n_out]
        row[0], row[1], row[2], row[3] = t[k], th_e[0], th_e[1], th_e[2]
        row[4], row[5], row[6] = p_e[0, 0], p_e[1, 1], p_e[2, 2]
        row[7], row[8], row[9], row[10] = th_m[0], p_m[0, 0], e_up, m_up
        n_out += 1
    return n_out
