"""Steps 2.-4. of :func:`~pmdc_ident.core.identification.identify.identify`: equation
error, the classical chain, output error for the linear and the Coulomb model, and the
choice between them by likelihood ratio."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

from pmdc_ident.core.data import TestKind
from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.errors import DataError, PmdcError
from pmdc_ident.core.estimators.classical import ClassicalResult, CoastFit, classical_chain
from pmdc_ident.core.estimators.equation_error import (
    EquationErrorResult,
    fit_equation_error,
    fit_mechanical_equation_error,
)
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.estimators.start import (
    COULOMB_TORQUE,
    start_model,
    start_values,
)
from pmdc_ident.core.identification.state import ModelChoice, WarningCode, _Report, _Setup
from pmdc_ident.core.model import Model
from pmdc_ident.core.progress import ProgressCallback

__all__ = ["minus_two_log_likelihood"]

TC = COULOMB_TORQUE


# ---------------------------------------------------------------------------
# 2.-3. equation error and the classical chain
# ---------------------------------------------------------------------------
def _equation_error(
    setup: _Setup, report: _Report, say: ProgressCallback
) -> EquationErrorResult | None:
    """A fast start; also gives the classical chain an R."""
    if not setup.dynamic:
        return None
    say("equation error (discretised equations)")
    try:
        if setup.current_mode:
            kt = setup.fixed.get("Kt")
            j = setup.fixed.get("J") if kt is None else None
            ee = fit_mechanical_equation_error(setup.dynamic, Kt=kt, J=j)
        else:
            j_known = setup.fixed.get("J") if setup.closure is None else None
            ee = fit_equation_error(setup.dynamic, Kt=setup.fixed.get("Kt"), J=j_known)
    except DataError as exc:
        if "no excitation" in str(exc):
            raise
        report.warnings.append(f"equation error skipped: {exc}")
        return None
    report.methods["equation_error"] = {"values": dict(ee.values), "method": ee.method}
    report.warnings.extend(ee.notes)
    return ee


def _classical(
    setup: _Setup, ee: EquationErrorResult | None, report: _Report, say: ProgressCallback
) -> ClassicalResult | None:
    """The classical chain on staircase / coast-down (tables or time series)."""
    kinds = (TestKind.STAIRCASE, TestKind.COAST)
    if setup.current_mode or not any(s.kind in kinds for s in setup.segments):
        return None
    say("classical chain (staircase, coast-down)")
    cfix = dict(setup.fixed)
    if "R" not in cfix and ee is not None and "R" in ee.values:
        # no multimeter value: the staircase alone pins R poorly
        cfix["R"] = ee.values["R"]
    try:
        classical = classical_chain(setup.segments, fixed=cfix)
    except DataError as exc:
        report.warnings.append(f"classical chain skipped: {exc}")
        return None
    from pmdc_ident.core.estimators.classical import staircase_levels

    for s in setup.segments:
        if s.kind is TestKind.STAIRCASE and len(levels := staircase_levels(s)) > 1:
            line = (
                f"staircase segment {s.label!r} holds {len(levels)} voltage levels: each is "
                "one steady level of the classical chain"
            )
            report.assumptions.append(line)
            report.said["staircase-levels"] = line
    if "R" not in setup.fixed and "R" in cfix:
        note = (
            f"classical: R = {cfix['R']:.4g} ohm taken from the equation-error "
            "fit (no multimeter value given)"
        )
        classical = replace(classical, notes=(note, *classical.notes))
    report.methods["classical"] = {
        "values": dict(classical.values),
        "ci95": {k: list(v) if v else None for k, v in classical.ci95.items()},
        "notes": list(classical.notes),
    }
    if classical.coast is not None:
        report.methods["classical"]["coast"] = _coast_json(classical.coast)
    return classical


def _coast_json(c: CoastFit) -> dict[str, Any]:
    return {
        "J": c.J,
        "J_ci95": list(c.J_ci95),
        "J_from_Tc_shape": c.J_from_Tc,
        "J_from_B_shape": c.J_from_B,
        "average_slope_rad_s2": c.average_slope_rad_s2,
        "J_one_average_slope": (c.Tc + c.B * c.w0_rad_s) / c.average_slope_rad_s2
        if c.average_slope_rad_s2 > 0
        else None,
        "rms_speed_rad_s": c.rms_speed_rad_s,
    }


# ---------------------------------------------------------------------------
# 4. output error, linear and Coulomb
# ---------------------------------------------------------------------------
def _output_error(
    setup: _Setup,
    model: str,
    ee: EquationErrorResult | None,
    classical: ClassicalResult | None,
    report: _Report,
    say: ProgressCallback,
) -> dict[str, FitResult]:
    start = start_values(
        classical.values if classical is not None else {},
        ee.values if ee is not None else {},
        setup.dynamic,
        setup.fixed,
        setup.current_mode,
    )
    want = [ModelChoice.LINEAR, ModelChoice.COULOMB] if model == ModelChoice.AUTO else [model]
    fits: dict[str, FitResult] = {}
    for kind in map(str, want):
        m0 = start_model(start, kind == ModelChoice.COULOMB, setup.current_mode, setup.fixed)
        say(f"output error, {kind} model")
        try:
            fits[kind] = setup.fit(
                setup.dynamic,
                m0,
                progress=lambda it, cost, k=kind: say(f"  {k}: iteration {it}, cost {cost:.6g}"),
            )
        except PmdcError as exc:
            report.warn(WarningCode.OUTPUT_ERROR_FAILED, f"output error ({kind}) failed: {exc}")
    if not fits:
        why = "; ".join(report.coded.get(WarningCode.OUTPUT_ERROR_FAILED, []))
        msg = f"the output-error fit failed on every model: {why}"
        raise DataError(msg)
    _restart_coulomb(setup, fits, say)
    for kind, f in fits.items():
        report.methods[f"output_error_{kind}"] = {
            "values": dict(f.values),
            "ci95": {k: list(v) if v else None for k, v in f.ci95.items()},
            "rms": dict(f.rms),
            "cost": f.cost,
            "minus_2_log_likelihood": minus_two_log_likelihood(f),
            "iterations": f.iterations,
            "converged": f.converged,
        }
    return fits


def _restart_coulomb(setup: _Setup, fits: dict[str, FitResult], say: ProgressCallback) -> None:
    """The Coulomb model contains the linear one (Tc = 0): a worse fit is a poor local
    minimum; restart it from the linear solution and keep the better of the two."""
    lin, cou = fits.get(ModelChoice.LINEAR), fits.get(ModelChoice.COULOMB)
    if lin is None or cou is None:
        return
    if minus_two_log_likelihood(cou) <= minus_two_log_likelihood(lin) + 1e-6:
        return
    say("output error, coulomb model restarted from the linear fit")
    m0 = Model(lin.model.params, (CoulombFriction(1e-6 * lin.model.params.Kt),))
    again = setup.fit(setup.dynamic, m0)
    if minus_two_log_likelihood(again) < minus_two_log_likelihood(cou):
        fits[ModelChoice.COULOMB] = again


def minus_two_log_likelihood(fit: FitResult) -> float:
    """-2 log L of Gaussian white residuals with per-signal variances set to their ML value."""
    n_per = fit.n_samples
    return float(sum(n_per * 2.0 * math.log(max(r, 1e-300)) for r in fit.rms.values()))


def _choose(fits: Mapping[str, FitResult], model: str) -> str:
    """Coulomb when its torque's interval lies above zero and the likelihood-ratio test
    (one added parameter, 95 %: -2 log L falls by more than 3.84) accepts it."""
    if model != ModelChoice.AUTO:
        return model
    c = fits.get(ModelChoice.COULOMB)
    lin = fits.get(ModelChoice.LINEAR)
    if c is None:
        return ModelChoice.LINEAR
    if lin is None:
        return ModelChoice.COULOMB
    ci = c.ci95.get(TC)
    better = minus_two_log_likelihood(lin) - minus_two_log_likelihood(c) > 3.84
    if ci is not None and ci[0] > 0 and c.identifiable.get(TC, False) and better:
        return ModelChoice.COULOMB
    return ModelChoice.LINEAR


def _note_choice(chosen: str, model: str, fits: Mapping[str, FitResult], report: _Report) -> None:
    if chosen == ModelChoice.COULOMB:
        report.assumptions.append(
            "friction is Coulomb plus viscous (Coulomb torque significant: its 95 % interval "
            "lies above zero and the likelihood-ratio test prefers it)"
        )
    elif model == ModelChoice.AUTO and ModelChoice.COULOMB in fits:
        report.assumptions.append("friction is viscous only (no significant Coulomb torque found)")
    warnings = report.warnings
    warnings.extend(w for w in fits[chosen].warnings if w not in warnings)
