"""The identification pipeline behind ``pmdc-ident identify``.

:func:`identify` is a short sequence of named steps:

1. check the arguments and sort the segments: tables and steady levels go to the
   classical chain, uniformly sampled time series to the dynamic methods;
2. equation error on the discretised equations (a fast start);
3. the classical chain on staircase and coast-down data;
4. output error over all dynamic segments at once, for the seeds' linear model
   and for the same plus Coulomb friction; the Coulomb model is kept when its
   friction torque is significant (95 % interval above zero);
5. validation: one segment is held out and predicted free-running by a fit
   on the others; residual whiteness and input cross-correlation; optionally a
   parametric bootstrap that checks the covariance intervals;
6. the sweep's non-parametric frequency response against the model's;
7. the parameter estimates, intervals widened for coloured residuals.

Current-driven data (no voltage column) give the mechanical side only (J, B,
Coulomb, load torque), given Kt.

Steps 1. and 7. are here; 2.-4. in :mod:`.methods`, 5.-6. in :mod:`.validation`, and
what the steps share (the checked inputs, the report they add to) in :mod:`.state`.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from pmdc_ident.core.assumptions import register_json
from pmdc_ident.core.data import Run, Segment, check_excitation, unique_labels
from pmdc_ident.core.effects import CoulombFriction, parameter_unit
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.errors import DataError, ParameterError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimators.classical import ClassicalResult
from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE, FitResult, fit_output_error
from pmdc_ident.core.estimators.start import COULOMB_TORQUE
from pmdc_ident.core.fixed import IDENTIFY_FIXABLE, FixedValues
from pmdc_ident.core.identification.estimate import (
    ParameterEstimate,
    estimate_from_fit,
    unidentified_needed,
)
from pmdc_ident.core.identification.fit_checks import FitChecks, check_parameters
from pmdc_ident.core.identification.methods import (
    _choose,
    _classical,
    _equation_error,
    _note_choice,
    _output_error,
    minus_two_log_likelihood,
)
from pmdc_ident.core.identification.results import IdentificationResult
from pmdc_ident.core.identification.state import (
    ModelChoice,
    WarningCode,
    _added_for,
    _fixed_for,
    _Report,
    _Setup,
)
from pmdc_ident.core.identification.validation import (
    _frequency_response,
    _holdout_validation,
    _initial_state_note,
    _quantisation_note,
    _residual_validation,
)
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import Limits
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams
from pmdc_ident.core.progress import ProgressCallback, silent
from pmdc_ident.core.quality.findings import Finding
from pmdc_ident.core.quality.misfit import Refit
from pmdc_ident.core.segmentation import contiguous_pieces

__all__ = ["ModelChoice", "identify", "merge_runs", "minus_two_log_likelihood"]

TABLE_MAX_ROWS = 20
TC = COULOMB_TORQUE
_FIXED_NOTE = frozenset({ParameterNote.FIXED})


def merge_runs(runs: Sequence[Run]) -> list[Segment]:
    """All segments of several runs, labels made unique (``step_up``, ``step_up_2``...)."""
    return unique_labels(s for run in runs for s in run.segments)


def identify(
    segments: Sequence[Segment],
    *,
    fixed: Mapping[str, float] | None = None,
    closure: str | None = CLOSURE_KT_KE,
    model: str = ModelChoice.AUTO,
    holdout: bool = True,
    bootstrap: int = 0,
    frequency: bool = True,
    progress: ProgressCallback | None = None,
    sources: tuple[str, ...] = (),
    seed: int = 0,
    added_inertia: Mapping[str, float] | None = None,
    findings: Sequence[Finding] = (),
    expected_rsd: Mapping[str, float] | None = None,
) -> IdentificationResult:
    """Identify the motor from ``segments`` (see module docs).

    ``added_inertia`` maps segment labels to a known inertia added for them
    (kg*m^2); with runs with and without it, Kt is estimated instead of assumed
    equal to Ke. ``findings`` and ``expected_rsd``: the data-quality gate's on these
    data (the parameters they bias are flagged; its expectation and the fit's verdict
    become one message): the fit stage of the assumption register.
    """
    say = progress or silent
    setup, report = _setup(segments, _checked_fixed(fixed), closure, model, added_inertia)
    limits = _limits(setup.segments)
    ee = _equation_error(setup, report, say)
    classical = _classical(setup, ee, report, say)
    if not setup.dynamic:
        result = _classical_only(classical, setup.fixed, report, sources, limits)
        checked = register_json(findings, setup.segments, report.said)
        return replace(result, assumptions_checked=checked)
    fits = _output_error(setup, model, ee, classical, report, say)
    chosen = _choose(fits, model)
    fit = fits[chosen]
    _note_choice(chosen, model, fits, report)
    if holdout:
        _holdout_validation(setup, fits, chosen, report, say)
    widen = _residual_validation(fit, setup.dynamic, report)
    if bootstrap > 0:
        from pmdc_ident.core.estimators.uncertainty import parametric_bootstrap

        say(f"bootstrap: {bootstrap} refits on simulated noise")
        report.validation["bootstrap"] = parametric_bootstrap(
            fit, setup.dynamic, n=bootstrap, seed=seed, closure=setup.closure
        )
    freq = _frequency_response(setup, fit, report) if frequency else None
    parameters = _estimates(fit, chosen, widen, setup.current_mode)
    refusal = unidentified_needed(parameters, fit.free)
    if refusal is not None:  # a motor file with a guessed R, Ke or J is no answer: exit 2
        raise DataError(refusal)
    if not all(report.validation.get("residuals", {}).get("white", {}).values()):
        say("misfit-robust checks: refits without the starts, on disjoint parts, per signal")
    checked = _register_checks(
        setup, fit, chosen, widen, parameters, report, findings, expected_rsd
    )
    parameters = checked.parameters
    _one_direction_term(setup.dynamic, parameters, report)
    _quantisation_note(fit, report)
    _initial_state_note(fit, setup.dynamic, report)
    return IdentificationResult(
        sources=sources,
        model_kind="mechanical" if setup.current_mode else chosen,
        model=fit.model,
        parameters=parameters,
        assumptions=tuple(report.assumptions),
        warnings=tuple(dict.fromkeys(report.warnings)),
        methods=report.methods,
        validation=report.validation,
        noise=dict(fit.noise),
        fit=fit,
        frequency=freq,
        fit_info=_fit_info(fit, setup.dynamic),
        limits=limits,
        assumptions_checked=register_json(
            findings, setup.segments, {**report.said, **checked.said}
        ),
    )


def _register_checks(
    setup: _Setup,
    fit: FitResult,
    chosen: str,
    widen: float,
    parameters: dict[str, ParameterEstimate],
    report: _Report,
    findings: Sequence[Finding],
    expected_rsd: Mapping[str, float] | None = None,
) -> FitChecks:
    """The fit stage of the assumption register (``core/identification/fit_checks.py``)."""
    white = dict(report.validation.get("residuals", {}).get("white", {}))
    checked = check_parameters(
        parameters,
        fit=fit,
        dyn=setup.dynamic,
        refit=_refit(setup, fit),
        white=white,
        widen=widen,
        findings=findings,
        expected_rsd=expected_rsd,
        fixed=setup.fixed,
        closure=setup.closure,
    )
    report.warnings.extend(checked.warnings)
    return checked


def _refit(setup: _Setup, fit: FitResult) -> Refit:
    """The chosen model refitted on other data, signal weights or fixed values (the
    misfit-robust checks), with the setup's closure and added inertia."""

    def refit(
        segs: Sequence[Segment],
        *,
        weights: Mapping[str, float] | None = None,
        fixed: Mapping[str, float] | None = None,
        model: Model | None = None,
    ) -> FitResult:
        m = model or fit.model
        return fit_output_error(
            segs,
            m,
            fixed={**_fixed_for(setup.fixed, m), **(fixed or {})},
            closure=setup.closure,
            added_inertia=_added_for(setup.added, segs),
            weights=weights,
        )

    return refit


# ---------------------------------------------------------------------------
# 1. arguments and segments
# ---------------------------------------------------------------------------
def _checked_fixed(fixed: Mapping[str, float] | None) -> dict[str, float]:
    return dict(FixedValues(fixed or {}, known=IDENTIFY_FIXABLE))


def _setup(
    segments: Sequence[Segment],
    fixed: dict[str, float],
    closure: str | None,
    model: str,
    added_inertia: Mapping[str, float] | None,
) -> tuple[_Setup, _Report]:
    if model not in (ModelChoice.AUTO, ModelChoice.LINEAR, ModelChoice.COULOMB):
        msg = f"unknown model {model!r}; use auto, linear or coulomb"
        raise ParameterError(msg)
    if not segments:
        msg = "no data"
        raise DataError(msg)
    segs = list(segments)
    check_excitation(segs)
    current_mode = all(s.voltage is None for s in segs)
    if not current_mode and any(s.voltage is None for s in segs):
        msg = "some inputs have a voltage column and some do not; identify them separately"
        raise DataError(msg)
    added = {k: float(v) for k, v in (added_inertia or {}).items() if float(v) > 0.0}
    closure_used, assumptions = _closure(closure, fixed, added, current_mode)
    report = _Report(assumptions)
    dyn = _dynamic_segments(segs, added, report)
    return _Setup(segs, dyn, fixed, closure_used, added, current_mode), report


def _dynamic_segments(
    segs: Sequence[Segment], added: dict[str, float], report: _Report
) -> list[Segment]:
    """The long, regularly sampled segments; one with gaps in time (dropped samples)
    enters as its contiguous pieces (added inertia carried over), the gaps reported."""
    dyn: list[Segment] = []
    skipped: list[Segment] = []
    for s in segs:
        if s.n <= TABLE_MAX_ROWS:
            continue  # a table (staircase levels, coast-down points)
        if _is_dynamic(s):
            dyn.append(s)
            continue
        pieces, gaps = contiguous_pieces(s, min_samples=TABLE_MAX_ROWS + 1)
        pieces = [p for p in pieces if _is_dynamic(p)]
        if not pieces:
            skipped.append(s)
            continue
        dyn += pieces
        kept = sum(p.n for p in pieces)
        for p in pieces:
            if s.label in added:
                added[p.label] = added[s.label]
        report.warnings.append(
            f"segment {s.label!r} has {gaps} gap(s) in time ({_worst_gap([s])}): fitted as "
            f"{len(pieces)} contiguous piece(s) {', '.join(p.label for p in pieces)}, each "
            f"from its own initial state ({s.n - kept} sample(s) in pieces too short to fit "
            "left out)"
        )
    if skipped:
        report.warn(
            WarningCode.SEGMENTS_WITH_GAPS,
            "segments with gaps in time (a sample period off the median by more than 25 %), "
            f"left out of the dynamic fit: {', '.join(s.label for s in skipped)} "
            f"({_worst_gap(skipped)})",
        )
    return dyn


def _closure(
    closure: str | None,
    fixed: Mapping[str, float],
    added: Mapping[str, float],
    current_mode: bool,
) -> tuple[str | None, list[str]]:
    """The closure of the (Kt, J, B) scale actually used, and the assumptions made."""
    closure_used = closure if ("Kt" not in fixed and "J" not in fixed) else None
    if added and not current_mode:
        closure_used = None
    assumptions: list[str] = []
    if current_mode:
        if "Kt" in fixed:
            given = f"(J, B, Coulomb, load torque) given Kt = {fixed['Kt']:g} N*m/A"
        elif "J" in fixed:
            given = f"(Kt, B, Coulomb, load torque) given J = {fixed['J']:g} kg*m^2"
        else:
            msg = (
                f"current-driven data (no voltage column) show only Kt/J: {opt('fix')} Kt=... "
                f"(the torque constant) or {opt('fix')} J=... (a known rotor inertia)"
            )
            raise ParameterError(msg)
        assumptions.append(f"no voltage column: mechanical-only fit {given}")
        closure_used = None
    elif added:
        amounts = ", ".join(sorted({f"{v:g}" for v in added.values()}))
        assumptions.append(
            f"a known added inertia ({amounts} kg*m^2 on {len(added)} segment(s)) fixes the "
            "(Kt, J, B) scale: Kt is estimated, not assumed equal to Ke"
        )
    elif closure_used == CLOSURE_KT_KE:
        assumptions.append(
            "Kt = Ke (SI units, power balance): closes the scale ambiguity of (Kt, J, B); "
            f"replace with {opt('fix')} Kt=... or {opt('fix')} J=..."
        )
    elif "Kt" in fixed:
        assumptions.append(f"Kt fixed at {fixed['Kt']:g} N*m/A (replaces the Kt = Ke closure)")
    elif "J" in fixed:
        assumptions.append(f"J fixed at {fixed['J']:g} kg*m^2 (replaces the Kt = Ke closure)")
    for k, v in fixed.items():
        if k not in ("Kt", "J") or current_mode:
            assumptions.append(f"{k} fixed at {v:g} {parameter_unit(k)} (user)")
    assumptions.append(
        "voltage column is the voltage at the armature (no dead zone, brush drop or sag); "
        "an empty cell is an open armature"
    )
    return closure_used, assumptions


def _is_dynamic(s: Segment) -> bool:
    return s.n > TABLE_MAX_ROWS and regular_sampling(s)


def _worst_gap(segs: Sequence[Segment]) -> str:
    """Where the sampling is least regular, in words."""
    worst, where = 0.0, ""
    for s in segs:
        dt = np.diff(s.t)
        k = int(np.argmax(np.abs(dt - s.dt_s)))
        off = abs(dt[k] - s.dt_s) / s.dt_s
        if off > worst:
            worst = off
            where = (
                f"worst: {dt[k]:.3g} s between samples at t = {s.t[k]:.6g} s of "
                f"{s.label!r}, median period {s.dt_s:.3g} s"
            )
    return where


def regular_sampling(s: Segment, jitter: float = 0.25) -> bool:
    """Every sample period within ``jitter`` of the median: timestamp jitter is tolerated
    (the fit simulates on the median period and says so), gaps are not."""
    dt = np.diff(s.t)
    return bool(np.all(np.abs(dt - s.dt_s) <= jitter * s.dt_s))


def _limits(segs: Sequence[Segment]) -> Limits:
    def peak(arrs: list[np.ndarray]) -> float:
        vals = [
            float(np.max(np.abs(a[np.isfinite(a)])))
            for a in arrs
            if a is not None and np.isfinite(a).any()
        ]
        return max(vals) if vals else 0.0

    v = peak([s.voltage for s in segs if s.voltage is not None])
    i = peak([s.current for s in segs if s.current is not None])
    w = peak([s.speed_or_derivative() for s in segs])
    d = Limits()
    return Limits(
        voltage_max_v=v if v > 0 else d.voltage_max_v,
        current_max_a=1.5 * i if i > 0 else d.current_max_a,
        speed_max_rad_s=1.2 * w if w > 0 else d.speed_max_rad_s,
    )


# ---------------------------------------------------------------------------
# 7. the estimates
# ---------------------------------------------------------------------------
def _estimates(
    fit: FitResult, chosen: str, widen: float, current_mode: bool
) -> dict[str, ParameterEstimate]:
    params = {name: estimate_from_fit(fit, name, f"output_error_{chosen}") for name in fit.values}
    if widen > 1.0:
        from pmdc_ident.core.estimators.uncertainty import widen_interval

        for name, est in params.items():
            if est.ci95 is not None:
                params[name] = replace(
                    est,
                    ci95=widen_interval(est.value, est.ci95, widen),
                    stderr=None if est.stderr is None else est.stderr * widen,
                )
    for name in fit.fixed:
        params[name] = replace(
            params[name], reason="fixed by the user", method="fixed", notes=_FIXED_NOTE
        )
    if current_mode:
        for name in ("R", "L", "Ke"):
            params[name] = replace(
                params[name],
                identifiable=False,
                reason="no voltage in the data (value is a placeholder)",
                notes=frozenset(),
            )
    return params


def _one_direction_term(
    dyn: Sequence[Segment], params: dict[str, ParameterEstimate], report: _Report
) -> None:
    """Name the Coulomb term for what it is when the rotor turned one way only."""
    from pmdc_ident.core.estimators.equation_error import ONE_DIRECTION_NOTE, one_direction

    speeds = [s.speed_or_derivative() for s in dyn]
    if not speeds or not one_direction(np.concatenate(speeds)):
        return
    if ONE_DIRECTION_NOTE not in report.assumptions:
        report.assumptions.append(ONE_DIRECTION_NOTE)
    report.warnings[:] = [w for w in report.warnings if w != ONE_DIRECTION_NOTE]
    name = "coulomb_friction.torque_nm"
    if name in params and params[name].method != "fixed":
        params[name] = replace(
            params[name],
            reason="one term: Coulomb friction + a constant load torque (the rotor turned one "
            "way only; a run in reverse separates them)",
            notes=frozenset({ParameterNote.ONE_TERM}),
        )


def _fit_info(fit: FitResult, dyn: Sequence[Segment]) -> dict[str, Any]:
    return {
        "n_samples": fit.n_samples,
        "cost": fit.cost,
        "iterations": fit.iterations,
        "evaluations": fit.nfev,
        "converged": fit.converged,
        "message": fit.message,
        "elapsed_s": fit.elapsed_s,
        "fast_path": fit.fast_path,
        "segments": [s.label for s in dyn],
    }


def _classical_only(
    classical: ClassicalResult | None,
    fixed: Mapping[str, float],
    report: _Report,
    sources: tuple[str, ...],
    limits: Limits,
) -> IdentificationResult:
    """The result when there is no time series: the classical chain's values, with
    placeholders for what the tables cannot give."""
    if classical is None or not classical.values:
        gaps = report.coded.get(WarningCode.SEGMENTS_WITH_GAPS, [])
        if gaps:
            msg = f"no dynamic fit possible and no staircase/coast-down table: {gaps[0]}"
        else:
            msg = "no segment long enough for a dynamic fit and no staircase/coast-down table"
        raise DataError(msg)
    vals = dict(classical.values)
    vals.update(fixed)
    params: dict[str, ParameterEstimate] = {}
    placeholder = {
        "L": (
            f"no dynamic electrical data (tables only); fix it from an LCR meter ({opt('fix')} "
            "L=...)",
            vals.get("R", 1.0) * 1e-4,
        ),
        "J": ("no coast-down in the data", 1e-3),
        "R": ("no staircase", 1.0),
    }
    for name in PARAMETER_NAMES + (TC,):
        if name in vals:
            assumed = name == "Kt" and name not in fixed
            params[name] = ParameterEstimate(
                name,
                float(vals[name]),
                None if name in fixed or assumed else classical.ci95.get(name),
                parameter_unit(name),
                not assumed,
                stderr=None if name in fixed or assumed else classical.stderr.get(name),
                reason="fixed by the user"
                if name in fixed
                else (
                    "assumed equal to Ke (closure Kt = Ke in SI units): not measured by these "
                    f"data; {opt('fix')} Kt=... holds a value you know"
                    if name == "Kt"
                    else ""
                ),
                method="fixed" if name in fixed else "classical",
                notes=_FIXED_NOTE
                if name in fixed
                else frozenset({ParameterNote.ASSUMED} if name == "Kt" else ()),
            )
        else:
            reason, value = placeholder.get(name, ("not in the data", 1.0))
            params[name] = ParameterEstimate(
                name, value, None, parameter_unit(name), False, reason=reason, method="placeholder"
            )
            report.warnings.append(f"{name}: {reason} (written as a placeholder {value:.3g})")
    p = MotorParams(**{n: params[n].value for n in PARAMETER_NAMES})
    tc = params[TC].value
    m = Model(p, (CoulombFriction(max(tc, 0.0)),) if tc > 0 else ())
    return IdentificationResult(
        sources=sources,
        model_kind="classical",
        model=m,
        parameters=params,
        assumptions=tuple(report.assumptions),
        warnings=tuple(dict.fromkeys(report.warnings)),
        methods=report.methods,
        validation={},
        noise={},
        limits=limits,
    )
