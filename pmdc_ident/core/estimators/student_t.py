"""Student's t quantile without scipy, for the classical chain's intervals.

:func:`t_quantile` is Student's t quantile: Newton steps on the regularised incomplete
beta function (a continued fraction) below 300 degrees of freedom, the expansion in
1/dof from 300 on; within 1e-11 of scipy's ``stdtrit`` (a test compares them).

Kept by hand on a measurement: ``scipy.special.stdtrit`` needs ``import scipy.special``,
about 0.3 s of CPU on this project's 2-core machine, while ``pmdc-ident identify`` of a
staircase table takes about 0.4 s in all; ``benchmarks/bench_scipy_imports.py`` measures
both, and the quantile's agreement, in one run.
"""

from __future__ import annotations

import math

__all__ = ["t_quantile"]


# ---------------------------------------------------------------------------
# Student's t quantile
# ---------------------------------------------------------------------------
def _beta_cf(a: float, b: float, x: float) -> float:
    """The continued fraction of the incomplete beta function (modified Lentz)."""
    tiny = 1e-300
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c, d = 1.0, 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > tiny else tiny)
    h = d
    for m in range(1, 100000):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > tiny else tiny)
        c = 1.0 + aa / c
        c = c if abs(c) > tiny else tiny
        delta = d * c
        h *= delta
        if abs(delta - 1.0) < 1e-16:
            break
    return h


def _betainc(a: float, b: float, x: float) -> float:
    """The regularised incomplete beta function I_x(a, b), 0 <= x <= 1."""
    if x <= 0.0:
        return 0.0
    if x >= 1.0:
        return 1.0
    log_front = (
        math.lgamma(a + b) - math.lgamma(a) - math.lgamma(b) + a * math.log(x) + b * math.log1p(-x)
    )
    if x < (a + 1.0) / (a + b + 2.0):
        return math.exp(log_front) * _beta_cf(a, b, x) / a
    return 1.0 - math.exp(log_front) * _beta_cf(b, a, 1.0 - x) / b


def _t_upper_tail(t: float, dof: float) -> float:
    """P(T > t) for t >= 0."""
    return 0.5 * _betainc(0.5 * dof, 0.5, dof / (dof + t * t))


def _t_log_pdf(t: float, dof: float) -> float:
    return (
        math.lgamma(0.5 * (dof + 1.0))
        - math.lgamma(0.5 * dof)
        - 0.5 * math.log(dof * math.pi)
        - 0.5 * (dof + 1.0) * math.log1p(t * t / dof)
    )


def t_quantile(p: float, dof: float) -> float:
    """Student's t quantile: the ``t`` with P(T <= t) = ``p``, ``dof`` >= 1 degrees of freedom."""
    if not 0.0 < p < 1.0 or not dof >= 1.0:
        msg = f"t_quantile needs 0 < p < 1 and dof >= 1, got p={p}, dof={dof}"
        raise ValueError(msg)
    if p < 0.5:
        return -t_quantile(1.0 - p, dof)
    if p == 0.5:
        return 0.0
    if dof == 1.0:
        return math.tan(math.pi * (p - 0.5))
    if dof == 2.0:
        return (2.0 * p - 1.0) * math.sqrt(2.0 / (4.0 * p * (1.0 - p)))
    q = 1.0 - p
    z = _normal_upper_quantile(q)
    # the expansion in 1/dof (Abramowitz & Stegun 26.7.5): its next term is below 1e-12
    # from 300 degrees of freedom on, where lgamma's differences below lose digits
    g = (
        (z**3 + z) / 4.0,
        (5.0 * z**5 + 16.0 * z**3 + 3.0 * z) / 96.0,
        (3.0 * z**7 + 19.0 * z**5 + 17.0 * z**3 - 15.0 * z) / 384.0,
        (79.0 * z**9 + 776.0 * z**7 + 1482.0 * z**5 - 1920.0 * z**3 - 945.0 * z) / 92160.0,
    )
    t = z + sum(gk / dof ** (k + 1) for k, gk in enumerate(g))
    if dof >= 300.0:
        return t
    for _ in range(100):
        pdf = math.exp(_t_log_pdf(t, dof))
        if not pdf > 0.0:
            break
        dt = (_t_upper_tail(t, dof) - q) / pdf
        t += dt
        if abs(dt) <= 1e-15 * abs(t):
            break
    return t


def _normal_upper_quantile(q: float) -> float:
    """z with P(Z > z) = q, by Newton on erfc (a start for :func:`t_quantile`)."""
    z = math.sqrt(-2.0 * math.log(q))
    z -= (2.515517 + 0.802853 * z + 0.010328 * z * z) / (
        1.0 + 1.432788 * z + 0.189269 * z * z + 0.001308 * z**3
    )
    for _ in range(50):
        f = 0.5 * math.erfc(z / math.sqrt(2.0)) - q
        dz = f / (math.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi))
        z += dz
        if abs(dz) <= 1e-15 * max(abs(z), 1.0):
            break
    return z
