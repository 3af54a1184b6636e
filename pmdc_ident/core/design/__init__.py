"""Experiment design: the shortest safe plan that reaches a target uncertainty (issue 25).

ROS-free. From a prior model (a motor file, a built-in motor, or a short pre-test),
the limits (voltage, current, speed, winding heat as ``int i^2 dt``, motor time, and
optionally the travel of a joint), the sample rate, the rig's noise and a target
(default: every identifiable parameter to 1 % relative sd, the Coulomb torque to 5 %),
:func:`plan_experiment` designs the plan that reaches the target in the least motor
time by optimising the expected information (A- or D-optimal on the relative sds)
over a family of segments the driver can play.

Modules: :mod:`.information` (the Fisher information of a segment, the fitted model's),
:mod:`.family` (the segments), :mod:`.planner` (the greedy design and what binds),
:mod:`.limits`, :mod:`.prior`, :mod:`.target`, :mod:`.baselines` (the default sequence,
WPILib's routine, a PRBS), :mod:`.reveal` (segments that make an effect visible),
:mod:`.pretest` (the automatic pre-test), :mod:`.sequential` (the node's ``plan: auto``)
and :mod:`.exchange` (the plan as CSV).
"""

from __future__ import annotations

from pmdc_ident.core.design.api import plan_experiment, session_limits
from pmdc_ident.core.design.exchange import plan_csv_text, plan_from_csv_text
from pmdc_ident.core.design.information import Noise
from pmdc_ident.core.design.limits import PlanLimits
from pmdc_ident.core.design.planner import DesignedPlan, design_plan, evaluate_plan
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.design.target import DEFAULT_TARGET, parse_target

__all__ = [
    "DEFAULT_TARGET",
    "DesignedPlan",
    "Noise",
    "PlanLimits",
    "Prior",
    "design_plan",
    "evaluate_plan",
    "parse_target",
    "plan_csv_text",
    "plan_experiment",
    "plan_from_csv_text",
    "session_limits",
]
