"""The identification node's ``plan`` parameter, ROS-free: which plan a session runs.

* ``default``: today's sequence (:func:`~pmdc_ident.node_logic.session.startup.build_session`).
* a path to a plan CSV (``pmdc-ident plan --csv`` writes one): that plan, checked
  against the driver's limits before anything moves.
* ``auto``: a sequential session (:mod:`pmdc_ident.core.design.sequential`): the
  pre-test runs first; the session then holds the safe command while the worker
  identifies it and designs the plan; the plan's segments are appended as they come
  (:meth:`Session.extend`); as segments finish the worker re-fits everything so far,
  and the session ends (:meth:`Session.finish`) once the target is met, or when the
  budget is spent (with the parameter still short and why).

The heavy part (identify, design) runs in the node's worker process: a
:class:`DesignJob` carries the samples so far and the :class:`SequentialDesign`
itself, a :class:`DesignOutcome` brings back its decision and its updated state.
A travel range (``plan_travel_rad``) becomes a safety rule as well: the session aborts
when the measured position leaves it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from pmdc_ident.core.enums import LogLevel
from pmdc_ident.core.errors import ParameterError, PmdcError
from pmdc_ident.core.excitation import PlannedSegment, TestPlan
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.safety import COMMAND_DELAY_S, SafetyConfig
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.node_logic.session.machine import Session
from pmdc_ident.node_logic.session.plan_check import check_plan
from pmdc_ident.node_logic.session.startup import SessionSettings, driver_limits, safety_for

__all__ = ["DesignJob", "DesignOutcome", "PlanSetting", "build_planned_session"]


@dataclass(frozen=True)
class PlanSetting:
    """The node's ``plan*`` parameters (``mode``: ``default``, ``auto`` or a CSV path)."""

    mode: str = "default"
    target: str = ""
    travel_rad: tuple[float, float] | None = None
    budget_s: float = 0.0  # 0: the default sequence's length
    heat_a2s: float = 0.0  # 0: the default sequence's heat
    reveal: tuple[str, ...] = ()
    criterion: str = "A"
    command_delay_s: float = COMMAND_DELAY_S  # travel: plans hold for commands this late
    # how late the current reading may be (anti-alias filter, ADC timing), s; None: not
    # known, up to 1/(2 pi) of a sample (information.CURRENT_LAG_SAMPLES)
    current_lag_s: float | None = None

    @property
    def auto(self) -> bool:
        return self.mode == "auto"

    @property
    def default(self) -> bool:
        return self.mode in ("", "default")

    @classmethod
    def from_values(cls, v: Mapping[str, Any]) -> PlanSetting:
        travel = [float(x) for x in (v.get("plan_travel_rad") or [])]
        if travel and len(travel) != 2:
            msg = f"plan_travel_rad takes [MIN, MAX] in rad ([0, 0]: none), got {travel}"
            raise ParameterError(msg)
        if travel and travel[0] == travel[1] == 0.0:
            travel = []
        reveal = tuple(x.strip() for x in str(v.get("plan_reveal", "")).split(",") if x.strip())
        setting = cls(
            mode=str(v.get("plan", "default")).strip() or "default",
            target=str(v.get("plan_target", "")),
            travel_rad=(travel[0], travel[1]) if travel else None,
            budget_s=float(v.get("plan_budget_s", 0.0)),
            heat_a2s=float(v.get("plan_heat_a2s", 0.0)),
            reveal=reveal,
            command_delay_s=float(v.get("plan_command_delay_s", COMMAND_DELAY_S)),
            current_lag_s=cls._lag(v.get("plan_current_lag_s", -1.0)),
        )
        setting.check()
        return setting

    @staticmethod
    def _lag(value: Any) -> float | None:
        """``plan_current_lag_s``: a negative value means not known (``None``)."""
        lag = float(value)
        if not math.isfinite(lag):
            msg = f"plan_current_lag_s must be a lag in s (negative: not known), got {value!r}"
            raise ParameterError(msg)
        return None if lag < 0 else lag

    def check(self) -> None:
        from pmdc_ident.core.design.target import parse_target
        from pmdc_ident.core.effects import EFFECT_NAMES as REVEALABLE

        if self.travel_rad is not None and not self.travel_rad[0] < self.travel_rad[1]:
            msg = f"plan_travel_rad must be [MIN, MAX] with MIN < MAX, got {list(self.travel_rad)}"
            raise ParameterError(msg)
        if self.target:
            parse_target(self.target)
        bad = [e for e in self.reveal if e not in REVEALABLE]
        if bad:
            msg = f"plan_reveal: unknown effect(s) {', '.join(bad)}"
            raise ParameterError(msg)
        if not (self.default or self.auto) and not self.mode.lower().endswith(".csv"):
            msg = (
                "plan must be 'default', 'auto' or a plan CSV (pmdc-ident plan --csv), "
                f"got {self.mode!r}"
            )
            raise ParameterError(msg)


@dataclass(frozen=True)
class DesignJob:
    """The samples so far of a ``plan: auto`` session and its design state, for the
    worker (plain data in and out)."""

    samples: DriverSamples
    session: str
    source: str
    design: Any  # pmdc_ident.core.design.sequential.SequentialDesign
    plan_done: bool
    position_rad: float
    speed_rad_s: float = 0.0  # the joint's state with the position: where it still goes
    current_a: float = 0.0


@dataclass(frozen=True)
class DesignOutcome:
    """The worker's decision: ``action`` (``extend``, ``stop``, ``continue``), the
    segments to append, the design's updated state, and a line for the log."""

    action: str
    segments: tuple[PlannedSegment, ...] = ()
    design: Any = None
    message: str = ""
    error: str = ""
    start_rad: float | None = None  # an extension: the position it was designed from
    notes: tuple[tuple[LogLevel, str], ...] = field(default=())


def _travel_safety(safety: SafetyConfig, setting: PlanSetting) -> SafetyConfig:
    if setting.travel_rad is None:
        return safety
    lo, hi = setting.travel_rad
    return replace(safety, position_min_rad=lo, position_max_rad=hi)


def build_planned_session(
    settings: SessionSettings,
    setting: PlanSetting,
    driver: Mapping[str, Any] | None,
    name: str,
    position_rad: float,
) -> tuple[Session, Any]:
    """The session for a ``plan`` other than ``default``, and for ``auto`` its
    :class:`~pmdc_ident.core.design.sequential.SequentialDesign` (else ``None``).
    :class:`PmdcError` when the plan would exceed a limit (nothing has moved then)."""
    limits, rate_hz = driver_limits(settings, driver)
    dt = 1.0 / rate_hz
    safety = _travel_safety(safety_for(settings, limits), setting)
    if setting.travel_rad is not None:
        lo, hi = setting.travel_rad
        if not lo < position_rad < hi:
            msg = (
                f"plan refused before anything moved: the joint is at {position_rad:.4g} rad, "
                f"outside the travel range [{lo:.4g}, {hi:.4g}] rad"
            )
            raise PmdcError(msg)
    design = None
    if setting.auto:
        plan, design = _auto(settings, setting, limits, dt, position_rad)
    else:
        plan = _from_csv(setting.mode, dt)
    problems = check_plan(plan, limits, safety, None)
    if problems:
        raise PmdcError("plan refused before anything moved: " + "; ".join(problems))
    session = Session(
        plan,
        safety,
        tau_m_s=settings.tau_s(),
        steady=settings.steady,
        safe_mode=settings.safe_mode,
        name=name,
        open_ended=setting.auto,
        # a designed plan (the pre-test, or a plan CSV: travel-limited, fast switching)
        # starts once the driver is seen to apply the session's own (safe) command and
        # this node has caught up with the driver, so none of it is lost to a command
        # topic that matched late and no first level is held longer than planned
        hold_first=True,
    )
    return session, design


def _from_csv(path: str, dt: float) -> TestPlan:
    from pmdc_ident.core.design.exchange import plan_from_csv_text

    p = Path(path).expanduser()
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        msg = f"parameter plan: cannot read {p} ({exc})"
        raise PmdcError(msg) from None
    plan = plan_from_csv_text(text, str(p))
    if abs(plan.dt_s - dt) > 1e-6 * dt:
        msg = (
            f"parameter plan: {p} is planned at {1 / plan.dt_s:.6g} Hz but the driver "
            f"samples at {1 / dt:.6g} Hz (re-plan with `pmdc-ident plan --rate-hz {1 / dt:.6g}`)"
        )
        raise PmdcError(msg)
    return plan


def _auto(
    settings: SessionSettings, setting: PlanSetting, limits: Any, dt: float, position_rad: float
) -> tuple[TestPlan, Any]:
    from pmdc_ident.core.design import Noise, Prior
    from pmdc_ident.core.design.sequential import SequentialDesign, SequentialSettings
    from pmdc_ident.core.design.target import parse_target

    nominal: MotorSpec = settings.nominal
    try:
        prior = Prior.from_spec(nominal, source=f"nominal motor {nominal.name}")
    except ParameterError:
        # the nominal motor sizes the pre-test only: its noise matters not
        prior = Prior(nominal.model, Noise(1e-3, 1e-3), f"nominal motor {nominal.name}")
    # the rig's current lag: every design and re-fit of the session counts L's bias from
    # it (SequentialDesign takes it from the nominal prior's noise)
    prior = replace(prior, noise=replace(prior.noise, current_lag_s=setting.current_lag_s))
    seq = SequentialDesign(
        prior,
        limits,
        dt,
        SequentialSettings(
            target=parse_target(setting.target) if setting.target else None,
            travel_rad=setting.travel_rad,
            heat_a2s=setting.heat_a2s or None,
            budget_s=setting.budget_s or None,
            criterion=setting.criterion,
            reveal=setting.reveal,
            safe_mode=settings.safe_mode,
            command_delay_s=setting.command_delay_s,
        ),
    )
    try:
        plan = seq.start(start_rad=position_rad)
    except PmdcError as exc:
        raise PmdcError(f"plan refused before anything moved: {exc}") from None
    return plan, seq


def run_design_job(job: DesignJob, run: Any) -> DesignOutcome:
    """The worker's part: decide from ``run`` (the job's samples, assembled)."""
    seq = job.design
    try:
        heat = 0.0
        for s in run.segments:
            if s.current is not None and s.voltage is not None:
                import numpy as np

                driven = np.isfinite(s.voltage)
                heat += float(np.sum(s.current[driven] ** 2) * s.dt_s)
        d = seq.decide(
            run.segments,
            plan_done=job.plan_done,
            position_rad=job.position_rad,
            heat_a2s=heat,
            speed_rad_s=job.speed_rad_s,
            current_a=job.current_a,
        )
    except PmdcError as exc:
        return DesignOutcome("stop", design=seq, message=f"design failed: {exc}", error=str(exc))
    if not math.isfinite(seq.run_s):
        return DesignOutcome("stop", design=seq, message="no motor time left")
    start = seq.start_rad if d.action == "extend" else None
    return DesignOutcome(d.action, tuple(d.segments), seq, d.message, start_rad=start)
