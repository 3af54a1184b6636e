"""Designing the shortest plan that reaches a target: greedy optimal design in time.

From the prior's state (at rest, at the start position), every candidate segment of
the family (:mod:`.family`) is simulated with the prior model (every effect it
carries), checked against the limits (:mod:`.limits`) and scored by the information it
adds (:mod:`.information`): the **A-optimal** criterion sums each targeted parameter's
relative variance over its target's square (a parameter already at its target counts
as met and no more); the **D-optimal** one is the log-determinant of the information.
The segment with the largest gain per second of motor time is appended and the motor's
state carried on, until the predicted relative sd of every targeted parameter is below
its target times a design margin. The last segment is then cut as short as the target
allows, and any segment whose removal (the rest re-simulated from the start) still
meets the target is dropped.

Which limit binds is measured, not guessed: at every choice, the best segment of the
whole family (the limits ignored, probes above the voltage limit included) is compared
with the best one the limits allow; the limit that turned the better ones away, weighed
by the information per second lost, is the one that binds.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.design.family import MIN_SAMPLES, Candidate, Scales, candidates
from pmdc_ident.core.design.information import (
    DESIGN_PARAMETERS,
    InformationModel,
    lag_bias,
    relative_sd,
    segment_information,
    segment_lag_terms,
    systematic_rsd,
    with_systematic,
)
from pmdc_ident.core.design.limits import PlanLimits, Violation, late_stop
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.design.target import DEFAULT_TARGET, describe_target, public_name
from pmdc_ident.core.errors import ParameterError, option_name
from pmdc_ident.core.excitation import PlannedSegment, TestPlan
from pmdc_ident.core.model import simulate

__all__ = ["DesignedPlan", "PlanPiece", "design_plan", "evaluate_plan"]

FloatArray = NDArray[np.float64]
REG_SD = 100.0  # the design's own prior, 1e4 % relative sd: keeps one segment's criterion finite
DESIGN_MARGIN = 0.9  # the plan aims at this fraction of each target
PRIOR_MARGIN_CAP = 0.5  # ... and lower by at most 1 / 1.5 for a parameter the prior knows badly
UNREACHABLE_FACTOR = 10.0  # a default-target parameter 10x off at the budget is not pursued
UNREACHABLE_L = 3.0  # ... L 3x off, when L/R is below the sample period
SHORTEN_INNER = 4  # segments before the last cut as short as the target allows
FLOOR_SHARE = 0.8  # a parameter whose systematic sd alone is this share of its target: dropped
MAX_ROUNDS = 200
NUISANCE_TC = 1e-3  # A x Ke: a Coulomb torque the prior lacks, as a direction only
PATTERN_CAP_TAU = 40.0  # a repeated pattern at most this many tau_m long
B_FLOOR = 0.01  # the design's B at least this share of the electrical damping Ke^2 / R
# what pins each parameter down, for the reason a parameter is left short
ADVICE = {
    "R": "the current at a step's start (V/R before the back-EMF builds)",
    "L": "the current's rise over L/R, which must span samples",
    "Ke": "steady speeds at several voltages",
    "J": "transients sampled well inside the mechanical time constant",
    "B": "steady speeds far apart (or long coasts), since B separates from the Coulomb "
    "torque only by speed",
    "Tc": "slow speeds in both directions",
}


@dataclass(frozen=True)
class PlanPiece:
    """One segment of a designed plan."""

    label: str
    candidate: Candidate
    start_s: float
    info_share: float = 0.0  # share of the criterion's gain this segment brought


@dataclass
class _State:
    x: FloatArray  # [i, w, theta]
    heat: float
    t: float


@dataclass(frozen=True)
class _Eval:
    cand: Candidate
    info: FloatArray
    violation: Violation | None
    end: FloatArray
    heat: float
    peak_i: float
    peak_w: float
    pos: tuple[float, float]


@dataclass(frozen=True)
class DesignedPlan:
    """A designed plan, what it is predicted to reach and what limits it."""

    plan: TestPlan
    pieces: tuple[PlanPiece, ...]
    prior: Prior
    limits: PlanLimits
    target: dict[str, float]  # what the plan aims at (parameters dropped removed)
    requested: dict[str, float]
    predicted_rsd: dict[str, float]
    met: bool
    short: dict[str, str]  # parameter -> why it misses its target
    dropped: dict[str, str]  # parameter -> why it is not targeted
    binding: str  # the limit that binds ("none" when no limit turned a better segment away)
    binding_detail: str
    criterion: str
    duration_s: float
    peak_current_a: float
    peak_speed_rad_s: float
    heat_a2s: float
    position_range_rad: tuple[float, float]
    trajectory: dict[str, FloatArray] = field(repr=False)
    prior_seconds: float = 0.0  # seconds of data already in hand (a pre-test)
    notes: tuple[str, ...] = ()
    # the revealed effects' predicted detection limits (``plan_experiment(reveal_sizes=)``)
    reveal_limits: tuple[Any, ...] = ()

    @property
    def dt_s(self) -> float:
        return self.plan.dt_s

    def segment_rows(self) -> list[dict[str, object]]:
        return [
            {
                "label": p.label,
                "kind": p.candidate.kind,
                "start_s": round(p.start_s, 6),
                "duration_s": round(p.candidate.n * self.dt_s, 6),
                "what": p.candidate.describe(),
                "info_share": round(p.info_share, 4),
            }
            for p in self.pieces
        ]

    def summary_lines(self) -> list[str]:
        lines = [f"prior: {self.prior.describe()}", f"limits: {self.limits.describe()}"]
        lines.append(
            f"target: {describe_target(self.requested)} relative sd ({self.criterion}-optimal "
            f"design, aiming at {DESIGN_MARGIN:.0%} of each)"
        )
        for name, why in self.dropped.items():
            lines.append(f"  not targeted: {public_name(name)}: {why}")
        lines.append(f"plan ({len(self.pieces)} segments, {self.duration_s:.4g} s of motor time):")
        for row in self.segment_rows():
            lines.append(
                f"  {row['label']:<12} {row['start_s']:>8.4g} s  {row['duration_s']:>7.4g} s  "
                f"{row['what']}"
            )
        lo, hi = self.position_range_rad
        lines.append(
            f"predicted under the prior: peak current {self.peak_current_a:.3g} A, peak speed "
            f"{self.peak_speed_rad_s:.4g} rad/s, heat {self.heat_a2s:.4g} A^2*s, position "
            f"{lo:.4g}..{hi:.4g} rad"
        )
        sds = ", ".join(
            f"{public_name(k)} {100 * v:.3g} %" if math.isfinite(v) else f"{public_name(k)} -"
            for k, v in self.predicted_rsd.items()
        )
        lines.append(f"predicted relative sd: {sds}")
        lines.append(
            f"binding limit: {self.binding}"
            + (f" ({self.binding_detail})" if self.binding_detail else "")
        )
        if self.met:
            lines.append("target met by the plan (predicted)")
        for name, why in self.short.items():
            lines.append(f"SHORT: {public_name(name)}: {why}")
        lines += [f"note: {n}" for n in self.notes]
        return lines

    def to_json(self) -> dict[str, object]:
        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "prior": self.prior.describe(),
            "limits": self.limits.describe(),
            "criterion": self.criterion,
            "target": {public_name(k): v for k, v in self.requested.items()},
            "targeted": {public_name(k): v for k, v in self.target.items()},
            "dropped": {public_name(k): v for k, v in self.dropped.items()},
            "duration_s": self.duration_s,
            "prior_seconds": self.prior_seconds,
            "segments": self.segment_rows(),
            "predicted_rsd": {public_name(k): num(v) for k, v in self.predicted_rsd.items()},
            "met": self.met,
            "short": {public_name(k): v for k, v in self.short.items()},
            "binding": self.binding,
            "binding_detail": self.binding_detail,
            "peak_current_a": self.peak_current_a,
            "peak_speed_rad_s": self.peak_speed_rad_s,
            "heat_a2s": self.heat_a2s,
            "position_range_rad": list(self.position_range_rad),
            "notes": list(self.notes),
            "reveal_limits": {d.effect: d.to_json() for d in self.reveal_limits},
        }


class _Designer:
    def __init__(
        self,
        prior: Prior,
        limits: PlanLimits,
        dt_s: float,
        names: Sequence[str],
        target: Mapping[str, float],
        criterion: str,
        prior_info: FloatArray | None,
        values: Mapping[str, float],
        prior_rsd: Mapping[str, float] | None = None,
    ) -> None:
        self.prior = prior
        self.limits = limits
        self.dt = dt_s
        self.im = InformationModel.build(values, names, dt_s, prior.noise)
        self.names = self.im.names
        self.target = dict(target)
        self.criterion = criterion
        self.sc = Scales.of(prior, limits, dt_s)
        k = len(self.names)
        self.reg = np.eye(k) / REG_SD**2
        self.info0 = np.zeros((k, k)) if prior_info is None else np.asarray(prior_info, float)
        self.pessimistic = prior.pessimistic()
        self.history: list[Candidate] = []  # chosen so far (their patterns are candidates)
        self.lost: dict[str, float] = {}
        self.floor: dict[str, float] = {}  # systematic relative sd (information.systematic_rsd)
        self.lag_rsd: dict[str, float] = {}  # the plan's lag bias as an sd (_lag_rsd)
        self.prior_voltages: tuple[FloatArray, ...] = ()  # the segments behind info0
        # a prior known to +-r: the truth may lie r below it, and a parameter's relative
        # sd grows as its value falls: aim lower by that much (at most by a third: a
        # sequential session re-fits as data come and stops once the target is met)
        rsd0 = dict(prior_rsd or {})
        self.prior_rsd = rsd0
        self.aim = {
            n: DESIGN_MARGIN / (1.0 + min(max(rsd0.get(n, 0.0), 0.0), PRIOR_MARGIN_CAP))
            for n in self.target
        }

    # -- criterion ---------------------------------------------------------------------
    def rsd(self, info: FloatArray) -> dict[str, float]:
        return relative_sd(info, self.names)

    def _var(self, info: FloatArray) -> FloatArray:
        m = info + self.reg
        d = np.sqrt(np.clip(np.diag(m), 1e-300, None))
        try:  # scaled to a unit diagonal: the parameters' information spans decades
            return np.diag(np.linalg.inv(m / np.outer(d, d))) / d**2
        except np.linalg.LinAlgError:
            return np.full(len(self.names), REG_SD**2)

    def phi(self, info: FloatArray) -> float:
        if self.criterion == "D":
            sign, logdet = np.linalg.slogdet(info + self.reg)
            return -logdet if sign > 0 else math.inf
        var = self._var(info)
        total = 0.0
        for k, n in enumerate(self.names):
            if n in self.target:
                total += max(var[k] / (self.aim[n] * self.target[n]) ** 2, 1.0)
        return total

    def met(self, info: FloatArray) -> bool:
        rsd = self.rsd(info)
        return all(rsd[n] <= self.aim[n] * t for n, t in self.target.items())

    # -- one segment -------------------------------------------------------------------
    def evaluate(self, cand: Candidate, st: _State, *, limits: PlanLimits | None = None) -> _Eval:
        lim = limits or self.limits
        v = cand.voltage
        sim = simulate(self.prior.model, v, self.dt, x0=st.x)
        cur = np.where(np.isnan(v), 0.0, sim.current)
        heat = st.heat + float(np.sum(cur**2) * self.dt)
        # the samples and the state the segment ends in (where the next one starts)
        end = sim.final_state
        pos = np.append(sim.position, end[2])
        spd = np.append(sim.speed, end[1])
        stop = None
        if lim.travel_rad is not None:
            i_all = np.append(cur, end[0] if np.isfinite(v[-1]) else 0.0)
            v_all = np.append(v, v[-1])
            stop = pos + late_stop(
                self.prior.model, v_all, spd, i_all, lim.safe_mode, lim.command_delay_s
            )
        viol = lim.check(v, cur, spd, pos, heat, stop, from_rad=float(st.x[2]))
        if cand.probe and viol is None:
            viol = Violation(cand.probe, "probe")
        if viol is None:
            viol = self._pessimistic(v, st, lim)
        info = segment_information(self.im, v, cur, sim.speed, sim.position)
        return _Eval(
            cand,
            info,
            viol,
            sim.final_state[:3].copy(),
            heat,
            float(np.max(np.abs(cur))) if cur.size else 0.0,
            float(np.max(np.abs(sim.speed))),
            (float(sim.position.min()), float(sim.position.max())),
        )

    def _pessimistic(self, v: FloatArray, st: _State, lim: PlanLimits) -> Violation | None:
        """The aborts (not their share) and the travel range for a motor that draws more
        and runs farther than the prior (:meth:`Prior.pessimistic`)."""
        ps = simulate(self.pessimistic, v, self.dt, x0=st.x)
        pcur = np.where(np.isnan(v), 0.0, ps.current)
        if float(np.max(np.abs(pcur))) > lim.current_max_a:
            return Violation("current", "a motor drawing more than the prior would trip it")
        pspd = np.append(ps.speed, ps.final_state[1])
        if float(np.max(np.abs(pspd))) > lim.speed_max_rad_s:
            return Violation("speed", "a motor faster than the prior would trip it")
        if lim.travel_rad is None:
            return None
        ppos = np.append(ps.position, ps.final_state[2])
        pi = np.append(pcur, ps.final_state[0] if np.isfinite(v[-1]) else 0.0)
        v_all = np.append(v, v[-1])
        pstop = ppos + late_stop(
            self.pessimistic, v_all, pspd, pi, lim.safe_mode, lim.command_delay_s
        )
        lo, hi = lim.travel_rad
        if min(ppos.min(), pstop.min()) < lo or max(ppos.max(), pstop.max()) > hi:
            return Violation("travel", "a faster motor than the prior would leave the range")
        return None

    def patterns(self) -> list[Candidate]:
        """The last one, two or four segments chosen, repeated two or four times as one
        segment: a plan that needs many of the same runs grows by doubling, not by one
        short segment per round (and one initial state instead of many to fit)."""
        out = []
        cap = max(int(PATTERN_CAP_TAU * self.sc.unit_s / self.dt), 4 * MIN_SAMPLES)
        for k in (1, 2, 4):
            if len(self.history) < k:
                break
            unit = np.concatenate([c.voltage for c in self.history[-k:]])
            for m in (2, 4):
                if unit.size * m > cap:
                    break
                out.append(
                    Candidate("pattern", "pattern", np.tile(unit, m), {"segments": k, "times": m})
                )
        return out

    def choose(self, info: FloatArray, st: _State) -> tuple[_Eval | None, list[_Eval]]:
        base = self.phi(info)
        evals = []
        best_ok, best_ok_rate = None, 0.0
        best_any_rate, best_any_reason = 0.0, ""
        gains: list[float] = []
        family = candidates(self.prior, self.limits, self.sc, float(st.x[1]), float(st.x[2]))
        for cand in family + self.patterns():
            dur = cand.n * self.dt
            ev = self.evaluate(cand, st)
            if ev.violation is None and st.t + dur > self.limits.budget_s + 1e-9:
                ev = replace(ev, violation=Violation("time", "beyond the budget"))
            evals.append(ev)
            gain = base - self.phi(info + ev.info)
            gains.append(gain)
            rate = gain / dur
            if rate > best_any_rate:
                best_any_rate = rate
                best_any_reason = ev.violation.limit if ev.violation else ""
            if ev.violation is None and rate > best_ok_rate:
                best_ok, best_ok_rate = ev, rate
        if best_any_reason and best_ok is not None and best_ok_rate > 0:
            lost = math.log(best_any_rate / best_ok_rate) * best_ok.cand.n * self.dt
            self.lost[best_any_reason] = self.lost.get(best_any_reason, 0.0) + lost
        elif best_ok is None:
            # nothing fits: the limit that turns most of the useful segments away ends it
            why = [
                e.violation.limit
                for e, g in zip(evals, gains, strict=True)
                if g > 0 and e.violation
            ]
            if why:
                top = max(set(why), key=why.count)
                self.lost[top] = self.lost.get(top, 0.0) + 1e3
        return (best_ok if best_ok_rate > 0 else None), evals

    # -- whole plans -------------------------------------------------------------------
    def replay(
        self, cands: Sequence[Candidate], start: _State
    ) -> tuple[list[_Eval], FloatArray, _State]:
        st = _State(start.x.copy(), start.heat, start.t)
        info = self.info0.copy()
        out = []
        for c in cands:
            ev = self.evaluate(c, st)
            out.append(ev)
            info = info + ev.info
            st = _State(ev.end, ev.heat, st.t + c.n * self.dt)
        return out, info, st

    def feasible(self, evs: Sequence[_Eval]) -> bool:
        return all(e.violation is None for e in evs)


def _truncate(c: Candidate, n: int) -> Candidate:
    return replace(c, voltage=c.voltage[:n].copy())


def design_plan(
    prior: Prior,
    limits: PlanLimits,
    dt_s: float,
    target: Mapping[str, float] | None = None,
    *,
    criterion: str = "A",
    fixed: Sequence[str] = (),
    prior_info: FloatArray | None = None,
    prior_seconds: float = 0.0,
    start_state: Sequence[float] | None = None,
    label_start: int = 1,
    user_target: bool = False,
    extra: Sequence[Candidate] = (),
    prior_rsd: Mapping[str, float] | None = None,
    aim_scale: Mapping[str, float] | None = None,
    prior_voltages: Sequence[FloatArray] = (),
) -> DesignedPlan:
    """The shortest plan (greedy, see the module docs) reaching ``target`` (default
    :data:`~pmdc_ident.core.design.target.DEFAULT_TARGET`) under ``limits``.

    ``prior_info``: information already in hand (a pre-test's, in the order of the
    free parameters); ``start_state``: ``[i, w, theta]`` the plan starts from (default
    at rest at ``limits.start_rad``); ``user_target``: the target was asked for, so a
    parameter out of reach is reported short rather than dropped; ``extra``: segments
    that must run first (a reveal plan's), designed around; ``prior_rsd``: how well
    the prior is known (relative sd per parameter, a pre-test's fit): the plan aims
    lower for a parameter whose true value may lie below the prior's; ``aim_scale``:
    per parameter, a factor on what the plan aims at (a sequential session's fit found
    a parameter worse known than this information predicts: it aims lower by as much);
    ``prior_voltages``: the commands of the segments behind ``prior_info``, in the order
    they ran from rest (a sequential session's record so far): a current read late
    biases their fit too, and the plan's predicted sds count it (:func:`_lag_rsd`).
    """
    if criterion not in ("A", "D"):
        msg = f"criterion must be A or D, got {criterion!r}"
        raise ParameterError(msg)
    if not (math.isfinite(dt_s) and dt_s > 0):
        msg = f"sample period must be > 0 s, got {dt_s}"
        raise ParameterError(msg)
    requested = dict(DEFAULT_TARGET if target is None else target)
    values, names = design_values(prior, fixed, prior_rsd)
    dropped: dict[str, str] = {}
    notes: list[str] = []
    for n in requested:
        if n in fixed:
            dropped[n] = "fixed (not fitted)"
        elif n == "Tc" and prior.coulomb_nm <= 0:
            dropped[n] = (
                "the prior has no Coulomb friction: fitted as a nuisance (the plan keeps it "
                "apart from B), not targeted"
            )
    if (
        "L" in requested
        and target is None
        and prior_rsd is not None
        and prior_rsd.get("L", 0.0) > 3.0 * requested["L"]
        and prior.model.params.electrical_time_constant_s < dt_s
    ):
        # a pre-test's L: where L/R is below the sample period its own fit hardly knows
        # it, and the plan would chase it with the whole budget
        dropped["L"] = (
            f"L/R ({prior.model.params.electrical_time_constant_s * 1e6:.3g} us, known to "
            f"{100 * prior_rsd['L']:.2g} %) is below the sample period {dt_s * 1e6:.3g} us: "
            "sample faster or fix L from an LCR meter"
        )
    # what the information cannot see (a lag of the current reading biases L): a
    # parameter whose bias alone may reach its target is out of reach of any plan
    floor = systematic_rsd(values, prior.noise, dt_s)
    for n, f in floor.items():
        if n in requested and n not in dropped and f >= FLOOR_SHARE * requested[n]:
            lag = prior.noise.current_lag(dt_s)
            why = (
                f"a current reading up to {lag * 1e6:.3g} us late (an anti-alias filter, the "
                f"ADC's timing: the model has no lag) biases {n} by up to {196 * f:.2g} %, "
                "whatever the plan: fix L from an LCR meter, or give the signal chain's lag "
                f"({option_name('current_lag_us')})"
            )
            if user_target:
                notes.append(f"{n}: {why}")
            else:
                dropped[n] = why
    aim = {k: v for k, v in requested.items() if k not in dropped}
    d = _Designer(prior, limits, dt_s, names, aim, criterion, prior_info, values, prior_rsd)
    d.floor = floor
    d.prior_voltages = tuple(np.asarray(v, float) for v in prior_voltages)
    for n, k in (aim_scale or {}).items():
        if n in d.aim and k > 0:
            d.aim[n] *= k
    for n, f in floor.items():
        if n in d.aim:  # the information's share of the target: the rest is the bias
            d.aim[n] *= math.sqrt(max(1.0 - (f / d.target[n]) ** 2, (1.0 - FLOOR_SHARE**2)))
    x0 = (
        np.array([0.0, 0.0, limits.start_rad])
        if start_state is None
        else np.asarray(start_state, float)
    )
    start = _State(x0.copy(), 0.0, 0.0)
    # segments asked for (reveal) come first, as they are
    forced = list(extra)
    evs, info, st = d.replay(forced, start)
    for ev in evs:
        if ev.violation is not None:
            msg = (
                f"the {ev.cand.kind} segment asked for breaks the {ev.violation.limit} limit "
                f"({ev.violation.detail}) under the prior"
            )
            raise ParameterError(msg)
    chosen, evs, info = _greedy(d, forced, start, info, st, dropped, user_target)
    if limits.travel_rad is None and not user_target:
        chosen, evs, info = _with_coastdown(d, forced, start, (chosen, evs, info), dropped)
    d.lag_rsd = _lag_rsd(d, forced + chosen, start)
    return _result(
        d, forced + chosen, evs, info, requested, dropped, prior_seconds, label_start, notes
    )


def _lag_rsd(d: _Designer, cands: Sequence[Candidate], start: _State) -> dict[str, float]:
    """Per parameter, half the bias a current reading up to ``current_lag`` late leaves
    in the fit of this plan (:func:`~.information.lag_bias`), as a standard deviation.

    Not only L's: the slow decay of the current after a step, read late, moves R, J and
    the friction too (on the independent generator's coreless, gearmotor and servo motors
    the predicted intervals missed R, J and Tc that way: coverage 80-85 %). The segments
    behind the information in hand (``d.prior_voltages``, a pre-test's) add their part of
    the bias (their information is in ``d.info0`` already); without them that information
    counts as unbiased, and where it is a large share the bias is under-stated."""
    noise = d.prior.noise
    lag = noise.current_lag(d.dt)
    if lag <= 0 or noise.current_sd <= 0 or not cands:
        return {}
    info = d.reg.copy()
    grad = np.zeros(len(d.names))
    x = np.zeros(3)
    for v in d.prior_voltages:
        sim = simulate(d.prior.model, v, d.dt, x0=x)
        cur = np.where(np.isnan(v), 0.0, sim.current)
        grad = grad + segment_lag_terms(d.im, v, cur, sim.speed, sim.position, lag)[1]
        x = sim.final_state[:3].copy()
    x = start.x.copy()
    for c in cands:
        sim = simulate(d.prior.model, c.voltage, d.dt, x0=x)
        cur = np.where(np.isnan(c.voltage), 0.0, sim.current)
        i_s, g_s = segment_lag_terms(d.im, c.voltage, cur, sim.speed, sim.position, lag)
        info, grad = info + i_s, grad + g_s
        x = sim.final_state[:3].copy()
    return {n: abs(b) / 1.96 for n, b in lag_bias(info + d.info0, grad, d.names).items()}


def _greedy(
    d: _Designer,
    forced: list[Candidate],
    start: _State,
    info: FloatArray,
    st: _State,
    dropped: dict[str, str],
    user_target: bool,
    first_choice: Candidate | None = None,
) -> tuple[list[Candidate], list[_Eval], FloatArray]:
    """The greedy rounds from ``st`` (``info`` in hand): each adds the segment with the
    most criterion gain per second, until the target is met or nothing fits; then the
    plan shortened (:func:`_shorten`) and ended at rest where the hold needs it.
    ``first_choice``: the first segment, given (see :func:`_with_coastdown`)."""
    chosen: list[Candidate] = []
    first = first_choice is None
    if first_choice is not None:
        ev = d.evaluate(first_choice, st)
        chosen.append(first_choice)
        d.history.append(first_choice)
        info = info + ev.info
        st = _State(ev.end, ev.heat, st.t + first_choice.n * d.dt)
    for _ in range(MAX_ROUNDS):
        if d.met(info):
            break
        best, evals = d.choose(info, st)
        if first and not user_target:
            newly = _unreachable(d, evals, info)
            for n, why in newly.items():
                dropped[n] = why
                d.target.pop(n, None)
            first = False
            if d.met(info):
                break
            if newly:
                best, evals = d.choose(info, st)
        first = False
        if best is None:
            # the budget: the best segment cut to what is left
            left = int((d.limits.budget_s - st.t) / d.dt)
            if left >= MIN_SAMPLES:
                cuts = [
                    _truncate(e.cand, left) for e in evals if e.cand.n > left and not e.cand.probe
                ]
                fits = [d.evaluate(c, st) for c in cuts]
                fits = [f for f in fits if f.violation is None]
                if fits:
                    base = d.phi(info)
                    best = max(fits, key=lambda f: base - d.phi(info + f.info))
            if best is None:
                break
        chosen.append(best.cand)
        d.history.append(best.cand)
        info = info + best.info
        st = _State(best.end, best.heat, st.t + best.cand.n * d.dt)
    chosen = _shorten(d, forced, _merged(chosen), start)
    evs, info, st = d.replay(forced + chosen, start)
    stop = _stop(d, st)
    if stop is not None:
        chosen.append(stop)
        evs, info, st = d.replay(forced + chosen, start)
    return chosen, evs, info


def _with_coastdown(
    d: _Designer,
    forced: list[Candidate],
    start: _State,
    plan: tuple[list[Candidate], list[_Eval], FloatArray],
    dropped: dict[str, str],
) -> tuple[list[Candidate], list[_Eval], FloatArray]:
    """The greedy plan, or one that starts with a coast-down where that is shorter.

    A coast-down's information on B grows much faster than its length, while the greedy
    rates each segment by its gain per second where it stands: with B known to tens of
    percent, a short level halves B's variance for a tenth of a second and always rates
    above the coast that would end the plan, so the greedy climbs by levels (the
    industrial motor: B from 40 % to 1 % in 4.7 s of levels and short coasts, where one
    spin-up and a 2.6 s coast reach it). The greedy is run again from each coast-down of
    the family (:func:`~.family.coastdowns`) that fits the limits, and the shortest plan
    that meets the target is kept (the greedy's own on a tie)."""
    from pmdc_ident.core.design.family import coastdowns

    chosen, evs, info = plan
    if not chosen:
        return plan  # the information in hand meets the target
    best = plan
    best_s = sum(c.n for c in chosen) * d.dt if d.met(info) else math.inf
    lost = dict(d.lost)
    _, info0, st = d.replay(forced, start)
    fits = [
        cd
        for cd in coastdowns(d.prior, d.sc)
        if st.t + cd.n * d.dt <= d.limits.budget_s + 1e-9 and not d.evaluate(cd, st).violation
    ]
    # one direction (the design's CPU: a greedy run each): the way the rotor turns, no
    # reversal (either way at rest)
    way = 1.0 if st.x[1] >= 0 else -1.0
    same = [cd for cd in fits if cd.settings["v"] * way > 0]
    for cd in same or fits:
        d.history, d.lost = [], {}
        alt = _greedy(d, forced, start, info0, st, dropped, False, cd)
        alt_s = sum(c.n for c in alt[0]) * d.dt
        if d.met(alt[2]) and alt_s < best_s:
            best, best_s, lost = alt, alt_s, dict(d.lost)
    d.lost = lost
    return best


def design_values(
    prior: Prior, fixed: Sequence[str] = (), prior_rsd: Mapping[str, float] | None = None
) -> tuple[dict[str, float], list[str]]:
    """The fitted model's values at the prior and its free parameters. Without a Coulomb
    friction in the prior, its torque is still a free nuisance (a real motor has one,
    and ``identify`` tries it): placed at a small value, which sets its column's
    direction only, so the plan keeps B apart from it."""
    values = prior.fitted_values()
    if values["Tc"] <= 0:
        values["Tc"] = NUISANCE_TC * prior.model.params.Ke
    # a B fitted to ~0 (a short pre-test: friction took it all) leaves its relative sd
    # without meaning; design for a small viscous friction instead (the safe side)
    p = prior.model.params
    unknown_b = (prior_rsd or {}).get("B", 0.0) > 0.5 or values["B"] < 1e-3 * p.Ke**2 / p.R
    if unknown_b:
        values["B"] = max(values["B"], B_FLOOR * p.Ke**2 / p.R)
    names = [n for n in DESIGN_PARAMETERS if n not in fixed]
    return values, names


def _unreachable(d: _Designer, evals: Sequence[_Eval], info: FloatArray) -> dict[str, str]:
    """Default-target parameters the whole family cannot bring near their target within
    the budget (at its average information per second): dropped, with the reason."""
    ok = [e for e in evals if e.violation is None or e.violation.limit == "time"]
    if not ok:
        return {}
    rate = sum(e.info for e in ok) / sum(e.cand.n * d.dt for e in ok)
    at_budget = d.rsd(info + rate * d.limits.budget_s)
    out = {}
    for n, t in d.target.items():
        if n in ("R", "Ke", "J"):
            continue  # a motor model needs them: short, never dropped
        if d.prior_rsd.get(n, 0.0) > 0.3:
            continue  # the prior hardly knows it: the data will say, not this prior
        r = at_budget.get(n, math.inf)
        factor = UNREACHABLE_L if n == "L" and d.sc.tau_e_s < d.dt else UNREACHABLE_FACTOR
        if r > factor * t:
            what = "not determined" if not math.isfinite(r) else f"about {100 * r:.2g} %"
            why = f"out of reach within {d.limits.budget_s:.3g} s ({what} at the family's average)"
            if n == "L" and d.sc.tau_e_s < d.dt:
                why += (
                    f": L/R = {d.sc.tau_e_s * 1e6:.3g} us is below the sample period "
                    f"{d.dt * 1e6:.3g} us; sample faster or fix L from an LCR meter"
                )
            else:
                why += f"; it needs {ADVICE.get(n, '')}"
            out[n] = why
    return out


def _shorten(
    d: _Designer, forced: list[Candidate], chosen: list[Candidate], start: _State
) -> list[Candidate]:
    """The last segment as short as the target allows; segments whose removal keeps the
    target met (the rest re-simulated from the start) dropped."""
    if not chosen:
        return chosen
    evs, info, _ = d.replay(forced + chosen, start)
    if not d.met(info):
        return chosen
    changed = True
    while changed and len(chosen) > 1:
        changed = False
        # least useful first: the smallest gain per second within the plan
        order = sorted(range(len(chosen)), key=lambda k: _gain(d, info, evs[len(forced) + k]))
        for k in order:
            trial = chosen[:k] + chosen[k + 1 :]
            t_evs, t_info, _ = d.replay(forced + trial, start)
            if d.feasible(t_evs) and d.met(t_info):
                chosen, evs, info = trial, t_evs, t_info
                changed = True
                break
    chosen = _shorten_inner(d, forced, chosen, start)
    # the last one as short as the target allows (bisection on its samples)
    head = forced + chosen[:-1]
    last = chosen[-1]
    h_evs, h_info, h_st = d.replay(head, start)
    lo, hi = MIN_SAMPLES, last.n
    while hi - lo > max(2, hi // 50):
        mid = (lo + hi) // 2
        ev = d.evaluate(_truncate(last, mid), h_st)
        if ev.violation is None and d.met(h_info + ev.info):
            hi = mid
        else:
            lo = mid
    ev = d.evaluate(_truncate(last, hi), h_st)
    if ev.violation is None and d.met(h_info + ev.info):
        chosen = chosen[:-1] + [_truncate(last, hi)]
    return chosen


def _shorten_inner(
    d: _Designer, forced: list[Candidate], chosen: list[Candidate], start: _State
) -> list[Candidate]:
    """The longest segments before the last (``SHORTEN_INNER`` of them) each as short as
    the target allows, the rest re-simulated from it. The greedy holds a level while a
    later segment cannot pay yet (a coast-down pays only from the top speed): the servo
    motor's plan held -24 V for 0.69 s (32 tau_m) before its coasts, where 0.1 s left
    every predicted sd within 1 % (B 0.624 against 0.617 %)."""
    if d.limits.travel_rad is not None:
        # a joint's plan runs in parts, each designed again from the measured angle: cut
        # to the bone, the first design left the node's travel-limited session (test/
        # nodes/test_plan_auto_dds.py) 2.51 s of motor time against 1.97 s planned
        return chosen
    inner = sorted(range(len(chosen) - 1), key=lambda k: -chosen[k].n)[:SHORTEN_INNER]
    for k in inner:
        seg = chosen[k]
        if seg.n <= 2 * MIN_SAMPLES:
            continue

        def trial(
            m: int, k: int = k, seg: Candidate = seg, now: list[Candidate] = chosen
        ) -> list[Candidate] | None:
            t = now[:k] + [_truncate(seg, m)] + now[k + 1 :]
            t_evs, t_info, _ = d.replay(forced + t, start)
            return t if d.feasible(t_evs) and d.met(t_info) else None

        lo, hi = MIN_SAMPLES, seg.n
        best = None
        while hi - lo > max(2, seg.n // 20):
            mid = (lo + hi) // 2
            got = trial(mid)
            if got is not None:
                hi, best = mid, got
            else:
                lo = mid
        if best is not None:
            chosen = best
    return chosen


HOLD_TAU = 5.0  # after the plan the session holds 0 V (or opens): checked this long


def _hold_ok(d: _Designer, st: _State) -> bool:
    """Whether the session's safe state after the plan (0 V brakes, or open) keeps the
    limits from ``st`` under the prior."""
    n = max(MIN_SAMPLES, int(HOLD_TAU * d.sc.tau_m_s / d.dt))
    fill = 0.0 if d.limits.safe_mode.value == "zero" else math.nan
    hold = Candidate("hold", "hold", np.full(n, fill))
    lim = replace(d.limits, heat_a2s=math.inf, budget_s=math.inf)
    return d.evaluate(hold, st, limits=lim).violation is None


def _stop(d: _Designer, st: _State) -> Candidate | None:
    """A ramp down to rest when the session's safe state would break a limit from where
    the plan ends (0 V at speed draws Ke w / R): the voltage from the back-EMF (the
    current it draws then is the friction's) down to 0 V, as short as the limits allow."""
    if _hold_ok(d, st):
        return None
    p = d.prior.model.params
    w = float(st.x[1])
    v0 = p.Ke * w + math.copysign(p.R * d.prior.coulomb_nm / p.Kt, w)
    v0 = max(-d.limits.voltage_max_v, min(d.limits.voltage_max_v, v0))
    for k in (1.0, 2.0, 4.0, 8.0, 16.0, 32.0):
        n = max(MIN_SAMPLES, int(k * d.sc.tau_m_s / d.dt))
        ramp = Candidate("stop", "stop", np.linspace(v0, 0.0, n), {"v": v0})
        ev = d.evaluate(ramp, st, limits=replace(d.limits, budget_s=math.inf))
        if ev.violation is None and _hold_ok(d, _State(ev.end, ev.heat, st.t)):
            return ramp
    return None


def stop_segment(
    prior: Prior, limits: PlanLimits, dt_s: float, state: Sequence[float], label: str
) -> PlannedSegment | None:
    """A ramp to rest from ``state`` ``[i, w, theta]`` when the session's hold (0 V, or
    open) after it would break a limit under the prior (``None`` when it would not)."""
    values, names = design_values(prior)
    d = _Designer(prior, limits, dt_s, names, {}, "A", None, values)
    ramp = _stop(d, _State(np.asarray(state, float), 0.0, 0.0))
    return None if ramp is None else PlannedSegment(label, ramp.voltage.copy())


def _merged(chosen: Sequence[Candidate]) -> list[Candidate]:
    """Consecutive levels at one voltage, and consecutive open-armature decays, as one
    segment (one initial state less to fit). For decays it is most of B's information:
    B is told from the Coulomb torque by how the deceleration changes with speed over
    the one coast, which a second initial speed to fit cuts in two (a 1.7 s coast on
    the scooter motor, cut in two pieces for re-fits: B's fitted sd 0.46 -> 0.95 %)."""
    out: list[Candidate] = []
    for c in chosen:
        prev = out[-1] if out else None
        if (
            prev is not None
            and prev.kind == c.kind == "level"
            and prev.settings.get("v") == c.settings.get("v")
        ):
            out[-1] = replace(prev, voltage=np.concatenate([prev.voltage, c.voltage]))
        elif prev is not None and prev.kind == c.kind == "decay":
            t_s = float(prev.settings.get("t_s", 0.0)) + float(c.settings.get("t_s", 0.0))
            voltage = np.concatenate([prev.voltage, c.voltage])
            out[-1] = replace(prev, voltage=voltage, settings={**prev.settings, "t_s": t_s})
        else:
            out.append(c)
    return out


def _gain(d: _Designer, info: FloatArray, ev: _Eval) -> float:
    dur = ev.cand.n * d.dt
    return (d.phi(info - ev.info) - d.phi(info)) / dur


def _result(
    d: _Designer,
    cands: Sequence[Candidate],
    evs: Sequence[_Eval],
    info: FloatArray,
    requested: dict[str, float],
    dropped: dict[str, str],
    prior_seconds: float,
    label_start: int,
    notes: list[str],
) -> DesignedPlan:
    dt = d.dt
    rsd = with_systematic(d.rsd(info), d.floor)
    # the predicted interval: the lag's bias through the sensitivities, for every
    # parameter (L's plan-free bound where it is larger); not counted in ``short``: no
    # longer plan removes it, and L's share of the target is taken out above
    lag = {n: max(d.floor.get(n, 0.0), v) for n, v in d.lag_rsd.items()} or d.floor
    predicted = with_systematic(d.rsd(info), lag)
    for n, tgt in d.target.items():
        if rsd.get(n, math.inf) <= tgt < predicted.get(n, 0.0):
            notes.append(
                f"{public_name(n)}: a current reading up to "
                f"{d.prior.noise.current_lag(dt) * 1e6:.3g} us late may bias it by up to "
                f"{196 * lag[n]:.2g} % on this plan, whatever its length"
            )
    pieces: list[PlanPiece] = []
    segs: list[PlannedSegment] = []
    t = 0.0
    total_gain = d.phi(d.info0) - d.phi(info)
    running = d.info0.copy()
    for k, (c, ev) in enumerate(zip(cands, evs, strict=True)):
        label = f"{c.prefix}_{label_start + k:02d}"
        before = d.phi(running)
        running = running + ev.info
        share = (before - d.phi(running)) / total_gain if total_gain > 0 else 0.0
        pieces.append(PlanPiece(label, c, t, share))
        segs.append(PlannedSegment(label, c.voltage.copy()))
        t += c.n * dt
    plan = TestPlan(tuple(segs), dt)
    traj = _trajectory(d, plan)
    short: dict[str, str] = {}
    for n, tgt in d.target.items():
        r = rsd.get(n, math.inf)
        if r > tgt:
            what = f"{100 * r:.3g} %" if math.isfinite(r) else "not determined"
            short[n] = (
                f"predicted {what} against the target {100 * tgt:.3g} % after {t:.3g} s; "
                f"it needs {ADVICE.get(n, '')}"
            )
    binding, detail = _binding(d, short)
    met = not short and bool(cands)
    if not cands:
        notes.append("the information in hand already meets the target: nothing to run")
        met = all(rsd.get(n, math.inf) <= tgt for n, tgt in d.target.items())
    i_peak = max((e.peak_i for e in evs), default=0.0)
    w_peak = max((e.peak_w for e in evs), default=0.0)
    pos = traj["position"]
    return DesignedPlan(
        plan=plan,
        pieces=tuple(pieces),
        prior=d.prior,
        limits=d.limits,
        target={k: v for k, v in d.target.items()},
        requested=requested,
        predicted_rsd={n: predicted[n] for n in d.names},
        met=met,
        short=short,
        dropped=dropped,
        binding=binding,
        binding_detail=detail,
        criterion=d.criterion,
        duration_s=t,
        peak_current_a=i_peak,
        peak_speed_rad_s=w_peak,
        heat_a2s=evs[-1].heat if evs else 0.0,
        position_range_rad=(float(pos.min()), float(pos.max())) if pos.size else (0.0, 0.0),
        trajectory=traj,
        prior_seconds=prior_seconds,
        notes=tuple(notes),
    )


def _binding(d: _Designer, short: Mapping[str, str]) -> tuple[str, str]:
    if short and d.limits.budget_s and not d.lost:
        return "time", f"the budget of {d.limits.budget_s:.3g} s of motor time"
    if not d.lost:
        return "none", "no limit turned a better segment away"
    name = max(d.lost, key=lambda k: d.lost[k])
    what = {
        "voltage": f"segments above {d.limits.voltage_max_v:.3g} V would be shorter",
        "current": f"steps would draw more than {d.limits.current_use_a:.3g} A",
        "speed": f"levels would turn faster than {d.limits.speed_use_rad_s:.4g} rad/s",
        "heat": f"the winding would take more than {d.limits.heat_a2s:.4g} A^2*s",
        "travel": "longer or faster runs would leave the travel range",
        "time": f"the budget of {d.limits.budget_s:.3g} s",
    }[name]
    others = ", ".join(k for k in sorted(d.lost, key=lambda k: -d.lost[k]) if k != name)
    return name, what + (f"; also {others}" if others else "")


def _trajectory(d: _Designer, plan: TestPlan) -> dict[str, FloatArray]:
    if not plan.segments:
        z = np.zeros(0)
        return {"t": z, "voltage": z, "current": z, "speed": z, "position": z}
    v = np.concatenate([s.voltage for s in plan.segments])
    x0 = np.array([0.0, 0.0, d.limits.start_rad])
    sim = simulate(d.prior.model, v, d.dt, x0=x0)
    return {
        "t": np.arange(v.size) * d.dt,
        "voltage": v,
        "current": np.where(np.isnan(v), 0.0, sim.current),
        "speed": sim.speed,
        "position": sim.position,
    }


def evaluate_plan(
    prior: Prior,
    plan: TestPlan,
    names: Sequence[str] | None = None,
    fixed: Sequence[str] = (),
    start_state: Sequence[float] | None = None,
) -> tuple[dict[str, float], FloatArray, tuple[str, ...]]:
    """The predicted relative sd of any plan (the default sequence, WPILib's routine, a
    PRBS) under ``prior``, its total information and the parameters' order: the same
    model and noise the designer uses, each segment from its own initial state."""
    values, free = design_values(prior, fixed)
    im = InformationModel.build(values, names or free, plan.dt_s, prior.noise)
    v = np.concatenate([s.voltage for s in plan.segments])
    x0 = None if start_state is None else np.asarray(start_state, float)
    sim = simulate(prior.model, v, plan.dt_s, x0=x0)
    cur = np.where(np.isnan(v), 0.0, sim.current)
    info = np.zeros((im.n_par, im.n_par))
    k = 0
    for s in plan.segments:
        sl = slice(k, k + s.voltage.size)
        k += s.voltage.size
        info = info + segment_information(im, v[sl], cur[sl], sim.speed[sl], sim.position[sl])
    floor = systematic_rsd(values, prior.noise, plan.dt_s)
    return with_systematic(relative_sd(info, im.names), floor), info, im.names
