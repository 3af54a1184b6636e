"""The automatic pre-test: at most two seconds that turn a rough nominal motor (or
none) into a prior the design can trust, and the prior identified from it.

The pre-test is sized from a nominal motor (the node's ``motor`` parameter: its tau_m
and its speed per volt) and the limits, never longer than ``MAX_PRETEST_S``: a step up
held four tau_m, coasting one with the armature open and braked to rest at 0 V (a
current no larger than the step's), then the same down. With a travel range it is a
square wave instead, its amplitude and half period shrunk until the nominal motor
(and one faster than it) stays inside the range, braked to rest at the end, also when a
stop or any one switch reaches the driver up to ``limits.command_delay_s`` late. What is identified
from it (``identify``'s pipeline on the pre-test's segments) is the prior, with the
noise levels the fit measured on the rig.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from pmdc_ident.core.design.family import Candidate, Scales
from pmdc_ident.core.design.information import Noise
from pmdc_ident.core.design.limits import PlanLimits, late_stop
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.errors import ParameterError, PmdcError
from pmdc_ident.core.excitation import PlannedSegment, TestPlan
from pmdc_ident.core.model import Model, simulate

if TYPE_CHECKING:
    from pmdc_ident.core.identification.results import IdentificationResult

__all__ = ["MAX_PRETEST_S", "PRETEST_PREFIX", "prior_from_result", "pretest_plan"]

MAX_PRETEST_S = 2.0
PRETEST_PREFIX = "pretest"
_FRACTIONS = (0.4, 0.25, 0.12, 0.06)


def _late_switches(v: np.ndarray, delay: int) -> list[np.ndarray]:
    """The plan with one of its level changes ``delay`` samples late (the level before
    it held meanwhile): a host held up at a switch. Every change, one at a time."""
    if delay <= 0:
        return []
    level = np.nan_to_num(v, nan=np.inf)
    out = []
    for k in np.flatnonzero(level[1:] != level[:-1]) + 1:
        late = v.copy()
        late[k : k + delay] = v[k - 1]
        out.append(late)
    return out


def _fits(nominal: Prior, limits: PlanLimits, v: np.ndarray, dt: float) -> bool:
    # the session holds 0 V after it (while the design is made): that too
    tail = int(5.0 * nominal.model.params.mechanical_time_constant_s / dt) + 2
    v = np.concatenate([v, np.zeros(tail)])
    delay = int(round(limits.command_delay_s / dt))
    for model in (nominal.model, nominal.pessimistic()):
        sim = simulate(model, v, dt, x0=np.array([0.0, 0.0, limits.start_rad]))
        cur = np.where(np.isnan(v), 0.0, sim.current)
        stop = None
        if limits.travel_rad is not None:
            stop = sim.position + late_stop(
                model, v, sim.speed, cur, limits.safe_mode, limits.command_delay_s
            )
        heat = float(np.sum(cur**2) * dt)
        if limits.check(v, cur, sim.speed, sim.position, heat, stop) is not None:
            return False
        if limits.travel_rad is None:
            continue
        # a switch that reaches the driver late shifts the rest of the square wave
        lo, hi = limits.travel_rad
        for late in _late_switches(v, delay):
            pos = simulate(model, late, dt, x0=np.array([0.0, 0.0, limits.start_rad])).position
            if float(pos.min()) < lo or float(pos.max()) > hi:
                return False
    return True


def pretest_plan(nominal: Prior, limits: PlanLimits, dt_s: float) -> TestPlan:
    """The pre-test for a rig whose motor is roughly ``nominal`` (see the module)."""
    sc = Scales.of(nominal, limits, dt_s)
    unit = min(sc.unit_s, MAX_PRETEST_S / 12.0)
    for frac in _FRACTIONS:
        v = frac * sc.v_top
        if limits.travel_rad is None:
            segs = []
            for sign, name in ((1.0, "up"), (-1.0, "down")):
                seq = np.r_[
                    np.full(sc.samples(4.0 * unit), sign * v),
                    np.full(sc.samples(2.0 * unit), math.nan),
                ]
                segs.append(PlannedSegment(f"{PRETEST_PREFIX}_{name}", seq))
            plan = TestPlan(tuple(segs), dt_s)
            if _fits(nominal, limits, np.concatenate([s.voltage for s in segs]), dt_s):
                return plan
            continue
        for h in (1.0, 0.5, 0.25, 0.12, 0.06):
            half = sc.samples(h * unit)
            cycles = max(2, min(8, int(MAX_PRETEST_S / (4 * half * dt_s))))
            one = []
            for sign in (1.0, -1.0):
                body = [np.full(half // 2, sign * v)]
                body += [
                    np.full(half, sign * v * (-1.0) ** (k + 1)) for k in range(2 * cycles - 1)
                ]
                body += [np.full(half - half // 2, sign * v), np.zeros(sc.samples(2.0 * unit))]
                one.append(np.concatenate(body))
            segs = [
                PlannedSegment(f"{PRETEST_PREFIX}_up", one[0]),
                PlannedSegment(f"{PRETEST_PREFIX}_down", one[1]),
            ]
            if sum(s.voltage.size for s in segs) * dt_s > MAX_PRETEST_S:
                continue
            if _fits(nominal, limits, np.concatenate([s.voltage for s in segs]), dt_s):
                return TestPlan(tuple(segs), dt_s)
    msg = (
        "no pre-test of at most 2 s keeps the nominal motor inside the limits "
        f"({limits.describe()}): give a motor file closer to the rig, or wider limits"
    )
    raise ParameterError(msg)


def prior_from_result(
    result: IdentificationResult, source: str, counts_per_rev: float = 0.0
) -> Prior:
    """The prior a pre-test's identification gives: its model (with the Coulomb
    friction when it chose one) and the noise its fit measured on the rig."""
    noise = dict(result.noise)
    cur = float(noise.get("current", 0.0))
    speed = float(noise.get("speed", 0.0))
    pos = float(noise.get("position", 0.0))
    if counts_per_rev > 0:
        pos = max(pos, 2.0 * math.pi / counts_per_rev / math.sqrt(12.0))
    if cur <= 0 or (speed <= 0 and pos <= 0):
        msg = (
            f"{source}: the pre-test's fit measured no noise levels (current {cur}, speed {speed})"
        )
        raise ParameterError(msg)
    return Prior(_with_friction(result), Noise(cur, speed, pos if speed <= 0 else 0.0), source)


def _with_friction(result: IdentificationResult) -> Model:
    """The fitted model, with its Coulomb friction even where a short record could not
    prove it: a linear fit's B takes the friction's torque at the speeds it saw, and a
    plan designed for that B (too large) misses B's target on the real motor."""
    from pmdc_ident.core.effects import CoulombFriction
    from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

    if result.model.effect("coulomb_friction") is not None:
        return result.model
    values = result.methods.get("output_error_coulomb", {}).get("values") or {}
    tc = float(values.get("coulomb_friction.torque_nm", 0.0))
    if tc <= 0 or not all(k in values for k in PARAMETER_NAMES):
        return result.model
    try:
        params = MotorParams(**{k: float(values[k]) for k in PARAMETER_NAMES})
    except PmdcError:
        return result.model
    return Model(params, (CoulombFriction(tc),))


def pretest_candidates(plan: TestPlan) -> list[Candidate]:
    """The pre-test as segments the design counts as already run."""
    return [Candidate("pretest", s.label, s.voltage) for s in plan.segments]
