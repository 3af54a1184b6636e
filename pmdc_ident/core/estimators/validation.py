"""Validation of a fitted model: held-out free-run error, residual whiteness, cross-correlation."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.estimators.output_error import FitResult

__all__ = ["HoldoutScore", "ResidualTests", "holdout_score", "residual_tests"]

FloatArray = NDArray[np.float64]
MAX_LAG = 25


@dataclass(frozen=True)
class HoldoutScore:
    """Free-run error on segments the fit never saw."""

    labels: tuple[str, ...]
    rms: dict[str, float]  # per signal, in its unit
    nrmse: dict[str, float]  # rms / std of the measured signal


def holdout_score(fit: FitResult, segments: Sequence[Segment]) -> HoldoutScore:
    preds = fit.simulate_segments(segments, use_fitted_initial_states=False)
    acc: dict[str, list[FloatArray]] = {}
    meas: dict[str, list[FloatArray]] = {}
    for seg, pred in zip(segments, preds, strict=True):
        pairs = []
        if seg.current is not None and seg.voltage is not None:
            pairs.append(("current", seg.current, pred.current))
        if seg.speed is not None:
            pairs.append(("speed", seg.speed, pred.speed))
        elif seg.position is not None:
            pairs.append(("position", seg.position, pred.position))
        for name, y, yhat in pairs:
            acc.setdefault(name, []).append(yhat - y)
            meas.setdefault(name, []).append(y)
    rms = {k: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) for k, v in acc.items()}
    nrmse = {}
    for k, v in meas.items():
        sd = float(np.std(np.concatenate(v)))
        nrmse[k] = rms[k] / sd if sd > 0 else math.inf
    return HoldoutScore(tuple(s.label for s in segments), rms, nrmse)


@dataclass(frozen=True)
class ResidualTests:
    """Whiteness (autocorrelation) and input cross-correlation of the fit residuals.

    ``*_outside`` is the fraction of lags 1..25 whose normalised correlation lies
    outside the 95 % band ``+-1.96/sqrt(N)``; about 5 % for white residuals
    independent of the input. Structured model error shows as far more.
    """

    autocorr_outside: dict[str, float]
    crosscorr_outside: dict[str, float]
    autocorr_max: dict[str, float]
    crosscorr_max: dict[str, float]
    white: dict[str, bool]
    independent_of_input: dict[str, bool]


def _xcorr(a: FloatArray, b: FloatArray, lags: range) -> FloatArray:
    a = a - a.mean()
    b = b - b.mean()
    den = math.sqrt(float(a @ a) * float(b @ b)) or 1.0
    return np.array([float(a[: a.size - k] @ b[k:]) / den for k in lags])


def residual_tests(fit: FitResult, segments: Sequence[Segment]) -> ResidualTests:
    preds = fit.simulate_segments(segments)
    ac_out: dict[str, list[float]] = {}
    cc_out: dict[str, list[float]] = {}
    ac_max: dict[str, float] = {}
    cc_max: dict[str, float] = {}
    for seg, pred in zip(segments, preds, strict=True):
        if seg.n < 4 * MAX_LAG:
            continue
        sigs = []
        if seg.current is not None and seg.voltage is not None:
            sigs.append(("current", seg.current - pred.current))
        if seg.speed is not None:
            sigs.append(("speed", seg.speed - pred.speed))
        band = 1.96 / math.sqrt(seg.n)
        u = None
        if seg.voltage is not None and not np.isnan(seg.voltage).any():
            u = seg.voltage
        for name, r in sigs:
            ac = _xcorr(r, r, range(1, MAX_LAG + 1))
            ac_out.setdefault(name, []).append(float(np.mean(np.abs(ac) > band)))
            ac_max[name] = max(ac_max.get(name, 0.0), float(np.max(np.abs(ac))))
            if u is not None and np.ptp(u) > 0:
                cc = _xcorr(u, r, range(0, MAX_LAG + 1))
                cc_out.setdefault(name, []).append(float(np.mean(np.abs(cc) > band)))
                cc_max[name] = max(cc_max.get(name, 0.0), float(np.max(np.abs(cc))))
    ac = {k: float(np.mean(v)) for k, v in ac_out.items()}
    cc = {k: float(np.mean(v)) for k, v in cc_out.items()}
    return ResidualTests(
        autocorr_outside=ac,
        crosscorr_outside=cc,
        autocorr_max=ac_max,
        crosscorr_max=cc_max,
        white={k: v <= 0.2 for k, v in ac.items()},
        independent_of_input={k: v <= 0.2 for k, v in cc.items()},
    )
