"""Start values for the output-error fit: one equation-error estimator for both
``identify`` and ``diagnose``.

:func:`equation_error_start` solves the motor's equations by least squares on the
samples themselves: ``V = R i + Ke w`` over the driven samples (L di/dt is
neglected) and ``J dw/dt + B w = Kt i`` over samples with a measured current (or an
open armature, i = 0). It is biased by every unmodelled effect, which is fine for a
start: the output-error fit refines it.

:func:`start_values` is what ``identify`` starts from: the classical chain's values,
then the discretised equation-error fit's, and :func:`equation_error_start` for R and
Ke when neither gave them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.effects import CoulombFriction, LoadTorque
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

__all__ = ["COULOMB_TORQUE", "LOAD_TORQUE", "equation_error_start", "start_model", "start_values"]

COULOMB_TORQUE = "coulomb_friction.torque_nm"
LOAD_TORQUE = "load_torque.torque_nm"


def _smooth(x: np.ndarray, width: int) -> np.ndarray:
    if width <= 1 or x.size <= width:
        return x
    return np.convolve(x, np.ones(width) / width, mode="same")


def _small_b(j: float, dt: float) -> float:
    """A start for B where the data gave none: a damping time J/B of 10^4 samples
    (at least 1000 s / 1 s), far slower than any test, that the fit can move either way."""
    return 1e-3 * j / max(10 * dt, 1e-3)


def equation_error_start(
    segments: Sequence[Segment], fixed: Mapping[str, float], *, smooth: bool = False
) -> MotorParams:
    """Equation-error starting values (biased by unmodelled effects, refined later).

    ``smooth``: ``V = R i + Ke w`` on the moving averages (over a fiftieth of each
    segment) of all three signals, not on the samples. A speed differentiated from a
    coarse encoder is mostly noise at a crawl (a count every few samples), and noise in
    a regressor pulls its coefficient towards zero: on a geared scooter motor's crawls
    (508 counts per turn, 2 kHz) Ke came out 0.17 against 0.73 V s/rad and the fit
    from there stopped in a misfit 30x the truth's cost; smoothed, 0.71. The average
    also blurs the transients (L di/dt is neglected either way), so this is a second
    start (:func:`pmdc_ident.core.diagnosis.pipeline._baseline` fits both)."""
    rows_e, ys_e, rows_m, ys_m = [], [], [], []
    for s in segments:
        w = s.speed_or_derivative()
        width = max(1, s.n // 50)
        ws = _smooth(w, width)
        dw = np.gradient(ws, s.t)
        is_open = s.open_mask
        if s.current is not None and s.voltage is not None:
            drive = ~is_open
            i_e, w_e, v_e = s.current, w, s.voltage
            if smooth and width > 1:
                # windows that touch an open sample are left out (no voltage there)
                drive = drive & (_smooth(is_open.astype(float), width) == 0.0)
                i_e, w_e = _smooth(s.current, width), ws
                v_e = _smooth(np.where(is_open, 0.0, s.voltage), width)
            rows_e.append(np.column_stack([i_e[drive], w_e[drive]]))
            ys_e.append(v_e[drive])
        i = np.zeros(s.n) if s.current is None else np.where(is_open, 0.0, s.current)
        if s.current is not None or is_open.all():
            rows_m.append(np.column_stack([dw, ws, i]))
            ys_m.append(np.zeros(s.n))
    r_guess, ke_guess = 1.0, 0.05
    if rows_e:
        a = np.concatenate(rows_e)
        y = np.concatenate(ys_e)
        ok = np.isfinite(y)
        if ok.sum() >= 2:
            (r_guess, ke_guess), *_ = np.linalg.lstsq(a[ok], y[ok], rcond=None)
    r = float(fixed.get("R", r_guess if r_guess > 0 else 1.0))
    ke = float(fixed.get("Ke", ke_guess if ke_guess > 0 else 0.05))
    kt = float(fixed.get("Kt", ke))
    j, b = math.nan, math.nan
    if rows_m:
        m = np.concatenate(rows_m)
        # J dw/dt + B w = Kt i
        sol, *_ = np.linalg.lstsq(m[:, :2], kt * m[:, 2], rcond=None)
        j, b = float(sol[0]), float(sol[1])
    if not (math.isfinite(j) and j > 0):
        j = ke * kt * 0.1 / r  # tau_m = 0.1 s
    dt = float(np.median([s.dt_s for s in segments]))
    if not (math.isfinite(b) and b > 0):
        # B is fitted in log scale: a start of 0 would hold it at 0 for good (a noisy
        # equation-error B below zero then made Ke absorb the viscous torque and the
        # diagnosis name a friction effect on a clean motor)
        b = _small_b(j, dt)
    values = {"R": r, "L": r * dt, "Ke": ke, "Kt": kt, "J": j, "B": b}
    values.update({k: float(v) for k, v in fixed.items()})
    return MotorParams(**values)


def start_values(
    classical: Mapping[str, float],
    equation_error: Mapping[str, float],
    dyn: Sequence[Segment],
    fixed: Mapping[str, float],
    current_mode: bool,
) -> dict[str, float]:
    """Start values for ``identify``'s fits: the classical chain's values, overridden by
    the discretised equation-error fit's finite ones, then the user's ``fixed`` values;
    R and Ke from :func:`equation_error_start` when those two did not give both."""
    vals: dict[str, float] = dict(classical)
    vals.update({k: v for k, v in equation_error.items() if math.isfinite(v)})
    dt = min(s.dt_s for s in dyn)
    if not current_mode and all(s.current is None for s in dyn):
        for k, v in _speed_response_start(dyn, {**vals, **fixed}).items():
            vals.setdefault(k, v)
    if ("R" not in vals or "Ke" not in vals) and not current_mode:
        p = equation_error_start(dyn, {})
        vals.update({"R": p.R, "Ke": p.Ke})
    if "L" not in vals:
        vals["L"] = vals.get("R", 1.0) * dt / 4.0  # below the sample period: flagged later
    vals.update(fixed)
    if "Kt" not in vals:
        vals["Kt"] = vals.get("Ke", 1.0)
    if "J" not in vals:
        vals["J"] = vals["Kt"] * 0.1
    vals.setdefault("B", 0.0)
    vals.setdefault("R", 1.0)
    vals.setdefault("Ke", vals["Kt"])
    # sanitize for a valid start
    for k in ("R", "L", "Ke", "Kt", "J"):
        if not (vals[k] > 0 and math.isfinite(vals[k])):
            vals[k] = 1.0
    vals["B"] = vals["B"] if vals["B"] > 0 else _small_b(vals["J"], dt)
    vals[COULOMB_TORQUE] = max(vals.get(COULOMB_TORQUE, 0.0), 0.0)
    return vals


def _speed_response_start(dyn: Sequence[Segment], known: Mapping[str, float]) -> dict[str, float]:
    """No current measured: R (as known, else 1 ohm), Ke and J from voltage -> speed.

    Its gain is ``Ke / (R B + Ke Kt)`` and its time constant ``R J / (R B + Ke Kt)``;
    with B neglected, Ke = 1 / gain and J = tau Ke Kt / R. (J's generic start, 0.1 Kt,
    was 250x off on a small motor, and the fit then settled on L -> 0 with J 5.6 % low.)
    """
    from pmdc_ident.core.quality.regress import voltage_speed_response

    response = voltage_speed_response(dyn)
    if response is None:
        return {}
    gain, tau = response
    r = float(known.get("R", 1.0))
    ke = float(known.get("Ke", known.get("Kt", 1.0 / gain)))
    kt = float(known.get("Kt", ke))
    return {"R": r, "Ke": ke, "J": tau * ke * kt / r}


def start_model(
    vals: Mapping[str, float], coulomb: bool, current_mode: bool, fixed: Mapping[str, float]
) -> Model:
    """The model a fit starts from: the linear model, plus Coulomb friction when asked
    for (or fixed), plus a load torque on current-driven data (or when fixed)."""
    p = MotorParams(**{n: vals[n] for n in PARAMETER_NAMES})
    effects = []
    if coulomb or COULOMB_TORQUE in fixed:
        tc = vals.get(COULOMB_TORQUE, 0.0)
        if tc <= 0 and COULOMB_TORQUE not in fixed:
            # a small positive start (1 mA worth of torque)
            tc = 1e-3 * p.Kt
        effects.append(CoulombFriction(tc))
    if current_mode or LOAD_TORQUE in fixed:
        # a load torque is fitted on current-driven data, or held where the user knows it
        effects.append(LoadTorque(float(vals.get(LOAD_TORQUE, 0.0))))
    return Model(p, tuple(effects))
