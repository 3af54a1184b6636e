"""A sequential session (the identification node's ``plan: auto``), ROS-free.

1. **Pre-test** (:mod:`.pretest`, at most 2 s), sized from the nominal motor.
2. **Design**: the pre-test is identified; its model and the noise its fit measured
   are the prior; the plan is designed counting the pre-test's information as already
   in hand (:func:`~.api.plan_experiment`); a parameter the pre-test knows badly is
   aimed lower (its true value may lie below the prior's), so the plan is on the safe
   side and the re-fits end it early. With a travel range the plan runs in parts of
   about ``TRAVEL_CHUNK_TAU`` tau_m, each designed from the measured angle (the angle
   integrates every difference between the motor and its prior).
3. **Run and re-fit**: as segments finish, everything recorded so far is identified
   again; the session stops as soon as the fit's own relative sd of every targeted
   parameter is at its target.
4. When the plan is over and a parameter is still short, it is designed again from the
   latest fit (its information in hand), while motor time is left in the budget;
   otherwise the session ends and says which parameter is short and why.

:class:`SequentialDesign` makes these decisions from recorded runs (``decide``); the
node (or a script, or the benchmark) runs what it says. Each decision is a
:class:`Decision`; :meth:`SequentialDesign.report` is the record the result carries.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.design.api import plan_experiment, session_limits
from pmdc_ident.core.design.information import Noise, systematic_rsd, with_systematic
from pmdc_ident.core.design.limits import PlanLimits, default_margin_rad, stop_distance
from pmdc_ident.core.design.planner import DesignedPlan, evaluate_plan
from pmdc_ident.core.design.pretest import pretest_plan, prior_from_result
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.design.target import DEFAULT_TARGET, describe_target, public_name
from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.excitation import PlannedSegment, TestPlan
from pmdc_ident.core.model import simulate
from pmdc_ident.core.motors import Limits
from pmdc_ident.core.safety import COMMAND_DELAY_S

__all__ = ["Decision", "SequentialDesign", "SequentialSettings", "start_tolerance_rad"]

KEYS = {"Tc": "coulomb_friction.torque_nm"}
TRAVEL_CHUNK_TAU = 20.0  # with a travel range, at most about this many tau_m per design
START_TOLERANCE = 0.1  # share of the travel margin an extension may start off its design
REST_S = 2.0  # the hold simulated to find where a moving joint comes to rest


@dataclass(frozen=True)
class SequentialSettings:
    """What the sequential session aims at and within what (units in the names)."""

    target: Mapping[str, float] | None = None  # None: the default target
    travel_rad: tuple[float, float] | None = None
    heat_a2s: float | None = None
    budget_s: float | None = None
    criterion: str = "A"
    reveal: tuple[str, ...] = ()
    fixed: Mapping[str, float] = field(default_factory=dict)
    use_fraction: float = 0.8
    safe_mode: SafeMode = SafeMode.ZERO
    max_designs: int = 40
    command_delay_s: float = COMMAND_DELAY_S  # travel: how late a command may arrive


@dataclass(frozen=True)
class Decision:
    """What to do next: ``stop`` (target met, or nothing more to do), ``extend`` (run
    ``segments`` next) or ``continue`` (let the plan run on)."""

    action: str
    segments: tuple[PlannedSegment, ...] = ()
    designed: DesignedPlan | None = None
    achieved: dict[str, float] = field(default_factory=dict)  # relative sd, fit's own
    message: str = ""
    short: dict[str, str] = field(default_factory=dict)


@dataclass
class _Round:
    t_s: float
    action: str
    message: str
    achieved: dict[str, float]
    planned_s: float = 0.0
    predicted: dict[str, float] = field(default_factory=dict)


class SequentialDesign:
    """The decisions of a sequential session (see the module docs)."""

    def __init__(
        self, nominal: Prior, driver: Limits, dt_s: float, settings: SequentialSettings
    ) -> None:
        self.nominal = nominal
        self.driver = driver
        self.dt = dt_s
        self.settings = settings
        self.target = dict(DEFAULT_TARGET if settings.target is None else settings.target)
        self.rounds: list[_Round] = []
        self.designs = 0
        self.planned_s = 0.0  # pre-test + the first design: the plan the session expects
        self.run_s = 0.0  # motor time of the segments handed out so far
        self.pretest: TestPlan | None = None
        self.last_plan: DesignedPlan | None = None
        self.prior: Prior | None = None
        self.dropped: dict[str, str] = {}
        self.start_rad = 0.0  # where the last extension was designed to start (at rest)

    # -- 1. the pre-test ---------------------------------------------------------------
    def limits(self, prior: Prior, start_rad: float) -> PlanLimits:
        s = self.settings
        return session_limits(
            prior,
            self.driver,
            self.dt,
            travel_rad=s.travel_rad,
            start_rad=start_rad,
            heat_a2s=s.heat_a2s,
            budget_s=s.budget_s,
            use_fraction=s.use_fraction,
            safe_mode=s.safe_mode,
            command_delay_s=s.command_delay_s,
        )

    def start(self, start_rad: float = 0.0) -> TestPlan:
        """The pre-test to run first, from the nominal motor."""
        self.budget_s = self.limits(self.nominal, start_rad).budget_s
        self.pretest = pretest_plan(self.nominal, self.limits(self.nominal, start_rad), self.dt)
        self.run_s = self.pretest.duration_s
        self.planned_s = self.run_s
        return self.pretest

    # -- 2.-4. decisions ---------------------------------------------------------------
    def decide(
        self,
        segments: Sequence[Segment],
        *,
        plan_done: bool,
        position_rad: float = 0.0,
        heat_a2s: float = 0.0,
        speed_rad_s: float = 0.0,
        current_a: float = 0.0,
    ) -> Decision:
        """What to do after the recorded ``segments`` (everything so far): ``plan_done``
        when every segment handed out has run; ``position_rad``, ``speed_rad_s`` and
        ``current_a`` the joint's state when the plan ran out. The session holds its safe
        command meanwhile, so an extension starts where that hold brings the rotor to
        rest under the fit so far (:attr:`start_rad`): a part that ends at speed goes on
        turning while the worker designs (0.26 rad of its 0.4 rad margin on the geared
        joint braking from 20 rad/s; a CI run designed from where the joint passed left
        its range)."""
        self.seen_s = sum(s.n for s in segments) * self.dt
        try:
            fitted, achieved = self._fit(segments)
        except PmdcError as exc:
            if not plan_done:
                return self._log(Decision("continue", message=f"re-fit not possible yet: {exc}"))
            return self._log(Decision("stop", message=f"identification failed: {exc}"))
        met = all(
            achieved.get(n, math.inf) <= t
            for n, t in self.target.items()
            if self._fitted(n, fitted)
        )
        if met:
            return self._log(
                Decision(
                    "stop",
                    achieved=achieved,
                    message=f"target met after {self.seen_s:.3g} s of motor time: "
                    + _sds(achieved, self.target),
                )
            )
        if not plan_done:
            return self._log(
                Decision("continue", achieved=achieved, message=_sds(achieved, self.target))
            )
        left = self.budget_s - self.run_s
        if self.designs >= self.settings.max_designs or left < 20 * self.dt:
            short = self._short(achieved, fitted)
            why = "the motor-time budget is spent" if left < 20 * self.dt else "designs exhausted"
            return self._log(
                Decision(
                    "stop",
                    achieved=achieved,
                    short=short,
                    message=f"{why} after {self.run_s:.3g} s; short: "
                    + "; ".join(f"{public_name(k)}: {v}" for k, v in short.items()),
                )
            )
        try:
            prior = prior_from_result(fitted, f"fit of the first {self.run_s:.3g} s")
            lag = self.nominal.noise.current_lag_s  # the rig's, as the user gave it
            prior = replace(prior, noise=replace(prior.noise, current_lag_s=lag))
            self.prior = prior
            plan_so_far = TestPlan(
                tuple(PlannedSegment(s.label, _voltage(s)) for s in segments), self.dt
            )
            pred, info, _ = evaluate_plan(prior, plan_so_far, fixed=self._fixed_names())
            # where the fit knows a parameter worse than this information predicts (a
            # widened interval, a value below the prior's), aim lower by as much
            calib = {
                n: min(1.0, pred[n] / achieved[n])
                for n in self.target
                if n in achieved and n in pred and 0 < achieved[n] < math.inf and pred[n] > 0
            }
            self.start_rad = self._rest(prior, current_a, speed_rad_s, position_rad)
            base = self.limits(prior, self.start_rad)
            lim = replace(
                base,
                budget_s=max(left, 20 * self.dt),
                heat_a2s=_left(self.settings.heat_a2s, heat_a2s, base),
            )
            designed = plan_experiment(
                prior,
                self.driver,
                self.dt,
                target=None if self.settings.target is None else self.target,
                criterion=self.settings.criterion,
                reveal=self.settings.reveal if self.designs == 0 else (),
                fixed=self._fixed_names(),
                prior_info=info,
                prior_seconds=self.run_s,
                start_state=(0.0, 0.0, self.start_rad),
                label_start=len(segments) + 1,
                limits=lim,
                prior_rsd=self._prior_rsd(fitted),
                aim_scale=calib,
                prior_voltages=[s.voltage for s in plan_so_far.segments],
            )
        except PmdcError as exc:
            return self._log(
                Decision("stop", achieved=achieved, message=f"no plan possible: {exc}")
            )
        self.designs += 1
        self.last_plan = designed
        for n in designed.dropped:
            self.target.pop(n, None)  # out of reach (or fixed): not waited for
        self.dropped = dict(designed.dropped)
        if not designed.pieces:
            return self._log(
                Decision(
                    "stop", achieved=achieved, designed=designed, message="nothing left to run"
                )
            )
        if self.designs == 1:
            self.planned_s = self.run_s + designed.duration_s
        segs = designed.plan.segments
        if self.settings.travel_rad is not None and len(segs) > 1:
            # a joint: the angle integrates every difference between the motor and its
            # prior, so a plan runs in short parts, each designed from the measured angle
            tau = designed.prior.model.params.mechanical_time_constant_s
            share = TRAVEL_CHUNK_TAU * tau / max(designed.duration_s, 1e-9)
            if share < 1.0:
                part = _first_part(designed, share, self.dt)
                segs = part if len(part) < len(segs) else segs
        self.run_s += sum(s.voltage.size for s in segs) * self.dt
        return self._log(
            Decision(
                "extend",
                segments=tuple(segs),
                designed=designed,
                achieved=achieved,
                message=f"design {self.designs}: {len(designed.pieces)} segments, "
                f"{designed.duration_s:.3g} s (binding: {designed.binding})"
                + ("" if len(segs) == len(designed.pieces) else f", the first {len(segs)} run now")
                + "; fit so far "
                + _sds(achieved, self.target)
                + "; predicted "
                + _sds(designed.predicted_rsd, self.target),
            )
        )

    def _rest(self, prior: Prior, i: float, w: float, theta: float) -> float:
        """Where the session's hold brings the joint to rest from ``(i, w, theta)``
        under ``prior``: its safe command simulated for up to :data:`REST_S`, then
        :func:`~.limits.stop_distance` from there (a rotor still coasting)."""
        if w == 0.0 and i == 0.0:
            return theta
        hold = math.nan if self.settings.safe_mode is SafeMode.OPEN else 0.0
        n = max(2, round(REST_S / self.dt))
        sim = simulate(prior.model, np.full(n, hold), self.dt, x0=(i, w, theta))
        end = float(sim.position[-1]) + float(
            stop_distance(
                prior.model,
                sim.speed[-1:],
                sim.current[-1:],
                self.settings.safe_mode,
            )[0]
        )
        return end if math.isfinite(end) else theta

    def _prior_rsd(self, result: Any) -> dict[str, float]:
        out = {}
        for n in ("R", "L", "Ke", "J", "B", "Tc"):
            e = result.parameters.get(KEYS.get(n, n))
            if e is not None and e.stderr is not None and e.value:
                out[n] = abs(float(e.stderr) / float(e.value))
        return out

    def _fixed_names(self) -> tuple[str, ...]:
        return tuple("Tc" if n == KEYS["Tc"] else n for n in self.settings.fixed)

    def _fitted(self, name: str, result: Any) -> bool:
        return name != "Tc" or KEYS["Tc"] in result.parameters

    def _fit(self, segments: Sequence[Segment]) -> tuple[Any, dict[str, float]]:
        from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE
        from pmdc_ident.core.identification.identify import identify

        result = identify(
            list(segments),
            fixed=dict(self.settings.fixed),
            closure=CLOSURE_KT_KE,
            holdout=False,
            frequency=False,
        )
        out = {}
        for n in self.target:
            e = result.parameters.get(KEYS.get(n, n))
            if e is None or e.stderr is None or not e.value:
                continue
            out[n] = abs(float(e.stderr) / float(e.value)) if math.isfinite(e.stderr) else math.inf
        # what the fit's own sd cannot see (a lag of the current reading biases L): the
        # target counts it, as the design does (information.systematic_rsd)
        par = result.parameters
        values = {k: float(par[k].value) for k in ("R", "L") if k in par}
        if "L" not in self.settings.fixed:
            lag = Noise(1.0, current_lag_s=self.nominal.noise.current_lag_s)
            out = with_systematic(out, systematic_rsd(values, lag, self.dt))
        return result, out

    def _short(self, achieved: Mapping[str, float], result: Any) -> dict[str, str]:
        from pmdc_ident.core.design.planner import ADVICE

        out = {}
        why = ""
        if self.last_plan is not None:
            why = f"; the binding limit was {self.last_plan.binding}"
        for n, t in self.target.items():
            if not self._fitted(n, result):
                continue
            a = achieved.get(n, math.inf)
            if a > t:
                what = f"{100 * a:.3g} %" if math.isfinite(a) else "not determined"
                out[n] = f"{what} against {100 * t:.3g} %: it needs {ADVICE.get(n, '')}{why}"
        return out

    def _log(self, d: Decision) -> Decision:
        r = _Round(self.run_s, d.action, d.message, dict(d.achieved))
        if d.designed is not None:
            r.planned_s = d.designed.duration_s
            r.predicted = dict(d.designed.predicted_rsd)
        self.rounds.append(r)
        return d

    def report(self, motor_s: float | None = None) -> dict[str, object]:
        """The session's record: target, pre-test, designs, decisions (for the result);
        ``motor_s``: the motor time the session really ran (default: what was handed out
        to run, which a session stopped at its target does not finish)."""

        def pct(d: Mapping[str, float]) -> dict[str, float | None]:
            return {public_name(k): (float(v) if math.isfinite(v) else None) for k, v in d.items()}

        return {
            "mode": "auto",
            "target": describe_target(self.target),
            "pretest_s": self.pretest.duration_s if self.pretest else 0.0,
            "planned_s": self.planned_s,
            "motor_s": self.run_s if motor_s is None else motor_s,
            "handed_out_s": self.run_s,
            "designs": self.designs,
            "not_targeted": {public_name(k): v for k, v in self.dropped.items()},
            "plan": self.last_plan.to_json() if self.last_plan is not None else None,
            "rounds": [
                {
                    "motor_s": round(r.t_s, 6),
                    "action": r.action,
                    "message": r.message,
                    "achieved_rsd": pct(r.achieved),
                    "planned_s": r.planned_s,
                    "predicted_rsd": pct(r.predicted),
                }
                for r in self.rounds
            ],
        }


def start_tolerance_rad(travel_rad: tuple[float, float]) -> float:
    """How far from its designed start a joint's extension may begin: a tenth of the
    travel margin the plan keeps (:attr:`PlanLimits.margin_rad`, the rest stays for
    the motor's difference from its fit while the plan runs)."""
    return START_TOLERANCE * default_margin_rad(travel_rad)


def _first_part(designed: DesignedPlan, share: float, dt: float) -> tuple[PlannedSegment, ...]:
    """The plan's segments up to about ``share`` of its length; where the session's hold
    after them (0 V brakes a rotor at speed with Ke w / R) would break a limit under the
    prior, a ramp to rest is added (:func:`~.planner.stop_segment`)."""
    from pmdc_ident.core.design.planner import stop_segment

    segs = designed.plan.segments
    ends = np.cumsum([s.voltage.size for s in segs])
    goal = share * ends[-1]
    cut = max(1, int(np.searchsorted(ends, goal, side="right")))
    if cut >= len(segs):
        return segs
    traj = designed.trajectory
    k = int(ends[cut - 1])
    # the state after the cut: the next sample of the prior's trajectory
    x = (float(traj["current"][k]), float(traj["speed"][k]), float(traj["position"][k]))
    label = f"stop_{segs[cut - 1].label.rsplit('_', 1)[-1]}b"
    stop = stop_segment(designed.prior, designed.limits, dt, x, label)
    return (*segs[:cut], stop) if stop is not None else segs[:cut]


def _voltage(s: Segment) -> np.ndarray:
    if s.voltage is None:
        return np.zeros(s.n)
    return np.asarray(s.voltage, dtype=float)


def _left(given: float | None, used: float, lim: PlanLimits) -> float:
    total = lim.heat_a2s if given is None else given
    return max(total - used, 1e-9) if math.isfinite(total) else math.inf


def _sds(rsd: Mapping[str, float], target: Mapping[str, float]) -> str:
    return ", ".join(
        f"{public_name(k)} {100 * v:.3g} %" + (" (met)" if k in target and v <= target[k] else "")
        if math.isfinite(v)
        else f"{public_name(k)} -"
        for k, v in rsd.items()
        if k in target
    )
