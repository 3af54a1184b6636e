"""Steps 5.-6. of :func:`~pmdc_ident.core.identification.identify.identify`: the
held-out segment, the residual tests (and the intervals' widening for coloured
residuals), the sweep's frequency response, and the notes on quantisation and
initial states."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pmdc_ident.core.data import Segment, TestKind
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.estimators.frequency import FrequencyResponse, estimate_frequency_response
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.estimators.validation import holdout_score, residual_tests
from pmdc_ident.core.identification.state import _Report, _Setup
from pmdc_ident.core.model import simulate_linear
from pmdc_ident.core.progress import ProgressCallback

__all__: list[str] = []


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
