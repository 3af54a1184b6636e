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
"""

from __future__ import annotations

import enum
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pmdc_ident.core.assumptions import register_json
from pmdc_ident.core.data import Run, Segment, TestKind, check_excitation, unique_labels
from pmdc_ident.core.effects import CoulombFriction, parameter_unit
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.errors import DataError, ParameterError, PmdcError
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimate import ParameterEstimate, estimate_from_fit, unidentified_needed
from pmdc_ident.core.estimators.classical import ClassicalResult, CoastFit, classical_chain
from pmdc_ident.core.estimators.equation_error import (
    EquationErrorResult,
    fit_equation_error,
    fit_mechanical_equation_error,
)
from pmdc_ident.core.estimators.frequency import FrequencyResponse, estimate_frequency_response
from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE, FitResult, fit_output_error
from pmdc_ident.core.estimators.start import (
    COULOMB_TORQUE,
    start_model,
    start_values,
)
from pmdc_ident.core.estimators.validation import holdout_score, residual_tests
from pmdc_ident.core.fixed import IDENTIFY_FIXABLE, FixedValues
from pmdc_ident.core.model import Model, simulate_linear
from pmdc_ident.core.motors import Limits
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams
from pmdc_ident.core.progress import ProgressCallback, silent
from pmdc_ident.core.quality.findings import Finding
from pmdc_ident.core.quality.fit_checks import FitChecks, check_parameters
from pmdc_ident.core.quality.misfit import Refit
from pmdc_ident.core.results import IdentificationResult
from pmdc_ident.core.segmentation import contiguous_pieces

__all__ = ["ModelChoice", "identify", "merge_runs", "minus_two_log_likelihood"]

TABLE_MAX_ROWS = 20
TC = COULOMB_TORQUE
_FIXED_NOTE = frozenset({ParameterNote.FIXED})


class ModelChoice(enum.StrEnum):
    """Which model the output-error fit reports (auto: Coulomb when significant)."""

    AUTO = "auto"
    LINEAR = "linear"
    COULOMB = "coulomb"


def merge_runs(runs: Sequence[Run]) -> list[Segment]:
    """All segments of several runs, labels made unique (``step_up``, ``step_up_2``...)."""
    return unique_labels(s for run in runs for s in run.segments)


@dataclass(frozen=True)
class _Setup:
    """The checked inputs of one identification."""

    segments: list[Segment]
    dynamic: list[Segment]  # long, regularly sampled: for the dynamic methods
    fixed: dict[str, float]
    closure: str | None  # the closure actually used
    added: dict[str, float]  # known added inertia by segment label, kg*m^2
    current_mode: bool  # no voltage column: mechanical side only

    def fit(self, segs: Sequence[Segment], model: Model, **kwargs: Any) -> FitResult:
        """The output-error fit of ``model`` on ``segs`` with this setup's fixed values,
        closure and added inertia."""
        return fit_output_error(
            segs,
            model,
            fixed=_fixed_for(self.fixed, model),
            closure=self.closure,
            added_inertia=_added_for(self.added, segs),
            **kwargs,
        )


class WarningCode(enum.Enum):
    """Warnings a later step of :func:`identify` looks for (by code, not by its text)."""

    OUTPUT_ERROR_FAILED = "output-error-failed"  # a model's output-error fit failed
    SEGMENTS_WITH_GAPS = "segments-with-gaps"  # segments left out for gaps in time


@dataclass
class _Report:
    """What the steps add to the result as they go."""

    assumptions: list[str]
    warnings: list[str] = field(default_factory=list)
    methods: dict[str, dict[str, Any]] = field(default_factory=dict)
    validation: dict[str, Any] = field(default_factory=dict)
    said: dict[str, str] = field(default_factory=dict)  # register entry -> what was done
    coded: dict[WarningCode, list[str]] = field(default_factory=dict)

    def warn(self, code: WarningCode, text: str) -> None:
        """A warning of the result that a later step may look for by ``code``."""
        self.warnings.append(text)
        self.coded.setdefault(code, []).append(text)


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
    """The fit stage of the assumption register (``core/quality/fit_checks.py``)."""
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


# ---------------------------------------------------------------------------
# 5.-6. validation and frequency response
# ---------------------------------------------------------------------------
def _quantisation_note(fit: FitResult, report: _Report) -> None:
    """Each quantised signal the fit used, and the noise its step holds it at."""
    units = {"current": "A", "speed": "rad/s", "position": "rad"}
    for name, step in fit.quantisation_steps.items():
        enc = f" (an encoder of {2 * math.pi / step:.6g} counts/rev)" if name == "position" else ""
        report.assumptions.append(
            f"{name} is quantised in steps of {step:.6g} {units[name]}{enc}: the fit's "
            f"noise model starts from no less than step / sqrt(12) = "
            f"{step / math.sqrt(12):.3g} {units[name]}, then takes the residuals' level"
        )


def _initial_state_note(fit: FitResult, dyn: Sequence[Segment], report: _Report) -> None:
    """A record that starts with the voltage already on: its initial state is estimated."""
    for s in dyn:
        if s.voltage is None or (s.history_voltage is not None and s.history_voltage.size):
            continue
        v0 = float(s.voltage[0])
        x0 = fit.initial_states.get(s.label)
        if x0 is None or not math.isfinite(v0) or v0 == 0.0:
            continue
        report.assumptions.append(
            f"{s.label} starts with {v0:.4g} V already on and nothing recorded before it: its "
            f"initial current and speed are estimated with the parameters (i0 = {x0[0]:.4g} A, "
            f"w0 = {x0[1]:.4g} rad/s), not assumed at rest"
        )


def _holdout_segments(dyn: Sequence[Segment]) -> list[Segment]:
    """One segment to predict: a step (prefer step_down), else the last non-sweep one."""
    if len(dyn) < 2:
        return []
    steps = [s for s in dyn if s.kind is TestKind.STEP]
    for s in steps:
        if "down" in s.label:
            return [s]
    if len(steps) >= 2:
        return [steps[-1]]
    others = [s for s in dyn if s.kind is not TestKind.SWEEP]
    return [others[-1]] if len(others) >= 2 else [dyn[-1]]


def _holdout_validation(
    setup: _Setup,
    fits: Mapping[str, FitResult],
    chosen: str,
    report: _Report,
    say: ProgressCallback,
) -> None:
    """Refit the chosen model without one segment and predict that segment free-running.

    Only the chosen model: a refit of the other one (a second output-error fit, a
    sixth of ``identify``'s time) changed nothing that is reported or decided."""
    held = _holdout_segments(setup.dynamic)
    if not held:
        report.warnings.append("only one dynamic segment: no held-out validation possible")
        return
    rest = [s for s in setup.dynamic if s not in held]
    say(f"validation: refit without {', '.join(s.label for s in held)}")
    for kind, f in fits.items():
        if kind != chosen:
            continue
        try:
            f_rest = setup.fit(rest, f.model)
        except DataError as exc:
            report.warnings.append(f"hold-out refit ({kind}) failed: {exc}")
            continue
        score = holdout_score(f_rest, held)
        report.methods[f"output_error_{kind}"]["holdout_rms"] = score.rms
        report.methods[f"output_error_{kind}"]["holdout_nrmse"] = score.nrmse
        if kind == chosen:
            report.validation["holdout"] = {
                "labels": list(score.labels),
                "rms": score.rms,
                "nrmse": score.nrmse,
                "model": kind,
            }


def _residual_validation(fit: FitResult, dyn: Sequence[Segment], report: _Report) -> float:
    """Residual whiteness and independence of the input; returns the factor by which the
    intervals widen for coloured residuals (1 when they are white)."""
    tests = residual_tests(fit, dyn)
    residuals: dict[str, Any] = {
        "autocorr_fraction_outside_95": tests.autocorr_outside,
        "crosscorr_input_fraction_outside_95": tests.crosscorr_outside,
        "autocorr_max": tests.autocorr_max,
        "crosscorr_max": tests.crosscorr_max,
        "white": tests.white,
        "independent_of_input": tests.independent_of_input,
    }
    report.validation["residuals"] = residuals
    widen = 1.0
    if not all(tests.white.values()):
        from pmdc_ident.core.estimators.uncertainty import coloured_noise_factor

        factors = coloured_noise_factor(fit, dyn)
        widen = math.sqrt(max([1.0, *factors.values()]))
        residuals["variance_inflation"] = factors
        residuals["interval_widening"] = widen
    for sig, ok in tests.white.items():
        if not ok:
            report.warnings.append(
                f"{sig} residuals are not white ({100 * tests.autocorr_outside[sig]:.0f} % of "
                "lags outside the 95 % band): unmodelled dynamics or coloured noise "
                "(see `pmdc-ident diagnose`); intervals widened x"
                f"{widen:.2g} for the residuals' autocorrelation"
            )
    return widen


def _frequency_response(
    setup: _Setup, fit: FitResult, report: _Report
) -> FrequencyResponse | None:
    """The sweep's measured frequency response against the fitted model's."""
    sweeps = [s for s in setup.dynamic if s.kind is TestKind.SWEEP]
    if not sweeps or setup.current_mode:
        return None
    sw = sweeps[0]
    try:
        x0 = np.array(fit.initial_states.get(sw.label, (0.0, 0.0, 0.0)))
        free = simulate_linear(fit.model.params, np.zeros(sw.n), sw.dt_s, x0=x0)
        freq = estimate_frequency_response(sw, free_response=(free.current, free.speed))
        mism = freq.mismatch_db(fit.model.params)
    except DataError as exc:
        report.warnings.append(f"frequency response skipped: {exc}")
        return None
    report.methods["frequency"] = {
        "segment": freq.label,
        "n_points": int(freq.freq_hz.size),
        "band_hz": [float(freq.freq_hz[0]), float(freq.freq_hz[-1])],
        "median_abs_mismatch_db": mism,
        "coherent_fraction": {
            "current": float(np.mean(freq.coherence_current >= 0.9))
            if freq.coherence_current is not None
            else None,
            "speed": float(np.mean(freq.coherence_speed >= 0.9)),
        },
    }
    return freq


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


def _added_for(added: Mapping[str, float], segs: Sequence[Segment]) -> dict[str, float]:
    labels = {s.label for s in segs}
    return {k: v for k, v in added.items() if k in labels}


def _fixed_for(fixed: Mapping[str, float], m: Model) -> dict[str, float]:
    names = set(PARAMETER_NAMES) | {f"{e.NAME}.{f}" for e in m.effects for f in e.as_dict()}
    return {k: v for k, v in fixed.items() if k in names}


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
