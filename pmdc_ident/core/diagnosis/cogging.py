"""The cogging candidate, fitted in the measured shaft angle.

A cogging torque is periodic in the rotor's angle, and the log measures that angle.
A free-run simulation integrates its own angle: a speed error of 0.1 % puts a
17-period ripple a quarter period out of phase within a few turns, so a cogging
model fitted by output error in time matches the data only by chance (the fit is
multimodal in the phase and loses what it found on the next segment). Here the
torque is a function of the *measured* angle instead, ``T(t) = a sin(N theta(t)) +
b cos(N theta(t))``, an input to the baseline's linear motor: by superposition the
outputs change by ``a r_s + b r_c``, the responses of the motor (from rest, the
armature open where it was) to the two torque signals, so ``(a, b)`` follow by
weighted linear least squares on the fit segments' residuals (the motor's
parameters held at the baseline's). ``N`` (periods per measured turn: slots x
poles on a direct drive, x the gear ratio on a geared one, or the output gear's
teeth) comes from the residuals' angle spectrum
(:func:`~pmdc_ident.core.diagnosis.localization.angle_harmonics`); the one that
fits the fit segments best stands. The held-out segments are predicted with the
coefficients fixed, from their own measured angle, as a held-out voltage is used.

The candidate carries a :class:`~pmdc_ident.core.effects.Cogging` effect of the same
amplitude, count and phase, so it costs the effect's two fitted parameters and a
combination with another effect is fitted in time as before.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.localization import shaft_angle
from pmdc_ident.core.diagnosis.scoring import NoiseModel, Residuals, residuals, simulated
from pmdc_ident.core.diagnosis.search import FIT_ERRORS, Fitted, Search, predictions
from pmdc_ident.core.effects import Cogging
from pmdc_ident.core.model import simulate_linear
from pmdc_ident.core.params import MotorParams

__all__ = ["angle_cogging", "held_waves"]

FloatArray = NDArray[np.float64]
NOTE = "fitted in the measured shaft angle (linear least squares, motor parameters held)"


def _responses(
    p: MotorParams, seg: Segment, periods: float, noise: NoiseModel, skip: int = 0
) -> dict[str, FloatArray]:
    """Per signal, the (n - skip, 2) responses of the linear motor to the torques
    sin(N theta) and cos(N theta) of the segment's measured angle, from rest."""
    v = np.zeros(seg.n) if seg.voltage is None else np.where(np.isnan(seg.voltage), np.nan, 0.0)
    cols: dict[str, list[FloatArray]] = {sig: [] for sig in noise.signals}
    for torque in held_waves(shaft_angle(seg), periods):
        sim = simulate_linear(p, v, seg.dt_s, x0=[0.0, 0.0, 0.0], load_torque_nm=torque)
        for sig in noise.signals:
            cols[sig].append(simulated(seg, sim, sig)[skip:])
    return {sig: np.column_stack(c) for sig, c in cols.items()}


def held_waves(theta: FloatArray, periods: float) -> tuple[FloatArray, FloatArray]:
    """sin and cos of ``periods`` x the angle, each as its mean over the sample it is
    held for (the angle moving linearly to the next sample's): a fast rotor passes
    much of a period within one sample, and the value at its start is then not the
    torque the rotor felt (its mean is, to the sinc of half the angle step)."""
    step = np.diff(theta, append=theta[-1] + (theta[-1] - theta[-2] if theta.size > 1 else 0.0))
    mid = periods * (theta + 0.5 * step)
    fade = np.sinc(periods * step / (2.0 * np.pi))  # sin(x)/x at x = N step / 2
    return np.sin(mid) * fade, np.cos(mid) * fade


def _design(
    p: MotorParams,
    segs: Sequence[Segment],
    skips: Sequence[int],
    periods: float,
    noise: NoiseModel,
) -> dict[str, FloatArray]:
    parts = [_responses(p, s, periods, noise, k) for s, k in zip(segs, skips, strict=True)]
    return {sig: np.vstack([d[sig] for d in parts]) for sig in noise.signals}


def _solve(x: dict[str, FloatArray], res: Residuals) -> tuple[FloatArray, float]:
    """Coefficients that best cancel ``res`` (noise-weighted) and the weighted cost."""
    sig_w = {s: 1.0 / res.noise.sigma[s] ** 2 for s in x}
    a = sum(np.nan_to_num(x[s]).T @ np.nan_to_num(x[s]) * sig_w[s] for s in x)
    b = sum(np.nan_to_num(x[s]).T @ np.nan_to_num(res.error[s]) * sig_w[s] for s in x)
    coef = -np.linalg.solve(np.asarray(a) + 1e-12 * np.trace(a) * np.eye(2), np.asarray(b))
    cost = sum(float(np.nansum((res.error[s] + x[s] @ coef) ** 2)) * sig_w[s] for s in x)
    return coef, cost


def _shifted(res: Residuals, x: dict[str, FloatArray], coef: FloatArray) -> Residuals:
    err = {s: res.error[s] + np.nan_to_num(x[s]) @ coef for s in res.error}
    return Residuals(err, res.seg_index, res.noise)


def angle_cogging(
    search: Search, base: Fitted, periods: Sequence[int | float]
) -> tuple[Fitted, float]:
    """The cogging candidate (see the module notes) for the best of ``periods``, and its
    gap on the fit segments."""
    t0 = time.perf_counter()
    p = base.fit.model.params
    fit_segs = search.split.fit
    fit_res = residuals(fit_segs, predictions(base.fit, fit_segs), search.noise)
    best: tuple[float, float, FloatArray] | None = None
    try:
        for n in periods:
            x = _design(p, fit_segs, [0] * len(fit_segs), float(n), search.noise)
            coef, cost = _solve(x, fit_res)
            if best is None or cost < best[0]:
                best = (cost, float(n), coef)
        if best is None:
            msg = "no shaft-angle period to try"
            raise ValueError(msg)
        _, n_best, coef = best
        x_fit = _design(p, fit_segs, [0] * len(fit_segs), n_best, search.noise)
        leads = search.leads
        x_held = _design(
            p, [li.segment for li in leads], [li.samples for li in leads], n_best, search.noise
        )
    except FIT_ERRORS as exc:
        search.say(f"candidate cogging: fit failed ({exc})")
        return Fitted(("cogging",), base.fit, base.res, base.gap, 0.0, failed=True), math.inf
    res = _shifted(base.res, x_held, coef)
    amp, phase = float(math.hypot(coef[0], coef[1])), float(math.atan2(coef[1], coef[0]))
    effect = Cogging(amp, n_best, phase)
    fit = replace(
        base.fit,
        model=base.fit.model.with_effects(effect),
        values={**base.fit.values, **{f"cogging.{k}": v for k, v in effect.as_dict().items()}},
        reasons={**base.fit.reasons, "cogging.torque_nm": NOTE, "cogging.phase_rad": NOTE},
    )
    out = Fitted(("cogging",), fit, res, res.gap(), time.perf_counter() - t0)
    search.say(f"candidate cogging ({n_best:g} per turn): held-out gap {out.gap:.3g}")
    return out, _shifted(fit_res, x_fit, coef).gap()
