"""Segments that make a named effect visible (``plan --reveal cogging,stribeck_friction``).

A plan designed for the parameters alone can be blind to an effect: a Stribeck hump
shows only at the lowest speeds, cogging only while the shaft crawls over its
detents, heating only when the same test is repeated hot. Each recipe here is sized
from the prior (speeds from its steady-state line, durations from tau_m, the
breakaway voltage from its friction) and the limits, and ordered so that the
diagnosis' default split (:mod:`pmdc_ident.core.diagnosis.holdout`: alternate
segments of one kind) puts both directions and the whole speed range on both sides:

==========================  ==================================================================
effect                      segments
==========================  ==================================================================
``coulomb_friction``,       a slow level each way, twice (``staircase``): direction changes at
``load_torque``             low speed
``stribeck_friction``       a staircase through the lowest speeds both ways (1.5 to 25 % of
                            the top speed), each level held to steady state
``cogging``                 slow crawls over up to a turn (the fastest over two: the angle
                            spectrum's span; or what the travel allows), each way
                            (``crawl``), at the speeds where 48, 16 and 4 periods per
                            turn pass at the mechanical bandwidth (at most 8 % of the top
                            speed): torque periodic in the angle, at a period the rotor
                            follows
``quadratic_drag``          a staircase to the top speed both ways
``brush_drop``,             a low-voltage staircase both ways and a small sweep about 0 V
``dead_zone``               (the current reverses)
``resistance_drift``        a reference step, a long hot hold (reversals, high current, to
                            half the heat budget), the same step again
``delay``                   sharp steps both ways from rest
``current_offset``          the armature open at rest (no current flows: a reading is offset)
``inductance_saturation``   steps from rest at low and at the highest current
==========================  ==================================================================

The segments run first in the plan; the design then adds what the parameters still
need (:func:`~.planner.design_plan` ``extra``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from pmdc_ident.core.design.family import Candidate, Scales
from pmdc_ident.core.design.limits import PlanLimits
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.effects import EFFECT_NAMES, EFFECT_TYPES
from pmdc_ident.core.errors import OptionError
from pmdc_ident.core.excitation import TestPlan, log_chirp

__all__ = ["RECIPES", "REVEALABLE", "predicted_limits", "reveal_segments"]

REVEALABLE: tuple[str, ...] = EFFECT_NAMES
COG_COUNTS = (48.0, 16.0, 4.0)  # cogging periods per turn the crawls are sized for
CRAWL_TOP = 0.08  # the fastest crawl, of the top speed
CRAWL_FLOOR = 0.002  # the lowest crawl voltage, of the top voltage (a speed to measure)
STRIBECK_SPEEDS = (0.015, 0.03, 0.06, 0.12, 0.25)
MAX_CRAWL_S = 6.0
# The diagnosis looks for cogging in the held-out residuals' spectrum over the shaft
# angle only where the held-out side spans two turns (localization.angle_harmonics: a
# period per turn is told from its neighbours over 4 pi), and the crawls go there and
# back, one direction on each side of the split: so the fastest crawl covers two turns
# and a half more (the prior's speed may be 15 % high, a crawl's first tau_m and a
# stall in a detent lose angle). A turn
# was too little: on the independent generator's scooter motor (17 or 117 periods per
# output turn) the held-out crawls spanned 7 rad and cogging was not even tried.
SPAN_TURNS = 2.5
MAX_SPAN_S = 4.0 * MAX_CRAWL_S  # ... for at most this long (a slow geared output)


def _voltage_for_speed(prior: Prior, w: float) -> float:
    """Steady voltage for speed ``w`` under the prior (its friction included)."""
    p = prior.model.params
    torque = p.B * abs(w) + prior.coulomb_nm
    return math.copysign(p.R * torque / p.Kt + p.Ke * abs(w), w)


def _top_speed(prior: Prior, sc: Scales) -> float:
    p = prior.model.params
    den = p.R * p.B + p.Ke * p.Kt
    return max((p.Kt * sc.v_top - p.R * prior.coulomb_nm) / den, 1e-9)


def _level(prefix: str, v: float, seconds: float, sc: Scales, kind: str = "crawl") -> Candidate:
    return Candidate(kind, prefix, np.full(sc.samples(seconds), v), {"v": v})


def reveal_segments(
    prior: Prior, limits: PlanLimits, dt_s: float, effects: Sequence[str]
) -> list[Candidate]:
    """The revealing segments for ``effects`` (vocabulary names), in plan order."""
    unknown = [e for e in effects if e not in REVEALABLE]
    if unknown:
        why = f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(REVEALABLE)}"
        raise OptionError("reveal", unknown, why, sep=": ")
    sc = Scales.of(prior, limits, dt_s)
    w_top = _top_speed(prior, sc)
    tau = sc.unit_s
    out: list[Candidate] = []
    done: set[str] = set()
    for name in dict.fromkeys(effects):
        key = EFFECT_TYPES[name].REVEAL
        if key in done:
            continue  # one recipe serves several names (Coulomb and a load torque)
        done.add(key)
        out += RECIPES[key](prior, limits, sc, w_top, tau)
    return out


def predicted_limits(prior: Prior, plan: TestPlan, effects: Sequence[str]) -> tuple[Any, ...]:
    """Per effect of ``effects``, the smallest size ``diagnose`` would show on a run of
    ``plan`` under the prior (:func:`~pmdc_ident.core.diagnosis.detection.detection_limits`
    on the prior's simulated run, its sensors' noise, the default split): the
    :class:`~pmdc_ident.core.diagnosis.detection.DetectionLimit` of each."""
    from pmdc_ident.core.diagnosis.detection import detection_limits
    from pmdc_ident.core.diagnosis.holdout import split_segments
    from pmdc_ident.core.diagnosis.scoring import estimate_noise
    from pmdc_ident.core.diagnosis.verdict import Thresholds
    from pmdc_ident.core.excitation import synthesize_run
    from pmdc_ident.core.model import Model
    from pmdc_ident.core.motors import SensorSpec

    n = prior.noise
    counts = 2 * math.pi / (n.position_sd * math.sqrt(12.0)) if n.position_sd > 0 else 0.0
    signals = ("current", "speed") if n.uses_speed else ("current", "position")
    run = synthesize_run(
        prior.model, plan, SensorSpec(n.current_sd, n.speed_sd, counts), signals=signals
    )
    return detection_limits(
        split_segments(run.segments),
        Model(prior.model.params),
        estimate_noise(run.segments),
        Thresholds(),
        effects,
    )


def _slow_both_ways(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    v = max(_voltage_for_speed(prior, 0.05 * w_top), sc.v_crawl)
    hold = 6.0 * tau
    return [_level("staircase", s * v, hold, sc, "slow") for s in (1.0, -1.0, 1.0, -1.0)]


def _stribeck(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    levels = []
    for frac in STRIBECK_SPEEDS:
        v = _voltage_for_speed(prior, frac * w_top)
        levels.append(min(max(v, 0.3 * sc.v_crawl), sc.v_top))
    # up, up, down, down, ...: the alternate split puts both directions on both sides
    out = []
    for k in range(0, len(levels), 2):
        pair = levels[k : k + 2]
        for sign in (1.0, -1.0):
            for v in pair:
                out.append(_level("staircase", sign * v, 5.0 * tau, sc, "stribeck"))
    return out


def _cogging(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    """Crawls at three slow speeds, each way: cogging shows where its period passes the
    shaft slower than the rotor can follow. A torque ripple at ``f`` moves the current
    by the whole ripple / Kt while ``f`` is below the mechanical bandwidth 1/(2 pi
    tau_m), and by a share ``1 / (2 pi f tau_m)`` of it above (the rotor's inertia
    filters it; the current sees it only through the back-EMF). So each crawl puts the
    cogging frequency of one count per turn (``COG_COUNTS``: the number is unknown) at
    that bandwidth: ``w = 1 / (N tau_m)``, no faster than ``CRAWL_TOP`` of the top speed
    and each at least 3x slower than the next (a geared motor's counts per output turn
    are large: its ladder goes on below the cap).
    The voltage is the prior's steady line (its friction included) with a margin over
    its breakaway; not floored at the family's crawl (2.5-5 % of the top voltage),
    which ran every crawl at the same speed, 5-25x above that bandwidth (an industrial
    motor, 28 periods per turn: 22 Hz against 3.7 Hz, cogging at 5 % of rated torque
    under a detection limit of 29 %). The slowest may stick in a detent where the
    cogging is large: the faster ones then move through it."""
    out = []
    travel = limits.travel_rad
    reach = math.inf
    if travel is not None:
        lo, hi = travel
        reach = 0.5 * (hi - lo - 2.0 * limits.margin_rad) * 0.8  # each crawl half the usable range
    p = prior.model.params
    v_break = p.R * prior.coulomb_nm / p.Kt
    v_min = max(1.5 * v_break, CRAWL_FLOOR * sc.v_top)
    speeds, cap = [], CRAWL_TOP * w_top
    for n in sorted(COG_COUNTS):  # 4, 16, 48 per turn: fastest first
        # a geared motor's bandwidth speed lies above the cap: the ladder goes on below
        w = min(1.0 / (n * max(tau, sc.dt_s)), cap)
        speeds.append(w)
        cap = w / 3.0
    for w in reversed(speeds):
        v = min(max(_voltage_for_speed(prior, w) + 0.5 * v_break, v_min), sc.v_top)
        # a turn (or the reach), and at least ten periods of the count it is sized for;
        # the fastest crawl SPAN_TURNS (see SPAN_TURNS)
        fastest = w == speeds[0]
        dist = min(2.0 * math.pi * (SPAN_TURNS if fastest else 1.0), reach)
        longest = MAX_SPAN_S if fastest else MAX_CRAWL_S
        seconds = min(max(dist / w, 20.0 * math.pi * tau) + 2.0 * tau, longest)
        if travel is not None:
            seconds = min(seconds, reach / w + tau)
        # there and back: the angle returns (a joint stays in its range)
        out.append(_level("crawl", v, seconds, sc, "crawl"))
        out.append(_level("crawl", -v, seconds, sc, "crawl"))
    return out


def _staircase_full(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    out = []
    for frac in (0.25, 0.5, 0.75, 1.0):
        for sign in (1.0, -1.0):
            out.append(_level("staircase", sign * frac * sc.v_top, 4.0 * tau, sc, "drag"))
    return out


def _low_voltage(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    out = []
    for frac in (0.05, 0.1, 0.2):
        v = max(frac * sc.v_top, sc.v_crawl)
        for sign in (1.0, -1.0):
            out.append(_level("staircase", sign * v, 4.0 * tau, sc, "low"))
    f0 = 1.0 / (2.0 * math.pi * tau)
    n = sc.samples(20.0 * tau)
    chirp = log_chirp(n, sc.dt_s, 0.5 * f0, min(10.0 * f0, 0.25 / sc.dt_s), 0.3 * sc.v_top)
    out.append(Candidate("chirp", "sweep", chirp, {"offset": 0.0, "amplitude": 0.3 * sc.v_top,
                                                   "f0": 0.5 * f0, "f1": 10 * f0}))  # fmt: skip
    return out


def _hot_hold(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    ref = 0.5 * sc.v_top
    half = sc.samples(2.0 * tau)
    cycle = np.r_[np.full(half, sc.v_top), np.full(half, -sc.v_top)]
    # heat of one cycle under the prior, roughly: the reversal currents (2 V / R) decay
    # over tau_m; a hold to half the heat budget, at most a minute
    p = prior.model.params
    i_rev = min(2.0 * sc.v_top / p.R, limits.current_use_a)
    heat_cycle = 2.0 * i_rev**2 * tau / 2.0
    budget = 0.5 * limits.heat_a2s if math.isfinite(limits.heat_a2s) else 60.0 * heat_cycle
    cycles = int(min(max(budget / max(heat_cycle, 1e-12), 2), 60.0 / (2 * half * sc.dt_s)))
    hot = np.tile(cycle, cycles)
    step = np.r_[np.zeros(sc.samples(tau)), np.full(sc.samples(5.0 * tau), ref)]
    return [
        Candidate("hold", "step", step, {"v": ref}),
        Candidate("hold", "square", hot, {"amplitude": sc.v_top, "half_s": half * sc.dt_s}),
        Candidate("hold", "step", np.r_[np.zeros(sc.samples(5.0 * tau)), step], {"v": ref}),
    ]


def _sharp_steps(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    out = []
    for sign in (1.0, -1.0):
        v = np.r_[np.zeros(sc.samples(tau)), np.full(sc.samples(3.0 * tau), sign * 0.5 * sc.v_top)]
        out.append(Candidate("step", "step", v, {"v": sign * 0.5 * sc.v_top}))
    return out


def _open_rest(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    return [Candidate("open", "open", np.full(sc.samples(10.0 * tau), math.nan), {})]


def _current_range(prior, limits, sc, w_top, tau):  # type: ignore[no-untyped-def]
    p = prior.model.params
    v_hi = min(sc.v_top, 0.95 * limits.current_use_a * p.R)
    out = []
    for v in (0.2 * v_hi, v_hi, -v_hi):
        seq = np.r_[np.zeros(sc.samples(2.0 * tau)), np.full(sc.samples(2.0 * tau), v)]
        out.append(Candidate("step", "step", seq, {"v": v}))
    return out


#: the recipes by the key an effect names in its ``REVEAL`` hook (core/effects)
RECIPES = {
    "slow_both_ways": _slow_both_ways,
    "stribeck_staircase": _stribeck,
    "crawls": _cogging,
    "full_staircase": _staircase_full,
    "low_voltage": _low_voltage,
    "hot_hold": _hot_hold,
    "sharp_steps": _sharp_steps,
    "open_rest": _open_rest,
    # large currents while moving: friction in proportion to the torque transmitted,
    # inductance falling at the highest current
    "current_range": _current_range,
}
