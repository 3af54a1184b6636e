"""Checks of the covariance intervals: a parametric bootstrap.

The fitted model is simulated on the recorded inputs from the fitted initial
states, white noise at the fitted per-signal levels is added, and the fit is
repeated from the fitted values. The spread of the refits, compared with the
covariance standard errors, tells whether the intervals can be trusted (ratio
near 1); a ratio well above 1 means the linearised covariance is optimistic.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.output_error import CLOSURE_KT_KE, FitResult, fit_output_error

__all__ = ["parametric_bootstrap", "simulated_copy"]


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
