"""The plans a designed one is compared with, sized for the same motor and limits.

* **default**: today's session (:func:`~pmdc_ident.core.excitation.plan_for_motor`:
  staircase, steps both ways, a log chirp, a coast-down), from the prior's tau_m;
* **WPILib**: the SysId routine's four tests, scaled from a 12 V system to the motor's
  voltage: a quasistatic ramp at 1 V/s for SysId's 10 s timeout and a 7 V step held
  ``WPILIB_STEP_S`` (or ten tau_m), each forward and backward, the rotor brought to
  rest between them;
* **PRBS**: a pseudo-random binary sequence of +-0.6 of the highest level the speed
  limit allows, clocked at half tau_m, of a given length.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from pmdc_ident.core.design.family import Scales
from pmdc_ident.core.design.limits import PlanLimits
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.excitation import PlannedSegment, SequenceConfig, TestPlan, plan_for_motor
from pmdc_ident.core.motors import Limits, MotorSpec

__all__ = ["default_sequence", "prbs_plan", "wpilib_routine"]

WPILIB_RAMP_V_PER_S = 1.0  # per 12 V of the system
WPILIB_STEP_V = 7.0  # per 12 V
WPILIB_TIMEOUT_S = 10.0
WPILIB_STEP_S = 2.0


def default_sequence(
    prior: Prior, limits: PlanLimits, dt_s: float, config: SequenceConfig | None = None
) -> TestPlan:
    """Today's default session for this motor (what the identification node runs)."""
    spec = MotorSpec(
        "prior",
        prior.model,
        limits=Limits(limits.voltage_max_v, limits.current_max_a, limits.speed_max_rad_s),
    )
    return plan_for_motor(spec, dt_s, config)


def wpilib_routine(prior: Prior, limits: PlanLimits, dt_s: float) -> TestPlan:
    """SysId's quasistatic and dynamic tests both ways, scaled to the motor's voltage."""
    scale = limits.voltage_max_v / 12.0
    tau = prior.model.params.mechanical_time_constant_s
    n_ramp = int(round(WPILIB_TIMEOUT_S / dt_s))
    ramp = np.minimum(WPILIB_RAMP_V_PER_S * scale * np.arange(n_ramp) * dt_s, limits.voltage_max_v)
    n_step = int(round(min(max(WPILIB_STEP_S, 10.0 * tau), WPILIB_TIMEOUT_S) / dt_s))
    step = np.full(n_step, min(WPILIB_STEP_V * scale, limits.voltage_max_v))
    rest = np.zeros(max(2, int(round(5.0 * tau / dt_s))))
    segs = []
    for sign, name in ((1.0, "forward"), (-1.0, "backward")):
        segs.append(PlannedSegment(f"quasistatic_{name}", np.r_[sign * ramp, rest]))
    for sign, name in ((1.0, "forward"), (-1.0, "backward")):
        segs.append(PlannedSegment(f"dynamic_{name}", np.r_[sign * step, rest]))
    return TestPlan(tuple(segs), dt_s)


def prbs_plan(
    prior: Prior, limits: PlanLimits, dt_s: float, duration_s: float, seed: int = 1
) -> TestPlan:
    """A PRBS of ``duration_s`` (a maximal-length 9-bit shift register, clock tau_m / 2)."""
    sc = Scales.of(prior, limits, dt_s)
    clock = max(1, int(round(0.5 * sc.tau_m_s / dt_s)))
    n = max(2, int(round(duration_s / dt_s)))
    state = (seed % 511) or 1
    bits = []
    for _ in range(math.ceil(n / clock) + 1):
        bit = ((state >> 8) ^ (state >> 4)) & 1
        state = ((state << 1) | bit) & 0x1FF
        bits.append(1.0 if bit else -1.0)
    v = np.repeat(np.asarray(bits), clock)[:n] * 0.6 * sc.v_top
    return TestPlan((PlannedSegment("prbs", v),), dt_s)


def with_limits_of(plan: TestPlan, voltage_max_v: float) -> TestPlan:
    """The plan clipped to a voltage limit (a plan sized for another motor)."""
    return replace(
        plan,
        segments=tuple(
            PlannedSegment(s.label, np.clip(s.voltage, -voltage_max_v, voltage_max_v))
            for s in plan.segments
        ),
    )
