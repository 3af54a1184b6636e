"""The identification pipeline behind ``pmdc-ident identify``.

1. Sort the segments: tables and steady levels go to the classical chain,
   uniformly sampled time series to the dynamic methods.
2. Equation error on the discretised equations (fast start).
3. Output error over all dynamic segments at once, for the seeds' linear model
   and for the same plus Coulomb friction; the Coulomb model is kept when its
   friction torque is significant (95 % interval above zero).
4. Validation: one segment is held out and predicted free-running by a fit
   on the others; residual whiteness and input cross-correlation; optionally a
   parametric bootstrap that checks the covariance intervals.
5. The sweep's non-parametric frequency response against the model's.

Current-driven data (no voltage column) give the mechanical side only (J, B,
Coulomb, load torque), given Kt.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from pmdc_ident.core.data import Run, Segment, TestKind
from pmdc_ident.core.effects import CoulombFriction, LoadTorque, parameter_unit
from pmdc_ident.core.errors import DataError, ParameterError
from pmdc_ident.core.estimators.classical import ClassicalResult, classical_chain
from pmdc_ident.core.estimators.equation_error import (
    EquationErrorResult,
    fit_equation_error,
    fit_mechanical_equation_error,
)
from pmdc_ident.core.estimators.frequency import estimate_frequency_response
from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE, FitResult, fit_output_error
from pmdc_ident.core.estimators.validation import holdout_score, residual_tests
from pmdc_ident.core.model import Model, simulate_linear
from pmdc_ident.core.motors import Limits
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams
from pmdc_ident.core.results import IdentificationResult, ParameterEstimate, estimate_from_fit

__all__ = ["ModelChoice", "identify", "identify_runs", "merge_runs"]

TABLE_MAX_ROWS = 20


class _Skip(Exception):  # noqa: N818 - control flow, never leaves this module
    """Internal: no time series for the dynamic methods."""


_SKIP = _Skip()


TC = "coulomb_friction.torque_nm"


class ModelChoice(enum.StrEnum):
    """Which model the output-error fit reports (auto: Coulomb when significant)."""

    AUTO = "auto"
    LINEAR = "linear"
    COULOMB = "coulomb"


Progress = Callable[[str], None]


def merge_runs(runs: Sequence[Run]) -> list[Segment]:
    """All segments of several runs, labels made unique (``step_up``, ``step_up_2``...)."""
    segs: list[Segment] = []
    labels: set[str] = set()
    for run in runs:
        for s in run.segments:
            label = s.label
            k = 2
            while label in labels:
                label = f"{s.label}_{k}"
                k += 1
            labels.add(label)
            segs.append(s if label == s.label else s.slice(0, s.n, label=label))
    return segs


def identify_runs(runs: Sequence[Run], **kwargs: Any) -> IdentificationResult:
    """:func:`identify` on the merged segments of several runs (files)."""
    return identify(merge_runs(runs), sources=tuple(r.source for r in runs), **kwargs)


def _check_excitation(segs: Sequence[Segment]) -> None:
    speeds = np.concatenate([s.speed_or_derivative() for s in segs])
    volts = [s.voltage[~np.isnan(s.voltage)] for s in segs if s.voltage is not None]
    v = np.concatenate(volts) if volts else np.zeros(0)
    has_open = any(s.open_mask.any() for s in segs)
    cur = [s.current for s in segs if s.current is not None]
    moving = float(np.ptp(speeds)) > 0 and float(np.max(np.abs(speeds))) > 0
    still_input = (v.size == 0 or (np.ptp(v) == 0 and abs(v[0]) == 0)) and not has_open
    if not moving and still_input:
        held = f"{v[0]:g} V" if v.size else "no voltage column"
        msg = (
            f"no excitation: the motor never moves ({held}, speed constant); "
            "record a step, sweep, staircase or coast-down"
        )
        raise DataError(msg)
    if not moving:
        msg = "no excitation: the speed never changes, so nothing mechanical can be identified"
        raise DataError(msg)
    if cur and not any(np.ptp(c) > 0 for c in cur) and (v.size == 0 or np.ptp(v) == 0):
        if not has_open:
            msg = "no excitation: voltage and current are constant in every segment"
            raise DataError(msg)


def _is_dynamic(s: Segment) -> bool:
    return s.n > TABLE_MAX_ROWS and regular_sampling(s)


def regular_sampling(s: Segment, jitter: float = 0.25) -> bool:
    """Every sample period within ``jitter`` of the median: timestamp jitter is tolerated
    (the fit simulates on the median period and says so), gaps are not."""
    dt = np.diff(s.t)
    return bool(np.all(np.abs(dt - s.dt_s) <= jitter * s.dt_s))


def identify(
    segments: Sequence[Segment],
    *,
    fixed: Mapping[str, float] | None = None,
    closure: str | None = CLOSURE_KT_KE,
    model: str = ModelChoice.AUTO,
    holdout: bool = True,
    bootstrap: int = 0,
    frequency: bool = True,
    progress: Progress | None = None,
    sources: tuple[str, ...] = (),
    seed: int = 0,
    added_inertia: Mapping[str, float] | None = None,
) -> IdentificationResult:
    """Identify the motor from ``segments`` (see module docs).

    ``added_inertia`` maps segment labels to a known inertia added for them
    (kg*m^2); with runs with and without it, Kt is estimated instead of assumed
    equal to Ke.
    """
    say = progress or (lambda _msg: None)
    fixed = {str(k): float(v) for k, v in (fixed or {}).items()}
    known = set(PARAMETER_NAMES) | {TC, "load_torque.torque_nm"}
    for k, v in fixed.items():
        if k not in known:
            msg = f"--fix {k}: unknown parameter (known: {', '.join(sorted(known))})"
            raise ParameterError(msg)
        if not math.isfinite(v) or (k in PARAMETER_NAMES and (v < 0 or (v == 0 and k != "B"))):
            msg = f"--fix {k}={v:g}: must be a positive number in {parameter_unit(k)}"
            raise ParameterError(msg)
    if model not in (ModelChoice.AUTO, ModelChoice.LINEAR, ModelChoice.COULOMB):
        msg = f"unknown model {model!r}; use auto, linear or coulomb"
        raise ParameterError(msg)
    if not segments:
        msg = "no data"
        raise DataError(msg)
    segs = list(segments)
    _check_excitation(segs)
    assumptions: list[str] = []
    warnings: list[str] = []
    methods: dict[str, dict[str, Any]] = {}
    validation: dict[str, Any] = {}
    current_mode = all(s.voltage is None for s in segs)
    if not current_mode and any(s.voltage is None for s in segs):
        msg = "some inputs have a voltage column and some do not; identify them separately"
        raise DataError(msg)

    added = {k: float(v) for k, v in (added_inertia or {}).items() if float(v) > 0.0}
    closure_used = closure if ("Kt" not in fixed and "J" not in fixed) else None
    if added and not current_mode:
        closure_used = None
    if current_mode:
        if "Kt" not in fixed:
            msg = "current-driven data (no voltage column) need the torque constant: --fix Kt=..."
            raise ParameterError(msg)
        assumptions.append(
            f"no voltage column: mechanical-only fit (J, B, Coulomb, load torque) "
            f"given Kt = {fixed['Kt']:g} N*m/A"
        )
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
            "replace with --fix Kt=... or --fix J=..."
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

    dyn = [s for s in segs if _is_dynamic(s)]
    skipped = [s.label for s in segs if not _is_dynamic(s) and s.n > TABLE_MAX_ROWS]
    if skipped:
        warnings.append(
            "segments with gaps in time (a sample period off the median by more than 25 %), "
            f"left out of the dynamic fit: {', '.join(skipped)}"
        )
    limits = _limits(segs)

    # 1. equation error (a fast start; also gives the classical chain an R)
    ee: EquationErrorResult | None = None
    try:
        if not dyn:
            raise _SKIP
        say("equation error (discretised equations)")
        if current_mode:
            ee = fit_mechanical_equation_error(dyn, Kt=fixed["Kt"])
        else:
            ee = fit_equation_error(
                dyn, Kt=fixed.get("Kt"), J=fixed.get("J") if closure_used is None else None
            )
        methods["equation_error"] = {"values": dict(ee.values), "method": ee.method}
        warnings.extend(ee.notes)
    except _Skip:
        pass
    except DataError as exc:
        if "no excitation" in str(exc):
            raise
        warnings.append(f"equation error skipped: {exc}")

    # 2. classical chain on staircase / coast-down (tables or time series)
    classical: ClassicalResult | None = None
    if any(s.kind in (TestKind.STAIRCASE, TestKind.COAST) for s in segs) and not current_mode:
        try:
            say("classical chain (staircase, coast-down)")
            cfix = dict(fixed)
            if "R" not in cfix and ee is not None and "R" in ee.values:
                # no multimeter value: the staircase alone pins R poorly
                cfix["R"] = ee.values["R"]
            classical = classical_chain(segs, fixed=cfix)
            if "R" not in fixed and "R" in cfix:
                classical = replace(
                    classical,
                    notes=(
                        f"classical: R = {cfix['R']:.4g} ohm taken from the equation-error "
                        "fit (no multimeter value given)",
                        *classical.notes,
                    ),
                )
            methods["classical"] = {
                "values": dict(classical.values),
                "ci95": {k: list(v) if v else None for k, v in classical.ci95.items()},
                "notes": list(classical.notes),
            }
            if classical.coast is not None:
                c = classical.coast
                methods["classical"]["coast"] = {
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
        except DataError as exc:
            warnings.append(f"classical chain skipped: {exc}")

    if not dyn:
        if classical is None or not classical.values:
            msg = "no segment long enough for a dynamic fit and no staircase/coast-down table"
            raise DataError(msg)
        return _classical_only(classical, fixed, assumptions, warnings, methods, sources, limits)

    start = _initial_values(ee, classical, dyn, fixed, current_mode)

    # 3. output error, linear and Coulomb
    want = [ModelChoice.LINEAR, ModelChoice.COULOMB] if model == ModelChoice.AUTO else [model]
    fits: dict[str, FitResult] = {}
    for kind in map(str, want):
        m0 = _start_model(start, kind, current_mode, fixed)
        say(f"output error, {kind} model")
        try:
            fits[kind] = fit_output_error(
                dyn,
                m0,
                fixed=_fixed_for(fixed, m0),
                closure=closure_used,
                progress=lambda it, cost, k=kind: say(f"  {k}: iteration {it}, cost {cost:.6g}"),
                added_inertia=_added_for(added, dyn),
            )
        except DataError as exc:
            warnings.append(f"output error ({kind}) failed: {exc}")
    if not fits:
        msg = "the output-error fit failed on every model"
        raise DataError(msg)
    lin, cou = fits.get(ModelChoice.LINEAR), fits.get(ModelChoice.COULOMB)
    if lin is not None and cou is not None:
        if minus_two_log_likelihood(cou) > minus_two_log_likelihood(lin) + 1e-6:
            # The Coulomb model contains the linear one (Tc = 0): a worse fit is a poor
            # local minimum; restart it from the linear solution.
            say("output error, coulomb model restarted from the linear fit")
            m0 = Model(lin.model.params, (CoulombFriction(1e-6 * lin.model.params.Kt),))
            again = fit_output_error(
                dyn,
                m0,
                fixed=_fixed_for(fixed, m0),
                closure=closure_used,
                added_inertia=_added_for(added, dyn),
            )
            if minus_two_log_likelihood(again) < minus_two_log_likelihood(cou):
                fits[ModelChoice.COULOMB] = again
    for kind, f in fits.items():
        methods[f"output_error_{kind}"] = {
            "values": dict(f.values),
            "ci95": {k: list(v) if v else None for k, v in f.ci95.items()},
            "rms": dict(f.rms),
            "cost": f.cost,
            "minus_2_log_likelihood": minus_two_log_likelihood(f),
            "iterations": f.iterations,
            "converged": f.converged,
        }
    chosen = _choose(fits, model)
    fit = fits[chosen]
    if chosen == ModelChoice.COULOMB:
        assumptions.append(
            "friction is Coulomb plus viscous (Coulomb torque significant: its 95 % interval "
            "lies above zero and the likelihood-ratio test prefers it)"
        )
    elif model == ModelChoice.AUTO and ModelChoice.COULOMB in fits:
        assumptions.append("friction is viscous only (no significant Coulomb torque found)")
    warnings.extend(w for w in fit.warnings if w not in warnings)
    if current_mode:
        chosen_kind = "mechanical"
    else:
        chosen_kind = chosen

    # 4. validation
    if holdout:
        held = _holdout_segments(dyn)
        if held:
            rest = [s for s in dyn if s not in held]
            say(f"validation: refit without {', '.join(s.label for s in held)}")
            for kind, f in fits.items():
                try:
                    f_rest = fit_output_error(
                        rest,
                        f.model,
                        fixed=_fixed_for(fixed, f.model),
                        closure=closure_used,
                        added_inertia=_added_for(added, rest),
                    )
                except DataError as exc:
                    warnings.append(f"hold-out refit ({kind}) failed: {exc}")
                    continue
                score = holdout_score(f_rest, held)
                methods[f"output_error_{kind}"]["holdout_rms"] = score.rms
                methods[f"output_error_{kind}"]["holdout_nrmse"] = score.nrmse
                if kind == chosen:
                    validation["holdout"] = {
                        "labels": list(score.labels),
                        "rms": score.rms,
                        "nrmse": score.nrmse,
                        "model": kind,
                    }
        else:
            warnings.append("only one dynamic segment: no held-out validation possible")
    tests = residual_tests(fit, dyn)
    validation["residuals"] = {
        "autocorr_fraction_outside_95": tests.autocorr_outside,
        "crosscorr_input_fraction_outside_95": tests.crosscorr_outside,
        "autocorr_max": tests.autocorr_max,
        "crosscorr_max": tests.crosscorr_max,
        "white": tests.white,
        "independent_of_input": tests.independent_of_input,
    }
    widen = 1.0
    if not all(tests.white.values()):
        from pmdc_ident.core.estimators.uncertainty import coloured_noise_factor

        factors = coloured_noise_factor(fit, dyn)
        widen = math.sqrt(max([1.0, *factors.values()]))
        validation["residuals"]["variance_inflation"] = factors
        validation["residuals"]["interval_widening"] = widen
    for sig, ok in tests.white.items():
        if not ok:
            warnings.append(
                f"{sig} residuals are not white ({100 * tests.autocorr_outside[sig]:.0f} % of "
                "lags outside the 95 % band): unmodelled dynamics or coloured noise "
                "(see `pmdc-ident diagnose`); intervals widened x"
                f"{widen:.2g} for the residuals' autocorrelation"
            )
    if bootstrap > 0:
        from pmdc_ident.core.estimators.uncertainty import parametric_bootstrap

        say(f"bootstrap: {bootstrap} refits on simulated noise")
        bs = parametric_bootstrap(fit, dyn, n=bootstrap, seed=seed, closure=closure_used)
        validation["bootstrap"] = bs

    # 5. frequency response
    freq = None
    sweeps = [s for s in dyn if s.kind is TestKind.SWEEP]
    if frequency and sweeps and not current_mode:
        try:
            sw = sweeps[0]
            x0 = np.array(fit.initial_states.get(sw.label, (0.0, 0.0, 0.0)))
            free = simulate_linear(fit.model.params, np.zeros(sw.n), sw.dt_s, x0=x0)
            freq = estimate_frequency_response(sw, free_response=(free.current, free.speed))
            mism = freq.mismatch_db(fit.model.params)
            methods["frequency"] = {
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
        except DataError as exc:
            warnings.append(f"frequency response skipped: {exc}")

    params = {name: estimate_from_fit(fit, name, f"output_error_{chosen}") for name in fit.values}
    if widen > 1.0:
        from pmdc_ident.core.estimators.uncertainty import widen_interval

        for name, est in params.items():
            if est.ci95 is not None:
                params[name] = _replace_est(
                    est,
                    ci95=widen_interval(est.value, est.ci95, widen),
                    stderr=None if est.stderr is None else est.stderr * widen,
                )
    for name in fit.fixed:
        params[name] = _replace_est(params[name], reason="fixed by the user", method="fixed")
    if current_mode:
        for name in ("R", "L", "Ke"):
            params[name] = _replace_est(
                params[name],
                identifiable=False,
                reason="no voltage in the data (value is a placeholder)",
            )
    if "L" in params and not params["L"].identifiable and "L" not in fixed:
        pass  # reason already names the needed rate
    fit_info = {
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
    return IdentificationResult(
        sources=sources,
        model_kind=chosen_kind,
        model=fit.model,
        parameters=params,
        assumptions=tuple(assumptions),
        warnings=tuple(dict.fromkeys(warnings)),
        methods=methods,
        validation=validation,
        noise=dict(fit.noise),
        fit=fit,
        frequency=freq,
        fit_info=fit_info,
        limits=limits,
    )


def _added_for(added: Mapping[str, float], segs: Sequence[Segment]) -> dict[str, float]:
    labels = {s.label for s in segs}
    return {k: v for k, v in added.items() if k in labels}


def _replace_est(p: ParameterEstimate, **kw: Any) -> ParameterEstimate:
    from dataclasses import replace

    return replace(p, **kw)


def _fixed_for(fixed: Mapping[str, float], m: Model) -> dict[str, float]:
    names = set(PARAMETER_NAMES) | {f"{e.NAME}.{f}" for e in m.effects for f in e.as_dict()}
    return {k: v for k, v in fixed.items() if k in names}


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


def _initial_values(
    ee: EquationErrorResult | None,
    classical: ClassicalResult | None,
    dyn: Sequence[Segment],
    fixed: Mapping[str, float],
    current_mode: bool,
) -> dict[str, float]:
    vals: dict[str, float] = {}
    if classical is not None:
        vals.update(classical.values)
    if ee is not None:
        vals.update({k: v for k, v in ee.values.items() if math.isfinite(v)})
    dt = min(s.dt_s for s in dyn)
    if "R" not in vals or "Ke" not in vals:
        vals.update(_crude_guess(dyn))
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
    scale_b = vals["J"] / max(10 * dt, 1e-3)
    vals["B"] = vals["B"] if vals["B"] > 0 else 1e-3 * scale_b
    vals[TC] = max(vals.get(TC, 0.0), 0.0)
    return vals


def _crude_guess(dyn: Sequence[Segment]) -> dict[str, float]:
    """R and Ke from the ends of segments (steady states) when nothing better exists."""
    rows = []
    for s in dyn:
        if s.voltage is None or s.current is None:
            continue
        k0 = int(0.8 * s.n)
        v = s.voltage[k0:]
        if np.isnan(v).any():
            continue
        rows.append(
            (
                float(v.mean()),
                float(s.current[k0:].mean()),
                float(s.speed_or_derivative()[k0:].mean()),
            )
        )
    if len(rows) >= 2:
        a = np.array(rows)
        (R, Ke), *_ = np.linalg.lstsq(a[:, 1:], a[:, 0], rcond=None)
        if R > 0 and Ke > 0:
            return {"R": float(R), "Ke": float(Ke)}
    return {}


def _start_model(
    vals: Mapping[str, float], kind: str, current_mode: bool, fixed: Mapping[str, float]
) -> Model:
    p = MotorParams(**{n: vals[n] for n in PARAMETER_NAMES})
    effects = []
    if kind == ModelChoice.COULOMB or TC in fixed:
        tc = vals.get(TC, 0.0)
        if tc <= 0 and TC not in fixed:
            # a small positive start (1 mA worth of torque)
            tc = 1e-3 * p.Kt
        effects.append(CoulombFriction(tc))
    if current_mode or "load_torque.torque_nm" in fixed:
        # a load torque is fitted on current-driven data, or held where the user knows it
        effects.append(LoadTorque(float(vals.get("load_torque.torque_nm", 0.0))))
    return Model(p, tuple(effects))


def minus_two_log_likelihood(fit: FitResult) -> float:
    """-2 log L of Gaussian white residuals with per-signal variances set to their ML value."""
    n_per = fit.n_samples
    return float(sum(n_per * math.log(max(r, 1e-300) ** 2) for r in fit.rms.values()))


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


def _classical_only(
    classical: ClassicalResult,
    fixed: Mapping[str, float],
    assumptions: list[str],
    warnings: list[str],
    methods: dict[str, dict[str, Any]],
    sources: tuple[str, ...],
    limits: Limits,
) -> IdentificationResult:
    vals = dict(classical.values)
    vals.update(fixed)
    params: dict[str, ParameterEstimate] = {}
    placeholder = {
        "L": (
            "no dynamic electrical data (tables only); fix it from an LCR meter (--fix L=...)",
            vals.get("R", 1.0) * 1e-4,
        ),
        "J": ("no coast-down in the data", 1e-3),
        "R": ("no staircase", 1.0),
    }
    for name in PARAMETER_NAMES + (TC,):
        if name in vals:
            params[name] = ParameterEstimate(
                name,
                float(vals[name]),
                None if name in fixed else classical.ci95.get(name),
                parameter_unit(name),
                True,
                stderr=None if name in fixed else classical.stderr.get(name),
                reason="fixed by the user"
                if name in fixed
                else ("assumed equal to Ke (closure Kt = Ke in SI units)" if name == "Kt" else ""),
                method="fixed" if name in fixed else "classical",
            )
        else:
            reason, value = placeholder.get(name, ("not in the data", 1.0))
            params[name] = ParameterEstimate(
                name, value, None, parameter_unit(name), False, reason=reason, method="placeholder"
            )
            warnings.append(f"{name}: {reason} (written as a placeholder {value:.3g})")
    p = MotorParams(**{n: params[n].value for n in PARAMETER_NAMES})
    tc = params[TC].value
    m = Model(p, (CoulombFriction(max(tc, 0.0)),) if tc > 0 else ())
    return IdentificationResult(
        sources=sources,
        model_kind="classical",
        model=m,
        parameters=params,
        assumptions=tuple(assumptions),
        warnings=tuple(dict.fromkeys(warnings)),
        methods=methods,
        validation={},
        noise={},
        limits=limits,
    )
