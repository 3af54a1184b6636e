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

The motor's parameters are the baseline's only as a start. A cogging large against the
drive (the slow crawls of a reveal plan: a rotor held in a detent, or stalled once
a period) leaves the linear baseline far off the motor: fitted on the encoder's
position, it bends R, L and J, and the segments' free initial states, to follow a
crawl's lost angle (an industrial motor's held crawl: L 9e-10 H against 28 mH, the
baseline's own spin-up 15 A RMS off), and cogging responses simulated with those
parameters explain nothing. So the parameters are refitted with the cogging
(:func:`_refit`: variable projection, the coefficients solved linearly for every
trial of R, L, Ke, J and B, on the diagnosis' own current and speed from the
measured initial states), from the baseline and from the equation-error start.
The refit stands only where the cogging, not the refit, closes the gap: it must
beat the same refit without cogging on held-out data by the two parameters'
penalty (on an effect-free record it does not), or, where the cogging's ripple is
below the noise per sample (a gearmotor at 1 kHz: 0.01 A of ripple in 0.012 A of
noise; the refit without it left 0.46 noise variances, under the penalty), show on
held-out data as evidence that accumulates over the samples (:func:`angle_evidence`:
the fit side's coefficients predict the held-out ripple at the count far beyond what
they do at off-harmonic counts), and close what the refit without it leaves as the
gap rule asks. The count is chosen again with the refitted motor
(:func:`_best_count`), among the counts tried and the strongest of the angle spectrum
of what the refit without cogging leaves on held-out data: the bent baseline chose it
(24 per turn for a gearmotor's 25; a scooter's 17 not offered at all under a misfit of
1300 noise variances).

The candidate carries a :class:`~pmdc_ident.core.effects.Cogging` effect of the same
amplitude, count and phase, so it costs the effect's two fitted parameters and a
combination with another effect is fitted in time as before.

**Plausibility** (:func:`implausible`): a fitted cogging is not named, and the result
says why, where the data cannot hold one, whatever its fit:

* *its period is not resolved by the sampling where its torque acts.* A torque of N
  periods per turn moves N |d theta| of its phase between two samples; beyond pi (half a
  period: Nyquist) the samples alias it, and sin/cos(N theta) read at those samples are
  a pseudo-random pair of regressors that can fit part of any residual (a 1.1 kW motor
  logged at 250 Hz with a current-rate limit: 23 periods per turn, above Nyquist at
  every speed but the slowest staircase level, "closed" 38-50 % of the gap). The share
  of the candidate's fitted effect (its simulated response, noise-weighted, on the fit
  and held-out samples) that falls on samples where its period is resolved must be at
  least half; a true cogging acts most where the rotor crawls, where it is resolved.
* *its size is impossible.* A rotor in a detent of a cogging of amplitude A is held
  against any torque below A; a rotor slower than sqrt(4 A / (N J)) has too little
  kinetic energy to roll over a detent. A record that has the rotor that slow (or at
  rest) and turning on through many periods shows a drive that exceeded A: a cogging
  larger than the largest torque the record applied (Kt times its peak current) cannot
  be the motor's.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis.localization import (
    MAX_HARMONIC,
    NYQUIST_PHASE_RAD,
    angle_harmonics,
    resolved_steps,
    shaft_angle,
)
from pmdc_ident.core.diagnosis.scoring import NoiseModel, Residuals, residuals, simulated
from pmdc_ident.core.diagnosis.search import FIT_ERRORS, Fitted, Scoring, Search, predictions
from pmdc_ident.core.effects import Cogging
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.estimators.start import equation_error_start
from pmdc_ident.core.model import Model, simulate_linear
from pmdc_ident.core.params import MotorParams

__all__ = ["angle_cogging", "held_waves", "implausible", "resolved_steps"]

FloatArray = NDArray[np.float64]
NOTE = "fitted in the measured shaft angle (linear least squares, motor parameters held)"
NOTE_REFIT = (
    "fitted in the measured shaft angle, the motor's parameters refitted with it "
    "(variable projection)"
)
REFIT_PARAMS = ("R", "L", "Ke", "J", "B")
REFIT_NFEV = 60  # least-squares evaluations per start (5 parameters, a smooth cost)
SD_REL_MAX = 50.0  # a refitted parameter's sd in log units beyond this: no interval
REFINE_STEPS = 4  # fit-side counts each side of a wide-search count
RESOLVED_SHARE_MIN = 0.5  # of the cogging's fitted effect on samples that resolve its period
ANGLE_NULLS = 16  # off-harmonic counts the held-out angle evidence is judged against
ANGLE_NULL_STEP = 1.0  # periods per turn between them at least (two resolution steps too)
ANGLE_Z = 5.0  # sd of the off-harmonic gains the candidate's must stand above


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
    ridge = 1e-12 * np.trace(a) * np.eye(np.shape(a)[0])
    coef = -np.linalg.solve(np.asarray(a) + ridge, np.asarray(b))
    cost = sum(float(np.nansum((res.error[s] + x[s] @ coef) ** 2)) * sig_w[s] for s in x)
    return coef, cost


def _shifted(res: Residuals, x: dict[str, FloatArray], coef: FloatArray) -> Residuals:
    err = {s: res.error[s] + np.nan_to_num(x[s]) @ coef for s in res.error}
    return Residuals(err, res.seg_index, res.noise)


@dataclass
class _Block:
    """One segment in a refit: the residuals of the linear motor from rest at its
    measured angle, the responses to its initial current and speed, and to the cogging's
    sin and cos torques (per signal: (n,), (n, 2), (n, 2))."""

    error: dict[str, FloatArray]
    initial: dict[str, FloatArray]
    cogging: dict[str, FloatArray] | None


def _blocks(
    p: MotorParams, segs: Sequence[Segment], noise: NoiseModel, periods: float | None
) -> list[_Block]:
    """The initial state is solved with the coefficients, as the output-error fit frees
    it (read off a coarse encoder's first samples, a rotor at rest can start at 8 rad/s)."""
    out = []
    for seg in segs:
        v = seg.voltage if seg.voltage is not None else np.zeros(seg.n)
        sim = simulate_linear(p, v, seg.dt_s, x0=[0.0, 0.0, float(shaft_angle(seg)[0])])
        res = residuals([seg], [sim], noise)
        err = {sg: e for sg, e in res.error.items() if np.isfinite(e).all()}
        v0 = np.where(np.isnan(v), np.nan, 0.0)
        units = [simulate_linear(p, v0, seg.dt_s, x0=u) for u in ([1.0, 0, 0], [0, 1.0, 0])]
        initial = {sg: np.column_stack([simulated(seg, u, sg) for u in units]) for sg in err}
        cog = None if periods is None else _responses(p, seg, periods, noise)
        out.append(_Block(err, initial, cog))
    return out


def _project(
    blocks: Sequence[_Block], sig_w: dict[str, float]
) -> tuple[FloatArray, list[dict[str, FloatArray]]]:
    """Least squares over the cogging's (a, b) (where the blocks have them) and every
    block's initial current and speed: the (a, b) and each block's weighted residuals."""
    n_c = 2 if blocks and blocks[0].cogging is not None else 0
    k = n_c + 2 * len(blocks)
    a, b = np.zeros((k, k)), np.zeros(k)
    for q, blk in enumerate(blocks):
        cols = slice(n_c + 2 * q, n_c + 2 * q + 2)
        for sg, e in blk.error.items():
            w = sig_w[sg] ** 2
            x_l = blk.initial[sg]
            a[cols, cols] += w * x_l.T @ x_l
            b[cols] += w * x_l.T @ e
            if n_c:
                x_c = blk.cogging[sg]  # type: ignore[index]
                a[:n_c, :n_c] += w * x_c.T @ x_c
                cross = w * x_c.T @ x_l
                a[:n_c, cols] += cross
                a[cols, :n_c] += cross.T
                b[:n_c] += w * x_c.T @ e
    ridge = 1e-12 * (np.trace(a) or 1.0) * np.eye(k)
    coef = -np.linalg.solve(a + ridge, b)
    shifted = []
    for q, blk in enumerate(blocks):
        c_l = coef[n_c + 2 * q : n_c + 2 * q + 2]
        part = {}
        for sg, e in blk.error.items():
            r = e + blk.initial[sg] @ c_l
            if n_c:
                r = r + blk.cogging[sg] @ coef[:n_c]  # type: ignore[index]
            part[sg] = r
        shifted.append(part)
    return (coef[:n_c] if n_c else np.zeros(2)), shifted


@dataclass(frozen=True)
class _Refit:
    params: MotorParams
    coef: FloatArray  # the cogging's (a, b)
    cost: float
    stderr_rel: dict[str, float]
    fit_res: Residuals  # on the fit segments, cogging and initial states applied


def _as_residuals(
    segs: Sequence[Segment], parts: Sequence[dict[str, FloatArray]], noise: NoiseModel
) -> Residuals:
    err = {
        sg: np.concatenate(
            [part.get(sg, np.full(seg.n, np.nan)) for seg, part in zip(segs, parts, strict=True)]
        )
        for sg in noise.signals
    }
    idx = np.concatenate([np.full(seg.n, k, dtype=np.int64) for k, seg in enumerate(segs)])
    return Residuals(err, idx, noise)


def _refit(
    search: Search, starts: Sequence[MotorParams], periods: float, cogging: bool
) -> _Refit | None:
    """The motor's parameters (``REFIT_PARAMS`` not held, Kt = Ke) refitted on the fit
    segments with a cogging of ``periods`` per turn in the measured angle (``cogging``)
    or without, from the best of ``starts``; the cogging's coefficients and each
    segment's initial current and speed are solved linearly for every trial (variable
    projection). ``None`` when no start can be fitted."""
    segs = search.split.fit
    names = [n for n in REFIT_PARAMS if n not in search.fixed]
    if not names or any(s.voltage is None for s in segs):
        return None
    sig_w = {sg: 1.0 / search.noise.sigma[sg] for sg in search.noise.signals}
    longest = max(s.n * s.dt_s for s in segs)

    def params_of(z: FloatArray, p0: MotorParams) -> MotorParams:
        vals = {n: float(math.exp(v)) for n, v in zip(names, z, strict=True)}
        if "Ke" in vals:
            vals["Kt"] = vals["Ke"]
        return p0.replace(**vals)

    def solve(p: MotorParams) -> tuple[FloatArray, list[dict[str, FloatArray]]]:
        return _project(_blocks(p, segs, search.noise, periods if cogging else None), sig_w)

    def vector(z: FloatArray, p0: MotorParams) -> FloatArray:
        _, parts = solve(params_of(z, p0))
        return np.concatenate([r * sig_w[sg] for part in parts for sg, r in part.items()])

    best: _Refit | None = None
    for p0 in starts:
        z0 = np.log([max(float(getattr(p0, n)), 1e-12) for n in names])
        try:
            out = least_squares(
                vector, z0, args=(p0,), method="trf", max_nfev=REFIT_NFEV, ftol=1e-6, xtol=1e-6
            )
        except FIT_ERRORS:
            continue
        if not np.isfinite(out.cost) or (best is not None and out.cost >= best.cost):
            continue
        p = params_of(out.x, p0)
        if p.L > longest * p.R:
            continue  # an integrator, not a winding (the module notes)
        dof = max(out.fun.size - len(names) - 2 * cogging - 2 * len(segs), 1)
        try:
            cov = np.linalg.inv(out.jac.T @ out.jac) * (2.0 * out.cost / dof)
            rel = {n: float(math.sqrt(max(cov[k, k], 0.0))) for k, n in enumerate(names)}
        except np.linalg.LinAlgError:
            rel = {}
        coef, parts = solve(p)
        best = _Refit(p, coef, float(out.cost), rel, _as_residuals(segs, parts, search.noise))
    return best


def _with_params(fit: FitResult, p: MotorParams, rel: dict[str, float]) -> FitResult:
    """``fit`` with the motor's parameters ``p`` (measured initial states from here on),
    their intervals from the refit's Jacobian (``rel``: relative sd)."""
    values, stderr, ci95, reasons = (
        dict(fit.values),
        dict(fit.stderr),
        dict(fit.ci95),
        dict(fit.reasons),
    )
    for n in (*REFIT_PARAMS, "Kt"):
        if n not in values or n in fit.fixed:
            continue
        v = float(getattr(p, n))
        values[n] = v
        sd = rel.get("Ke" if n == "Kt" else n)
        if sd is not None and not sd < SD_REL_MAX:
            sd = None  # not determined by the fit segments (and beyond exp's range)
        stderr[n] = None if sd is None else v * sd
        ci95[n] = None if sd is None else (v * math.exp(-1.96 * sd), v * math.exp(1.96 * sd))
        reasons[n] = NOTE_REFIT
    return replace(
        fit,
        model=Model(p, fit.model.effects),
        values=values,
        stderr=stderr,
        ci95=ci95,
        reasons=reasons,
        initial_states={},
    )


def _held_out(search: Search, fit: FitResult, periods: float, coef: FloatArray) -> Residuals:
    """Held-out residuals of ``fit``'s linear motor plus the angle cogging ``coef``."""
    p = fit.model.params
    leads = search.leads
    x = _design(
        p, [li.segment for li in leads], [li.samples for li in leads], periods, search.noise
    )
    return _shifted(search.held_out_residuals(fit), x, coef)


def _refitted(
    search: Search, base: Fitted, periods: float, held_gap: float, counts: Sequence[float] = ()
) -> tuple[FitResult, FloatArray, Residuals, float, float] | None:
    """The cogging candidate with the motor's parameters refitted (see the module
    notes): its fit (without the effect), coefficients, held-out residuals and fit-side
    gap; ``None`` where the refit's gain on held-out data is not the cogging's."""
    penalty = Scoring.for_baseline(base, search.cfg.thresholds).penalty
    if base.gap <= 2.0 * penalty:
        return None  # no two-parameter effect can be significant: nothing to refit for
    starts = [base.fit.model.params]
    for smooth in (False, True):
        try:
            starts.append(equation_error_start(search.split.fit, search.fixed, smooth=smooth))
        except FIT_ERRORS:
            pass
    with_cog = _refit(search, starts, periods, cogging=True)
    if with_cog is None:
        return None
    without = _refit(search, [with_cog.params], periods, cogging=False)
    plain_held = None
    if without is not None:
        plain_held = search.held_out_residuals(_with_params(base.fit, without.params, {}))
        # the count chosen again on the fit side with the refitted motor, among the
        # counts tried and the strongest of the angle spectrum of what it leaves on
        # held-out data (the baseline's bent parameters chose them: a gearmotor's 25
        # per turn read as 24, a scooter's 17 hidden under a misfit of 1300 noise
        # variances, the strongest count left by the refit)
        _, _, strongest = angle_harmonics(search.split.held_out, plain_held)
        more = _trial_counts(search.split.fit, [n for n in strongest if n not in counts])
        again = _best_count(search, without.params, without.fit_res, [*counts, *more])
        if again != periods:
            redo = _refit(search, [without.params, with_cog.params], again, cogging=True)
            if redo is not None and redo.cost < with_cog.cost:
                periods, with_cog = again, redo
    fit = _with_params(base.fit, with_cog.params, with_cog.stderr_rel)
    res = _held_out(search, fit, periods, with_cog.coef)
    # the linear motor without cogging: the refit, or the baseline where it does better
    plain_gap = base.gap
    evidence = None
    if without is not None and plain_held is not None:
        plain_gap = min(plain_gap, plain_held.gap())
        evidence = angle_evidence(search, without, plain_held, periods)
    gap = res.gap()
    # judged against the refit without cogging as a single effect against the
    # baseline: beyond its penalty, and closing what that refit leaves; or, where the
    # cogging's ripple is below the noise per sample, by the held-out evidence that
    # accumulates over the samples at its count (:func:`angle_evidence`)
    plain = Scoring.for_baseline(replace(base, gap=plain_gap), search.cfg.thresholds)
    search.say(
        f"candidate cogging ({periods:g} per turn), motor parameters refitted: held-out gap "
        f"{gap:.3g} (refitted without cogging {plain_gap:.3g}, held {held_gap:.3g})"
        + ("" if evidence is None else f"; {evidence.text()}")
    )
    by_gap = plain_gap - gap > 2.0 * plain.penalty and plain.closes(gap)
    by_angle = evidence is not None and evidence.shown and gap < plain_gap and plain.closes(gap)
    if not (gap < held_gap and (by_gap or by_angle)):
        return None
    if by_angle and not by_gap:
        search.notes.append(f"cogging ({periods:g} per turn): {evidence.text()}")  # type: ignore[union-attr]
    return fit, with_cog.coef, res, with_cog.fit_res.gap(), periods


def _best_count(
    search: Search, p: MotorParams, fit_res: Residuals, counts: Sequence[float]
) -> float:
    """The count of ``counts`` whose angle cogging (linear, ``p`` held) fits the fit
    segments' residuals ``fit_res`` best."""
    segs = search.split.fit
    costs = [
        _solve(_design(p, segs, [0] * len(segs), n, search.noise), fit_res)[1] for n in counts
    ]
    return float(counts[int(np.argmin(costs))])


@dataclass(frozen=True)
class AngleEvidence:
    """The held-out gain of a cogging at the candidate count against the same gain at
    off-harmonic counts (:func:`angle_evidence`), in noise variances summed over samples."""

    periods: float
    gain: float
    null: tuple[float, ...]

    @property
    def z(self) -> float:
        nul = np.asarray(self.null)
        sd = float(np.std(nul, ddof=1)) if nul.size > 1 else 0.0
        return (self.gain - float(np.mean(nul))) / sd if sd > 0 else 0.0

    @property
    def shown(self) -> bool:
        return (
            len(self.null) >= ANGLE_NULLS
            and self.gain > 0.0
            and self.gain > max(self.null)
            and self.z >= ANGLE_Z
        )

    def text(self) -> str:
        return (
            f"held-out gain at {self.periods:g} per turn {self.gain:.3g} noise variances "
            f"summed, {self.z:.1f} sd above the same gain at {len(self.null)} off-harmonic "
            f"counts (largest {max(self.null, default=math.nan):.3g})"
        )


def angle_evidence(
    search: Search, plain: _Refit, held: Residuals, periods: float
) -> AngleEvidence | None:
    """Evidence that accumulates over samples where a cogging's ripple is below the noise
    per sample: the cogging's (a, b) fitted on the fit segments' residuals of the linear
    motor ``plain`` (refitted without cogging), its gain on the held-out residuals
    ``held`` (their noise-weighted squared error, summed, less the same with the
    cogging's predicted ripple removed), against the same gain at ``ANGLE_NULLS``
    counts that no cogging of this count has (non-integer offsets from it, at least two
    resolution steps of the held-out angle away): a torque periodic in the angle at the
    count shows on held-out data, in phase with the fit side; elsewhere the fit side's
    coefficients fit noise and cost held-out error. The off-harmonic gains carry the
    record's own autocorrelated residuals, so the gain is judged on its own scale."""
    leads = search.leads
    if not leads:
        return None
    theta = np.concatenate([shaft_angle(li.segment)[li.samples :] for li in leads])
    turns = float(np.ptp(theta[np.isfinite(theta)])) / (2.0 * math.pi) if theta.size else 0.0
    if turns <= 0.0:
        return None
    step = max(ANGLE_NULL_STEP, 2.0 / turns)
    offsets = [(k + 0.5) * step for k in range(1, ANGLE_NULLS // 2 + 1)]
    nulls = [periods + s * d for d in offsets for s in (-1.0, 1.0) if periods + s * d > 0.5]
    segs = search.split.fit
    weights = {sg: 1.0 / search.noise.sigma[sg] ** 2 for sg in held.error}
    base_cost = sum(float(np.nansum(held.error[sg] ** 2)) * w for sg, w in weights.items())

    def gain(n: float) -> float:
        coef, _ = _solve(
            _design(plain.params, segs, [0] * len(segs), n, search.noise), plain.fit_res
        )
        x = _design(
            plain.params,
            [li.segment for li in leads],
            [li.samples for li in leads],
            n,
            search.noise,
        )
        moved = _shifted(held, x, coef)
        return base_cost - sum(
            float(np.nansum(moved.error[sg] ** 2)) * w for sg, w in weights.items()
        )

    return AngleEvidence(periods, gain(periods), tuple(gain(n) for n in nulls))


def _resolved_share(search: Search, p: MotorParams, effect: Cogging) -> float:
    """The share of the cogging's effect (its simulated response, noise-weighted, on the
    fit and the held-out samples) that falls on samples resolving its period."""
    n = effect.periods_per_rev
    coef = effect.torque_nm * np.array([math.cos(effect.phase_rad), math.sin(effect.phase_rad)])
    segs = [*search.split.fit, *(li.segment for li in search.leads)]
    skips = [0] * len(search.split.fit) + [li.samples for li in search.leads]
    on = total = 0.0
    for seg, k in zip(segs, skips, strict=True):
        x = _responses(p, seg, n, search.noise, k)
        e = sum((np.nan_to_num(x[sg]) @ coef) ** 2 / search.noise.sigma[sg] ** 2 for sg in x)
        ok = resolved_steps(shaft_angle(seg), n)[k:]
        on += float(np.sum(e[ok]))
        total += float(np.sum(e))
    return on / total if total > 0 else 1.0


def _size_reason(search: Search, p: MotorParams, effect: Cogging) -> str:
    """Why ``effect`` is too large for the record to have turned the rotor, or ''."""
    a, n = effect.torque_nm, effect.periods_per_rev
    if not (a > 0 and n > 0 and p.J > 0):
        return ""
    segs = [*search.split.fit, *search.split.held_out]
    w = np.concatenate([np.abs(s.speed_or_derivative()) for s in segs])
    cur = np.concatenate([s.current for s in segs if s.current is not None] or [np.zeros(1)])
    peak = abs(p.Kt) * float(np.nanmax(np.abs(cur)))
    turned = sum(float(np.nansum(np.abs(np.diff(shaft_angle(s))))) for s in segs)
    crossing = math.sqrt(4.0 * a / (n * p.J))  # kinetic energy J w^2/2 = the detent's 2A/N
    crawled = bool(np.any(w[np.isfinite(w)] < crossing))
    if not (crawled and n * turned > 20.0 * math.pi and a > peak):
        return ""
    return (
        f"cogging not named: {a:.3g} N*m at {n:g} periods per turn would hold the rotor in a "
        f"detent against every torque the record applied (Kt x peak current = {peak:.3g} N*m), "
        f"yet the rotor turned on from below {crossing:.3g} rad/s, too slow to roll over a "
        "detent: no cogging of that size"
    )


def implausible(search: Search, fit: FitResult) -> str:
    """Why the cogging in ``fit`` cannot be the record's (see the module notes: its
    period unresolved where its torque acts, or a size that would have stopped the
    rotor), or '' where it can."""
    effect = fit.model.effect("cogging")
    if not isinstance(effect, Cogging) or not effect.torque_nm > 0:
        return ""
    p = fit.model.params
    share = _resolved_share(search, p, effect)
    search.say(
        f"candidate cogging ({effect.periods_per_rev:g} per turn): {share:.0%} of its effect "
        "on samples that resolve its period"
    )
    if share < RESOLVED_SHARE_MIN:
        n, rate = effect.periods_per_rev, 1.0 / search.dt_s
        fastest = NYQUIST_PHASE_RAD * rate / n  # rad/s: half a period per sample
        return (
            f"cogging not named: its {n:g} periods per turn are not resolved by the sampling "
            f"where its fitted torque acts: {share:.0%} of its effect lies on samples where it "
            f"moves less than half a period per sample (below {fastest:.3g} rad/s at "
            f"{rate:.4g} Hz); aliased, sin/cos({n:g} theta) fit the residual by chance"
        )
    return _size_reason(search, p, effect)


def _trial_counts(segs: Sequence[Segment], periods: Sequence[int | float]) -> list[float]:
    """The counts tried on the fit segments: each of ``periods``; one from the wide
    search (:func:`~pmdc_ident.core.diagnosis.localization.wide_peaks`: not an integer,
    or above ``MAX_HARMONIC``) also on a grid of ``REFINE_STEPS`` around it, a quarter of
    the fit side's resolution apart (1 / its turns spanned; the held-out spectrum's own
    may be coarser, and a count off by 1 / turns slips a whole period over the record)."""
    out: list[float] = []
    theta = np.concatenate([shaft_angle(s) for s in segs])
    turns = float(np.ptp(theta[np.isfinite(theta)])) / (2.0 * math.pi) if theta.size else 0.0
    for n in periods:
        n = float(n)
        if (n != round(n) or n > MAX_HARMONIC) and turns > 0:
            d = 0.25 / turns
            out += [n + k * d for k in range(-REFINE_STEPS, REFINE_STEPS + 1) if n + k * d > 0]
        else:
            out.append(n)
    return out


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
        tried = _trial_counts(fit_segs, periods)
        for n in tried:
            x = _design(p, fit_segs, [0] * len(fit_segs), n, search.noise)
            coef, cost = _solve(x, fit_res)
            if best is None or cost < best[0]:
                best = (cost, n, coef)
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
    fit_gap = _shifted(fit_res, x_fit, coef).gap()
    search.say(f"candidate cogging ({n_best:g} per turn): held-out gap {res.gap():.3g}")
    motor, note = base.fit, NOTE
    try:
        again = _refitted(search, base, n_best, res.gap(), tried)
    except FIT_ERRORS as exc:
        search.say(f"candidate cogging: refit failed ({exc})")
        again = None
    if again is not None:
        motor, coef, res, fit_gap, n_best = again
        note = NOTE_REFIT
    amp, phase = float(math.hypot(coef[0], coef[1])), float(math.atan2(coef[1], coef[0]))
    effect = Cogging(amp, n_best, phase)
    fit = replace(
        motor,
        model=motor.model.with_effects(effect),
        values={**motor.values, **{f"cogging.{k}": v for k, v in effect.as_dict().items()}},
        reasons={**motor.reasons, "cogging.torque_nm": note, "cogging.phase_rad": note},
    )
    why = implausible(search, fit)
    if why:
        search.say(why)
        search.notes.append(why)
    out = Fitted(("cogging",), fit, res, res.gap(), time.perf_counter() - t0, failed=bool(why))
    return out, fit_gap
