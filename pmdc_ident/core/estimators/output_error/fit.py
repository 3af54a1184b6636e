"""``fit_output_error``: the fit as a short sequence of named steps.

1. prepare the segments (inputs, outputs, free initial states, added inertia);
2. pin the fixed values and decide the Kt = Ke closure;
3. choose the free parameters;
4. solve by Levenberg-Marquardt, then re-weight by the residual noise and refit;
5. build the result (covariance, intervals, identifiability) and flag what the data
   cannot resolve (the (Kt, J, B) scale, an inductance faster than the sampling).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.estimators.output_error.parameters import (
    at_limit,
    build_model,
    is_fitted_field,
    model_values,
    parameter_info,
)
from pmdc_ident.core.estimators.output_error.problem import Problem
from pmdc_ident.core.estimators.output_error.results import FitResult, build_result
from pmdc_ident.core.estimators.output_error.segments import (
    SIGNALS,
    PreparedSegment,
    initial_noise,
    prepare_segments,
)
from pmdc_ident.core.estimators.output_error.simulators import FAST_EFFECTS
from pmdc_ident.core.estimators.solver import LMSettings, LMState, levenberg_marquardt
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import PARAMETER_NAMES
from pmdc_ident.core.quantisation import record_steps

__all__ = ["CLOSURE_KT_KE", "fit_output_error"]

FloatArray = NDArray[np.float64]
CLOSURE_KT_KE = "Kt=Ke"
_ELECTRICAL = ("R", "L", "Ke", "Kt")


def fit_output_error(
    segments: Sequence[Segment],
    model: Model,
    *,
    free: Sequence[str] | None = None,
    fixed: Mapping[str, float] | None = None,
    closure: str | None = CLOSURE_KT_KE,
    weights: Mapping[str, float] | None = None,
    max_nfev: int = 200,
    progress: Callable[[int, float], None] | None = None,
    refine_noise: bool = True,
    check_inductance: bool = True,
    added_inertia: Mapping[str, float] | None = None,
) -> FitResult:
    """Fit ``model`` to ``segments`` by output error (see the package docs).

    ``free`` lists the parameters to fit (default: all identifiable ones);
    ``fixed`` pins values (``{"L": 3e-4}``); ``closure`` ``"Kt=Ke"`` ties Kt to
    Ke unless Kt or J is fixed (``None``: no closure). ``weights`` multiplies
    the per-signal residual weights (``{"current": 0.5}``). ``progress(it,
    cost)`` is called after every iteration. ``added_inertia`` maps segment
    labels to a known inertia added for them (kg*m^2): runs with and without it
    fix the (Kt, J, B) scale, so the Kt = Ke closure is dropped.
    """
    t_start = time.perf_counter()
    warnings: list[str] = []
    segs = prepare_segments(segments, warnings, added_inertia)
    current_mode = segs[0].voltage is None
    fixed = {str(k): float(v) for k, v in (fixed or {}).items()}
    if closure not in (None, CLOSURE_KT_KE):
        msg = f"unknown closure {closure!r}; use {CLOSURE_KT_KE!r} or None"
        raise ParameterError(msg)
    values = _pinned_values(model, fixed)
    has_added = any(ps.dJ > 0 for ps in segs)
    tie_kt, reasons = _closure(closure, fixed, has_added, current_mode)
    if tie_kt:
        values["Kt"] = values["Ke"]
    free_names = _free_names(values, fixed, free, tie_kt, current_mode)
    if not tie_kt and {"Kt", "J", "B"} <= set(free_names):
        warnings.append(
            "Kt, J and B are all free without a closure: only their ratios are identifiable"
        )
    _check_weights(weights)
    fast = set(model.effect_names) <= FAST_EFFECTS
    base = build_model(model, values)
    # the first weights: an encoder's (any quantised signal's) step over the record, the
    # gate's rule, floors its noise at step / sqrt(12); the refit then weights by the
    # residuals (a floor there overweights current when a rotor rests in one count)
    fitted = [n for n in SIGNALS if any(SIGNALS[idx] == n for ps in segs for idx, _ in ps.outputs)]
    steps = {k: q.step for k, q in record_steps([ps.seg for ps in segs], fitted).items()}
    noise = initial_noise(segs, steps)
    prob = Problem(segs, base, values, free_names, tie_kt, fast, noise, weights or {})
    z, lm = _solve(prob, max_nfev, progress, refine_noise)
    result = build_result(
        prob, z, lm, reasons, fixed, closure if tie_kt else None, warnings, t_start
    )
    result = replace(result, quantisation_steps=steps)
    result = _flag_scale_ambiguity(result)
    if check_inductance and not current_mode:
        result = _flag_from_bound(result, segs, t_start)
    return result


def _pinned_values(model: Model, fixed: Mapping[str, float]) -> dict[str, float]:
    """Every parameter of ``model`` by name, with the ``fixed`` ones checked and pinned."""
    values = model_values(model)
    for name, v in fixed.items():
        if name not in values:
            msg = f"cannot fix {name!r}: not a parameter of this model (known: {list(values)})"
            raise ParameterError(msg)
        info = parameter_info(name)
        if not (info.lower <= v <= info.upper) or (info.log and v <= 0.0):
            msg = f"fixed value {name}={v:g} is outside its range"
            raise ParameterError(msg)
        values[name] = v
    return values


def _closure(
    closure: str | None, fixed: Mapping[str, float], has_added: bool, current_mode: bool
) -> tuple[bool, dict[str, str]]:
    """Whether Kt is tied to Ke, and the reasons for what the data cannot give."""
    reasons: dict[str, str] = {}
    tie_kt = closure == CLOSURE_KT_KE and "Kt" not in fixed and "J" not in fixed
    if has_added:
        # a known added inertia on some segments fixes the (Kt, J, B) scale
        tie_kt = False
    if current_mode:
        tie_kt = False
        for n in ("R", "L", "Ke"):
            reasons[n] = "no voltage in the data: electrical parameters are not observable"
        if "Kt" not in fixed and "J" not in fixed:
            reasons["Kt"] = "given (current-driven data fix the scale through Kt or J)"
    return tie_kt, reasons


def _free_names(
    values: Mapping[str, float],
    fixed: Mapping[str, float],
    free: Sequence[str] | None,
    tie_kt: bool,
    current_mode: bool,
) -> list[str]:
    """The parameters to fit: ``free`` (checked) or every fittable one."""
    if free is None:
        # current-driven data: Kt is fitted when a known J fixes the scale instead
        unseen = ("R", "L", "Ke") if "J" in fixed else _ELECTRICAL
        return [
            n
            for n in values
            if n not in fixed
            and not (current_mode and n in unseen)
            and not (tie_kt and n == "Kt")
            and (n in PARAMETER_NAMES or (is_fitted_field(n) and not at_limit(n, values[n])))
        ]
    names = []
    for n in free:
        if n not in values:
            msg = f"cannot fit {n!r}: not a parameter of this model (known: {list(values)})"
            raise ParameterError(msg)
        if n in fixed or (tie_kt and n == "Kt"):
            continue
        names.append(n)
    return names


def _check_weights(weights: Mapping[str, float] | None) -> None:
    for k in weights or {}:
        if k not in SIGNALS:
            msg = f"weights keys must be among {SIGNALS}, got {k!r}"
            raise ParameterError(msg)


_START_DIVERGES = (
    "the fit cannot start: simulating the start model on these data diverges "
    "(are the signals in SI units, and is the voltage the armature's?)"
)


def _solve(
    prob: Problem,
    max_nfev: int,
    progress: Callable[[int, float], None] | None,
    refine_noise: bool,
) -> tuple[FloatArray, LMState]:
    """Levenberg-Marquardt from the start; with ``refine_noise``, refit once re-weighted.

    Maximum likelihood with unknown noise levels: reweight by the residual RMS and
    refit, unless the weights barely change (then the optimum does not move beyond a
    small fraction of its standard error).
    """
    settings = LMSettings(max_nfev=max_nfev, start_error=_START_DIVERGES)
    z, lm = levenberg_marquardt(prob, prob.z0(), settings, progress)
    if not refine_noise:
        return z, lm
    new_noise = prob.residual_noise(z)
    moved = any(not 0.9 < new_noise[k] / prob.noise[k] < 1.1 for k in new_noise)
    prob.noise = new_noise
    if moved:
        z, lm2 = levenberg_marquardt(prob, z, settings, progress)
        lm = LMState(lm2.cost, lm.nfev + lm2.nfev, lm.it + lm2.it, lm2.converged, lm2.message)
    return z, lm


def _flag_scale_ambiguity(result: FitResult) -> FitResult:
    scale = ("Kt", "J", "B")
    if not all(n in result.free and not result.identifiable[n] for n in scale):
        return result
    why = (
        "scale ambiguity: voltage, current and speed fix (Kt, J, B) only up to a common "
        "factor; use the Kt = Ke closure, fix Kt or J, or add a known inertia"
    )
    notes = {k: v for k, v in result.notes.items() if k not in scale}
    return replace(result, reasons={**result.reasons, **dict.fromkeys(scale, why)}, notes=notes)


def _flag_from_bound(res: FitResult, segs: Sequence[PreparedSegment], t_start: float) -> FitResult:
    """Identifiability from the fit's own information matrix (the Cramer-Rao bound on
    these data): relative sd > 50 % not identifiable, 10-50 % weakly, each reason
    saying what would pin the parameter down; for L the sample rate at which its
    bound drops below 10 %. L/R below the sample period alone is no longer a flag:
    the first sample after each voltage step may still pin L (a note says so)."""
    from pmdc_ident.core.quality.information import WEAK, advice_for

    dt_min = min(s.dt for s in segs)
    tau_e = res.values["L"] / res.values["R"] if "L" in res.values else math.inf
    reasons, identifiable = dict(res.reasons), dict(res.identifiable)
    ci95, stderr, warnings = dict(res.ci95), dict(res.stderr), list(res.warnings)
    notes = dict(res.notes)
    for name in res.free:
        se = res.stderr.get(name)
        value = abs(res.values.get(name, math.nan))
        rel = se / value if se is not None and value > 0 else math.inf
        hint = advice_for(name, rel, tau_e=tau_e, dt_s=dt_min)
        if not identifiable.get(name, True):
            reasons[name] = f"{reasons.get(name, 'not identifiable')}; {hint}"
            if name == "L":
                ci95[name], stderr[name] = None, None
                warnings.append(f"L: {reasons[name]}")
        elif rel > WEAK:
            reasons[name] = f"weakly identifiable: relative sd {rel:.0%} on these data; {hint}"
            notes[name] = frozenset({ParameterNote.WEAKLY_IDENTIFIABLE})
        elif name == "L" and tau_e < dt_min:
            notes[name] = frozenset({ParameterNote.FAST_ELECTRICAL})
            reasons[name] = (
                f"L/R ~ {tau_e * 1e3:.2g} ms is below the sample period {dt_min * 1e3:.3g} ms: "
                "L shows only in the current's first sample after a step and its lag behind "
                f"the back-EMF (relative sd {rel:.2%} on these data); a delay or a filtered "
                "current sensor would bias it "
                "(`pmdc-ident check` looks for both), an LCR meter confirms it"
            )
    return replace(
        res,
        reasons=reasons,
        notes=notes,
        identifiable=identifiable,
        ci95=ci95,
        stderr=stderr,
        warnings=tuple(warnings),
        elapsed_s=time.perf_counter() - t_start,
    )
