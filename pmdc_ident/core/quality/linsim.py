"""Exact ZOH responses of small linear systems in plain numpy (no numba, no scipy).

The gate needs output-error sensitivities of the motor over long records within
a fraction of a second, without the JIT compiler or scipy's import time. A
linear system is split into its modes (eigenvalues of the sampled state
matrix); each mode is a first-order recursion ``z[k+1] = lam z[k] + w[k]``,
evaluated blockwise with a weighted cumulative sum (exact, vectorised) and the
block ends carried over in a short loop.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["expm", "first_order_scan", "zoh", "zoh_response"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
_LOG_RANGE = 300.0  # |lam|^-m stays below e^300 within a block


def expm(a: FloatArray) -> FloatArray:
    """Matrix exponential by scaling and squaring with a Taylor series (small matrices)."""
    norm = float(np.max(np.sum(np.abs(a), axis=0))) if a.size else 0.0
    s = max(0, int(math.ceil(math.log2(norm))) + 1) if norm > 0.5 else 0
    x = a / 2.0**s
    out = np.eye(a.shape[0])
    term = np.eye(a.shape[0])
    for k in range(1, 14):
        term = term @ x / k
        out = out + term
    for _ in range(s):
        out = out @ out
    return out


def zoh(a: FloatArray, b: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """``(Phi, Gamma)`` of ``x' = A x + B u`` with ``u`` held over each sample period."""
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n] = a * dt_s
    big[:n, n:] = b * dt_s
    e = expm(big)
    return e[:n, :n], e[:n, n:]


def first_order_scan(lam: complex, w: ComplexArray, z0: complex = 0.0) -> ComplexArray:
    """``z[0] = z0``, ``z[k+1] = lam z[k] + w[k]`` for ``k < n - 1``; returns ``z[:n]``."""
    n = w.size
    out = np.empty(n, dtype=complex)
    out[0] = z0
    if n == 1:
        return out
    drive = np.asarray(w[:-1], dtype=complex)
    mag = abs(lam)
    if mag < 1e-200:
        out[1:] = drive
        return out
    decay = -math.log(mag)
    m = int(min(max(_LOG_RANGE / decay, 1.0), 512.0)) if decay > 0 else 512
    pad = (-drive.size) % m
    d = np.concatenate([drive, np.zeros(pad, dtype=complex)]).reshape(-1, m)
    j = np.arange(m)
    up = lam ** (-j.astype(float))  # lam^-j
    down = lam ** (j + 1.0)  # lam^(j+1)
    # forced response inside each block from a zero block start
    forced = np.cumsum(d * up, axis=1) * (lam ** j.astype(float))
    carry = np.empty(d.shape[0], dtype=complex)  # state at each block's start
    state = complex(z0)
    for b in range(d.shape[0]):
        carry[b] = state
        state = forced[b, -1] + down[-1] * state
    full = forced + carry[:, None] * down[None, :]
    out[1:] = full.reshape(-1)[: n - 1]
    return out


def zoh_response(
    phi: FloatArray, gam: FloatArray, c: FloatArray, u: FloatArray, x0: FloatArray
) -> FloatArray:
    """Outputs ``y[k] = C x[k]`` of ``x[k+1] = Phi x[k] + Gamma u[k]`` from ``x[0] = x0``.

    ``u`` is ``(n, inputs)``, ``c`` is ``(outputs, states)``; returns ``(n, outputs)``.
    """
    lam, vec = np.linalg.eig(phi)
    inv = np.linalg.inv(vec)
    w = u @ (inv @ gam).T  # modal drive, (n, states)
    z0 = inv @ x0
    cv = c @ vec
    y = np.zeros((u.shape[0], c.shape[0]), dtype=complex)
    for j in range(lam.size):
        z = first_order_scan(complex(lam[j]), w[:, j], complex(z0[j]))
        y += np.outer(z, cv[:, j])
    return y.real
