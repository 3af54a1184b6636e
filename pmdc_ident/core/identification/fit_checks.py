"""The fit stage of the assumption register: every reported parameter checked before it
is called identified (``identify`` and the identification node alike).

:func:`check_parameters` takes the fit's estimates and returns them with the flags of

* the gate's findings that bias a parameter (``armature-voltage``: :mod:`.bias`);
* the misfit-robust checks when the residuals are not white (:mod:`pmdc_ident.core.quality.misfit`:
  ``run-start``, ``parts-agree``, ``electrical-resolution``);
* the gate's expectation and the fit's verdict as one message (``gate-and-fit``);
* the Kt = Ke closure reported as an assumption, never a measurement (``kt-equals-ke``);
* values outside a motor's physical range (``physical-range``).

Each flag sets ``identifiable: false`` (no interval) with the reason and what to
record; one warning per register entry says which parameters it flagged.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.identification.bias import flag_biased
from pmdc_ident.core.identification.estimate import ParameterEstimate
from pmdc_ident.core.params import PARAMETER_RANGES
from pmdc_ident.core.quality.findings import Finding
from pmdc_ident.core.quality.information import NOT_IDENTIFIABLE, TIMING_SHARE, WEAK
from pmdc_ident.core.quality.misfit import Refit

__all__ = ["FitChecks", "check_parameters"]

_GATE_NAMES = {"coulomb_friction.torque_nm": "Tc"}


@dataclass
class FitChecks:
    """The checked parameters, the warnings to add and, per register entry, the line
    that said what was done (for ``assumptions_checked``)."""

    parameters: dict[str, ParameterEstimate]
    warnings: list[str] = field(default_factory=list)
    said: dict[str, str] = field(default_factory=dict)


def _flag(p: ParameterEstimate, reason: str, *notes: ParameterNote) -> ParameterEstimate:
    """``p`` not identifiable, for ``reason`` (whose codes are ``notes``)."""
    return replace(p, identifiable=False, ci95=None, reason=reason, notes=frozenset(notes))


def check_parameters(
    parameters: Mapping[str, ParameterEstimate],
    *,
    fit: FitResult,
    dyn: Sequence[Segment],
    refit: Refit,
    white: Mapping[str, bool],
    widen: float,
    findings: Iterable[Finding] = (),
    expected_rsd: Mapping[str, float] | None = None,
    fixed: Mapping[str, float] | None = None,
    closure: str | None = None,
) -> FitChecks:
    """The fit-stage checks of the register on ``parameters`` (see the module notes).

    ``refit(segments)``: the chosen model fitted on other segments with the same fixed
    values and closure; ``white``: residual whiteness per signal; ``widen``: the
    intervals' factor for coloured residuals; ``expected_rsd``: the gate's expectation
    before the fit."""
    from pmdc_ident.core.quality.misfit import misfit_flags

    fixed = dict(fixed or {})
    out = FitChecks(dict(parameters))
    _timing_budget(out, fit, dyn, fixed)
    params, biased = flag_biased(out.parameters, findings, fixed)
    out.parameters = params
    if biased:
        out.warnings.append(biased)
        out.said["current-filter"] = biased
    free = [n for n in fit.free if n in params and n not in fixed]
    misfit = misfit_flags(fit, dyn, refit, white=white, widen=widen)
    by_code: dict[str, list[str]] = {}
    for f in misfit.flags:
        p = params.get(f.name)
        if p is None or f.name not in free or not p.identifiable:
            continue
        params[f.name] = _flag(p, f"model misfit: {f.reason}")
        by_code.setdefault(f.code, []).append(f.name)
    _cover(out, misfit.cover)
    for code, names in by_code.items():
        line = (
            f"{', '.join(names)} flagged ({code}): the residuals show what the model misses, "
            "and a check that does not trust the model failed (see each one's note)"
        )
        out.warnings.append(line)
        out.said[code] = line
    _friction_split(out, fit, dyn, refit, expected_rsd or {}, fixed)
    _one_message(out, fit, expected_rsd or {})
    if closure is not None and "Kt" in params and "Kt" not in fixed:
        params["Kt"] = _flag(
            params["Kt"],
            "assumed equal to Ke (closure Kt = Ke in SI units): voltage, current and speed "
            f"cannot measure it; {opt('fix')} Kt=... (a datasheet), or runs with a known "
            f"added inertia ({opt('added_inertia')}) measure it",
            ParameterNote.ASSUMED,
        )
        out.said["kt-equals-ke"] = "Kt reported as assumed (Kt = Ke), not identified"
    _physical_range(out)
    return out


def _cover(out: FitChecks, cover: Mapping[str, list[tuple[float, float]]]) -> None:
    """Each identified parameter's interval widened to cover the refits of the
    misfit-robust checks (disjoint parts, each signal, without the start): with
    non-white residuals the covariance interval describes a model that is wrong."""
    names = []
    for name, ranges in cover.items():
        p = out.parameters.get(name)
        if p is None or not p.identifiable or p.ci95 is None or not ranges:
            continue
        lo = min([p.ci95[0], *(r[0] for r in ranges)])
        hi = max([p.ci95[1], *(r[1] for r in ranges)])
        if (lo, hi) == tuple(p.ci95):
            continue
        note = (
            "the interval covers the model refitted on disjoint parts of the data and led "
            "by each signal (the residuals are not white)"
        )
        rel = (hi - lo) / (2 * 1.96 * abs(p.value)) if p.value else math.inf
        if rel > NOT_IDENTIFIABLE:
            out.parameters[name] = _flag(p, f"not identifiable: relative sd {rel:.0%} once {note}")
        else:
            notes = p.notes
            weakly = rel > WEAK and ParameterNote.WEAKLY_IDENTIFIABLE not in p.notes
            if weakly:
                note = f"weakly identifiable: relative sd {rel:.0%} once {note}"
                gate = p.notes & {ParameterNote.GATE_EXPECTED}
                notes = frozenset({ParameterNote.WEAKLY_IDENTIFIABLE, *gate})
            reason = f"{p.reason}; {note}" if p.reason and not weakly else note
            if weakly and p.reason:
                reason = f"{note}; {p.reason}"
            out.parameters[name] = replace(p, ci95=(lo, hi), reason=reason, notes=notes)
        names.append(name)
    if names:
        out.said["white-residuals"] = f"intervals widened over the refits: {', '.join(names)}"


def _timing_budget(
    out: FitChecks, fit: FitResult, dyn: Sequence[Segment], fixed: Mapping[str, float]
) -> None:
    """L's interval with the sub-sample timing no record can show: the model has the
    voltage change and the current sampled exactly at the sample instants, and an
    offset of ``TIMING_SHARE`` of a period reads as an L changed by about that offset
    over L/R (MuJoCo's dcmotor integrated with 200 Euler steps per sample lags by half a
    step, 0.25 % of a period: L came out 0.34 % low with a +-0.12 % interval). Folded
    into L's standard error; above 10 % it is weakly identifiable, above 50 % not."""
    p = out.parameters.get("L")
    if p is None or "L" in fixed or not p.identifiable or p.stderr is None or not dyn:
        return
    r = fit.values.get("R", math.nan)
    tau = p.value / r if r > 0 else math.nan
    dt = min(s.dt_s for s in dyn)
    if not (math.isfinite(tau) and tau > 0):
        return
    sys_rel = TIMING_SHARE * dt / tau
    se = math.hypot(p.stderr, sys_rel * p.value)
    rel = se / p.value
    note = (
        f"the interval includes a sub-sample timing uncertainty ({TIMING_SHARE:.0%} of the "
        f"{dt * 1e3:.3g} ms period: {sys_rel:.2%} of L at L/R = {tau * 1e3:.3g} ms)"
    )
    if rel > NOT_IDENTIFIABLE:
        out.parameters["L"] = _flag(
            p,
            f"L/R = {tau * 1e3:.3g} ms against a {dt * 1e3:.3g} ms sample: a timing offset of "
            f"{TIMING_SHARE:.0%} of a period alone moves L by {sys_rel:.0%}; fix L from an "
            f"LCR meter ({opt('fix')} L=...)",
            ParameterNote.FAST_ELECTRICAL,
        )
        return
    z = 1.96 * rel
    ci = (p.value * math.exp(-z), p.value * math.exp(z))
    reason, notes = p.reason, p.notes
    if rel > WEAK and ParameterNote.WEAKLY_IDENTIFIABLE not in notes:
        reason = f"weakly identifiable: relative sd {rel:.0%} on these data; {note}"
        notes = frozenset({ParameterNote.WEAKLY_IDENTIFIABLE})
    else:
        reason = f"{reason}; {note}" if reason else note
        notes = notes if p.reason else frozenset()
    out.parameters["L"] = replace(p, ci95=ci, stderr=se, reason=reason, notes=notes)


ONE_SPEED_SHARE = 0.8  # of the moving samples within 5 % of one speed: one steady speed
TC = "coulomb_friction.torque_nm"


def one_speed(dyn: Sequence[Segment]) -> float | None:
    """The speed (rad/s) the rotor holds in most of the record when it holds one (then
    viscous and constant friction are one torque there), else None."""
    w = np.abs(np.concatenate([s.speed_or_derivative() for s in dyn]))
    top = float(np.max(w)) if w.size else 0.0
    moving = w[w > 0.05 * top]
    if moving.size < 20:
        return None
    med = float(np.median(moving))
    share = float(np.mean(np.abs(moving - med) <= 0.05 * med))
    return med if share >= ONE_SPEED_SHARE else None


def _friction_split(
    out: FitChecks,
    fit: FitResult,
    dyn: Sequence[Segment],
    refit: Refit,
    expected: Mapping[str, float],
    fixed: Mapping[str, float],
) -> None:
    """One steady speed cannot tell viscous from constant friction: B (and the Coulomb
    torque) flagged, as one message with the gate's figure; every other parameter's
    interval made to cover the other split (all friction viscous, or all constant),
    refitted."""
    from pmdc_ident.core.effects import CoulombFriction
    from pmdc_ident.core.errors import PmdcError
    from pmdc_ident.core.model import Model

    w = one_speed(dyn)
    params = out.parameters
    if w is None or "B" in fixed or "B" not in fit.free:
        return
    has_tc = TC in fit.values
    if has_tc and TC in fixed:
        return
    b, tc = fit.values["B"], fit.values.get(TC, 0.0)
    torque = b * w + tc
    try:
        if has_tc:  # all of it viscous
            others = tuple(e for e in fit.model.effects if not isinstance(e, CoulombFriction))
            alt = refit(dyn, model=Model(fit.model.params, others))
        else:  # all of it constant
            m = Model(fit.model.params, (*fit.model.effects, CoulombFriction(max(torque, 1e-12))))
            alt = refit(dyn, model=m, fixed={"B": 1e-6 * b if b > 0 else 1e-15})
    except PmdcError:
        alt = None
    g = expected.get("B")
    gate = (
        f" (the gate expected a relative sd of {g:.0%} for B beside a constant torque)"
        if g is not None and math.isfinite(g) and g > NOT_IDENTIFIABLE
        else ""
    )
    what = (
        f"the rotor holds one steady speed here (about {w:.4g} rad/s): viscous and constant "
        f"friction are one torque ({torque:.3g} N*m) there{gate}, so "
    )
    for name in ("B", TC):
        p = params.get(name)
        if p is None or not p.identifiable:
            continue
        params[name] = _flag(
            p,
            what + f"{name} holds only under the chosen split, which these data cannot test; "
            "record steady speeds at several voltages (a staircase), both directions",
            *([ParameterNote.GATE_EXPECTED] if gate else []),
        )
    said = ["B" if "B" in params else "", TC if has_tc else ""]
    if alt is not None:
        split = "all viscous" if has_tc else "all constant"
        for name in fit.free:
            p = params.get(name)
            if name in ("B", TC) or p is None or not p.identifiable or p.ci95 is None:
                continue
            other = alt.values.get(name)
            se = alt.stderr.get(name) or 0.0
            if other is None or p.ci95[0] <= other <= p.ci95[1]:
                continue
            lo = min(p.ci95[0], other - 1.96 * se)
            hi = max(p.ci95[1], other + 1.96 * se)
            note = (
                f"the interval covers the friction's split between viscous and constant, "
                f"which one steady speed cannot tell ({name} = {other:.4g} with it {split})"
            )
            params[name] = replace(
                p, ci95=(lo, hi), reason=f"{p.reason}; {note}" if p.reason else note
            )
            said.append(name)
    line = (
        f"one steady speed (about {w:.4g} rad/s): viscous and constant friction are one torque; "
        f"flagged or widened: {', '.join(n for n in said if n)}"
    )
    out.warnings.append(line)
    out.said["identifiability"] = line


def _one_message(out: FitChecks, fit: FitResult, expected: Mapping[str, float]) -> None:
    """The gate's expectation and the fit's verdict of each parameter as one message."""
    params = out.parameters
    for name, p in list(params.items()):
        g = expected.get(_GATE_NAMES.get(name, name))
        if g is None or not math.isfinite(g) or g <= NOT_IDENTIFIABLE or not p.identifiable:
            continue
        se = fit.stderr.get(name)
        rel = se / abs(p.value) if se is not None and p.value else math.inf
        note = (
            f"the gate expected a relative sd of {g:.0%} before the fit (its quick "
            f"linearisation); the fit's own bound on these data is {rel:.2%} and decides"
        )
        params[name] = replace(
            p,
            reason=f"{p.reason}; {note}" if p.reason else note,
            notes=(p.notes if p.reason else frozenset()) | {ParameterNote.GATE_EXPECTED},
        )


def _physical_range(out: FitChecks) -> None:
    """Values no motor has: flagged (the motor file carries the nearest end of the range,
    :meth:`IdentificationResult.motor_spec`)."""
    names = []
    for name, (lo, hi) in PARAMETER_RANGES.items():
        p = out.parameters.get(name)
        if p is None or (math.isfinite(p.value) and lo <= p.value <= hi):
            continue
        end = lo if p.value < lo else hi
        why = (
            f"the fit ran to {p.value:.3g} {p.unit}, outside the physical range [{lo:g}, {hi:g}]: "
            f"the data do not hold it (the motor file carries {end:g})"
        )
        out.parameters[name] = _flag(p, f"{why}; {p.reason}" if p.reason else why)
        names.append(name)
    if names:
        line = f"{', '.join(names)} outside the physical range: flagged, clamped in the motor file"
        out.warnings.append(line)
        out.said["physical-range"] = line
