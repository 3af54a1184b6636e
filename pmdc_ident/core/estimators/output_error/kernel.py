"""The fast path's numba kernel: one exact zero-order-hold step per sample with the
sensitivity equations propagated alongside the state (see :mod:`.simulators` for the
matrices it is given and :mod:`.problem` for how its normal equations are used).

Its compiled form embeds :func:`pmdc_ident.core.model.effects_kernel`, but numba's
on-disk cache checks only this file's time stamp: a change to ``effects_kernel`` must
touch this file too (this note was last touched for the smooth brush drop in
effects_kernel, after the Stribeck shape exponent), or processes keep running the old
kernel here.
"""

from __future__ import annotations

import math

import numpy as np

from pmdc_ident.core._jit import njit
from pmdc_ident.core.effects.layout import (
    COL_CQ,
    COL_I0,
    COL_TC,
    COL_TH0,
    COL_TL,
    COL_TS,
    COL_W0,
    COL_WS,
    N_SENS,
)
from pmdc_ident.core.model import effects_kernel, stribeck_fall

__all__ = [
    "COL",
    "COL_CQ",
    "COL_I0",
    "COL_TC",
    "COL_TH0",
    "COL_TL",
    "COL_TS",
    "COL_W0",
    "COL_WS",
    "N_SENS",
    "fast_kernel",
]

# Sensitivity column layout of the kernel (core.effects.layout): R..B per log of the
# value, then Coulomb and load torque, the initial current, speed and angle, Stribeck
# torque and speed, drag. An effect on the fast path names its columns (FAST_COLUMNS).
COL = {"R": 0, "L": 1, "Ke": 2, "Kt": 3, "J": 4, "B": 5}


@njit
def fast_kernel(
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
    ``T = T_load + sign(w) (Tc + Ts exp(-(|w|/ws)^d)) + Cq w|w|`` (``fx`` = [Ts, ws,
    Cq, d]); their dependence on w enters the sensitivity recursion.

    ``cmode``: current-driven (mechanical only; ``imeas`` is the input).
    ``el``: rotor-held electrical step [a, b, da/dR, da/dL, db/dR, db/dL].
    """
    n = v.shape[0]
    X = np.empty((n, 3))
    ts, ws, cq, ds = fx[0], fx[1], fx[2], fx[3]
    t_static = tc + ts
    m = mx.shape[1]
    no = oidx.shape[0]
    A = np.zeros((m, m))
    g = np.zeros(m)
    jr = np.zeros(m)
    s = np.zeros((3, N_SENS))
    sn = np.zeros((3, N_SENS))
    need6 = np.zeros(6, dtype=np.bool_)
    for c in nc:
        if c < 6:
            need6[c] = True
    # The mixing matrix is sparse (each kernel column feeds one or two Jacobian columns):
    # its non-zero entries in the order of nc, so each Jacobian entry sums the same
    # terms in the same order as the dense product did (zero terms add nothing).
    n_mix = 0
    for c in nc:
        for c2 in range(m):
            if mx[c, c2] != 0.0:
                n_mix += 1
    mix_c = np.empty(n_mix, dtype=np.int64)
    mix_c2 = np.empty(n_mix, dtype=np.int64)
    mix_f = np.empty(n_mix)
    q = 0
    for c in nc:
        for c2 in range(m):
            if mx[c, c2] != 0.0:
                mix_c[q], mix_c2[q], mix_f[q] = c, c2, mx[c, c2]
                q += 1
    # The angle's sensitivities are needed only when the angle is an output: nothing
    # else depends on it (its column of Phi is zero in the current and speed rows).
    ns_rows = 2
    for o in range(no):
        if oidx[o] == 2:
            ns_rows = 3
    if phc[0, 2] != 0.0 or phc[1, 2] != 0.0 or pho[0, 2] != 0.0 or pho[1, 2] != 0.0:
        ns_rows = 3
    x = np.empty(3)
    xn = np.empty(3)
    st5 = np.zeros(5)
    vbuf = np.zeros(1)
    refine = nsub > 1 and not cmode and t_static > 0.0
    x[0], x[1], x[2] = x0[0], x0[1], x0[2]
    if cmode:
        x[0] = imeas[0]
    s[0, COL_I0] = 1.0
    s[1, COL_W0] = 1.0
    s[2, COL_TH0] = 1.0
    if cmode:
        s[0, COL_I0] = 0.0
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
                    jr[c2] = off[c2] if idx == 0 else 0.0
                for q in range(n_mix):
                    jr[mix_c2[q]] += s[idx, mix_c[q]] * mix_f[q]
                for c2 in range(m):
                    jr[c2] *= osc[o]
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
                effects_kernel(vbuf, coef, phs, gas, hs, nsub, False, st5)
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
        ex = stribeck_fall(w, ws, ds) if ts > 0.0 else 0.0
        # d/dw and ws d/dws of x^d, x = |w|/ws (d = 2: 2 w / ws^2 and 2 x^2)
        xr = abs(w) / ws
        xd = xr * xr if ds == 2.0 else xr**ds
        dxd_dw = 0.0 if w == 0.0 else ds * xd / w
        torque = tl + sg * (tc + ts * ex) + cq * w * abs(w)
        dt_dw = -sg * ts * ex * dxd_dw + 2.0 * cq * abs(w)
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
            for a in range(ns_rows):
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
                sn[a, COL_TC] += ga[a, 1] * sg
                sn[a, COL_TL] += ga[a, 1]
                if ts > 0.0:
                    sn[a, COL_TS] += ga[a, 1] * sg * ex
                    sn[a, COL_WS] += ga[a, 1] * sg * ts * ex * ds * xd / ws
                sn[a, COL_CQ] += ga[a, 1] * w * abs(w)
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
            effects_kernel(vbuf, coef, phs, gas, hs, nsub, False, st5)
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
            for a in range(ns_rows):
                for c in nc:
                    s[a, c] = sn[a, c]
    for c2 in range(m):
        for c3 in range(c2):
            A[c3, c2] = A[c2, c3]
    return X, A, g
