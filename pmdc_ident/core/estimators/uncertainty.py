"""Checks of the covariance intervals: a parametric bootstrap.

The fitted model is simulated on the recorded inputs from the fitted initial
states, white noise at the fitted per-signal levels is added, and the fit is
repeated from the fitted values. The spread of the refits, compared with the
covariance standard errors, tells whether the intervals can be trusted (ratio
near 1); a ratio well above 1 means the linearised covariance is optimistic.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE, FitResult, fit_output_error

__all__ = ["coloured_noise_factor", "parametric_bootstrap", "simulated_copy", "widen_interval"]

MAX_LAG = 50


def simulated_copy(
    fit: FitResult, segments: Sequence[Segment], rng: np.random.Generator
) -> list[Segment]:
    """The segments with the fitted model's response plus noise at the fitted levels."""
    preds = fit.simulate_segments(segments)
    out = []
    for seg, pred in zip(segments, preds, strict=True):
        kw: dict[str, Any] = {}
        if seg.current is not None and seg.voltage is not None:
            kw["current"] = pred.current + rng.normal(0, fit.noise.get("current", 0.0), seg.n)
        if seg.speed is not None:
            kw["speed"] = pred.speed + rng.normal(0, fit.noise.get("speed", 0.0), seg.n)
        if seg.position is not None:
            kw["position"] = pred.position + rng.normal(0, fit.noise.get("position", 0.0), seg.n)
        out.append(replace(seg, **kw))
    return out


def parametric_bootstrap(
    fit: FitResult,
    segments: Sequence[Segment],
    *,
    n: int = 20,
    seed: int = 0,
    closure: str | None = CLOSURE_KT_KE,
) -> dict[str, Any]:
    if fit.closure is None:
        closure = None
    """Refit ``n`` simulated copies; per parameter: bootstrap std and its ratio to the stderr."""
    rng = np.random.default_rng(seed)
    names = [k for k in fit.covariance_names if fit.stderr.get(k)]
    samples: dict[str, list[float]] = {k: [] for k in names}
    for _ in range(n):
        data = simulated_copy(fit, segments, rng)
        f = fit_output_error(
            data,
            fit.model,
            free=list(fit.free),
            fixed=fit.fixed,
            closure=closure,
            check_inductance=False,
            added_inertia=fit.added_inertia,
        )
        for k in names:
            samples[k].append(f.values[k])
    out: dict[str, Any] = {"n": n, "parameters": {}}
    for k in names:
        arr = np.array(samples[k])
        sd = float(arr.std(ddof=1)) if arr.size > 1 else float("nan")
        se = float(fit.stderr[k] or float("nan"))
        out["parameters"][k] = {
            "bootstrap_std": sd,
            "covariance_stderr": se,
            "ratio": sd / se if se > 0 else None,
            "bootstrap_ci95": [float(np.percentile(arr, 2.5)), float(np.percentile(arr, 97.5))],
        }
    return out


def coloured_noise_factor(fit: FitResult, segments: Sequence[Segment]) -> dict[str, float]:
    """Variance inflation for autocorrelated residuals, per signal (1 when white).

    ``1 + 2 sum_k (1 - k/(K+1)) rho_k`` over lags 1..50 (Bartlett weights), the
    long-run variance factor of a coloured residual: the covariance intervals
    assume white residuals, and their width scales with the square root of this.
    """
    preds = fit.simulate_segments(segments)
    acc: dict[str, list[float]] = {}
    for seg, pred in zip(segments, preds, strict=True):
        if seg.n < 4 * MAX_LAG:
            continue
        pairs = []
        if seg.current is not None and seg.voltage is not None:
            pairs.append(("current", seg.current - pred.current))
        if seg.speed is not None:
            pairs.append(("speed", seg.speed - pred.speed))
        for name, r in pairs:
            r = r - r.mean()
            den = float(r @ r)
            if den <= 0:
                continue
            f = 1.0
            for k in range(1, MAX_LAG + 1):
                rho = float(r[:-k] @ r[k:]) / den
                f += 2.0 * (1.0 - k / (MAX_LAG + 1)) * rho
            acc.setdefault(name, []).append(max(f, 1.0))
    return {k: float(np.median(v)) for k, v in acc.items()}


def _power(ratio: float, factor: float) -> float:
    try:
        return ratio**factor
    except OverflowError:
        return math.inf


def widen_interval(
    value: float, ci: tuple[float, float] | None, factor: float
) -> tuple[float, float] | None:
    """Scale an interval's half-widths by ``factor`` (in ratio when it is all positive)."""
    if ci is None or factor <= 1.0:
        return ci
    lo, hi = ci
    if lo > 0 and value > 0:
        # in ratio: an end past the float range is open (0 or inf), where a Python
        # float's ** raises OverflowError (a parameter bounded by nothing: sd 200 in
        # log puts its interval at e^+-392 around the value)
        return (value * _power(lo / value, factor), value * _power(hi / value, factor))
    return (value - (value - lo) * factor, value + (hi - value) * factor)
