"""The segments a designed plan is made of: what the driver can play.

From the motor's state under the prior (current, speed, angle), each candidate is one
labelled segment: a voltage **level** held for a duration (a step from rest, a step
between speeds, a reversal, a brake at 0 V, a crawl just above breakaway), an
**open-armature decay** (a coast, J and the friction without the electrical side), a
logarithmic **chirp** (offset, amplitude, band, length) or a **square wave** (back and
forth around zero: direction changes and little travel). Durations and bands scale
with the prior's mechanical time constant; levels with the highest voltage the speed
limit allows. A few **probes** above the voltage limit are evaluated, never chosen:
they tell what the voltage limit costs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.design.limits import PlanLimits
from pmdc_ident.core.design.prior import Prior
from pmdc_ident.core.excitation import log_chirp

__all__ = ["Candidate", "Scales", "candidates", "coastdowns"]

FloatArray = NDArray[np.float64]
LEVELS = (-1.0, -0.75, -0.5, -0.25, 0.25, 0.5, 0.75, 1.0)
LEVEL_TAU = (1.0, 2.0, 4.0, 8.0)
DECAY_FRACTIONS = (0.3, 0.6, 0.9)
DECAY_CAP_TAU = 40.0  # a decay at most this many tau_m long
SPIN_UP_TAU = 6.0  # a coast-down's spin-up, as the default sequence's: 99.8 % of its speed
CHIRP_TAU = (6.0, 12.0)
SQUARE_AMPLITUDES = (0.5, 1.0)
SQUARE_HALF_TAU = (0.5, 1.0, 2.0)
SQUARE_CYCLES = (2, 4)
PROBE_FACTOR = 1.25  # voltage probes: this times the voltage limit
MIN_SAMPLES = 12


@dataclass(frozen=True)
class Candidate:
    """One segment the driver can play: its label prefix, its samples and its settings."""

    kind: str  # level, decay, chirp, square (reveal: crawl, hold, ...)
    prefix: str  # label prefix: step, coast, sweep, square, ...
    voltage: FloatArray = field(repr=False)
    settings: dict[str, float] = field(default_factory=dict)
    probe: str = ""  # a limit this candidate breaks on purpose ("voltage")

    @property
    def n(self) -> int:
        return int(self.voltage.size)

    def describe(self) -> str:
        s = self.settings
        if self.kind == "level":
            return f"level {s['v']:+.3g} V"
        if self.kind == "decay":
            return "armature open (coast)"
        if self.kind == "coastdown":
            return f"spin-up {s['v']:+.3g} V, then armature open {s['t_s']:.3g} s (coast)"
        if self.kind == "chirp":
            return (
                f"chirp {s['offset']:+.3g} V +- {s['amplitude']:.3g} V, "
                f"{s['f0']:.3g}-{s['f1']:.3g} Hz"
            )
        if self.kind == "pattern":
            return f"the last {s['segments']:.0f} segment(s) again, {s['times']:.0f} times"
        if self.kind == "stop":
            return f"ramp {s['v']:+.3g} V -> 0 V (to rest)"
        if self.kind == "square":
            return f"square +-{s['amplitude']:.3g} V, half period {s['half_s'] * 1e3:.3g} ms"
        if "v" in s:
            return f"level {s['v']:+.3g} V ({self.kind})"
        return ", ".join(f"{k} {v:.3g}" for k, v in s.items()) or self.kind


@dataclass(frozen=True)
class Scales:
    """The prior's time and voltage scales the family is sized by."""

    dt_s: float
    tau_m_s: float
    tau_e_s: float
    unit_s: float  # the duration unit: tau_m, at least a few samples
    v_top: float  # highest level: the voltage limit, or the speed limit's voltage
    v_crawl: float  # just above breakaway (a slow speed)

    @classmethod
    def of(cls, prior: Prior, limits: PlanLimits, dt_s: float) -> Scales:
        p = prior.model.params
        tau_m = p.mechanical_time_constant_s
        unit = max(tau_m, 4.0 * dt_s)
        # steady speed w at voltage V: (Kt V - R T) / (R B + Ke Kt)
        den = p.R * p.B + p.Ke * p.Kt
        t_fric = prior.coulomb_nm
        v_for_speed = (0.95 * limits.speed_use_rad_s * den + p.R * t_fric) / p.Kt
        v_top = min(limits.voltage_max_v, v_for_speed)
        v_break = p.R * prior.breakaway_nm / p.Kt
        v_crawl = min(max(1.5 * v_break + 0.02 * v_top, 0.05 * v_top), 0.5 * v_top)
        return cls(dt_s, tau_m, p.L / p.R, unit, v_top, v_crawl)

    def samples(self, seconds: float) -> int:
        return max(MIN_SAMPLES, int(round(seconds / self.dt_s)))


def coastdowns(prior: Prior, sc: Scales) -> list[Candidate]:
    """Spin up at the top level either way, then open the armature for a share of the
    stop time from that speed: the default sequence's coast-down as one segment (the
    planner's :func:`~.planner._with_coastdown` tries a plan from each). Its information
    on B grows much faster than its length (B is told from the Coulomb torque by how the
    deceleration changes with speed), which a greedy choice by gain per second where it
    stands does not see. The spin-up is the default sequence's, so the armature opens on
    the no-load current (opened mid-transient, 1.6 A through the industrial motor's
    28 mH, the independent generator's record showed a held-out gap of 476 noise RMS
    that a 24 ms lag closed). Only where the rotor coasts longer than the family's decays go
    (``DECAY_CAP_TAU`` tau_m): elsewhere those decays already span the coast. (There,
    on the 500 Hz gearmotor, a coast-down cut to 17 open samples left B 2.5 % off on
    the project's own simulator, against a predicted sd of 0.9 %: not understood.)"""
    p = prior.model.params
    den = p.R * p.B + p.Ke * p.Kt
    out = []
    for sign in (1.0, -1.0):
        v = sign * sc.v_top
        w = (p.Kt * abs(v) - p.R * prior.coulomb_nm) / den if den > 0 else 0.0
        if w <= 0:
            continue
        spin = np.full(sc.samples(SPIN_UP_TAU * sc.unit_s), v)
        t_stop = _stop_time(prior, w)
        if not t_stop > DECAY_CAP_TAU * sc.unit_s:
            continue
        for frac in DECAY_FRACTIONS:
            dur = frac * t_stop
            if not math.isfinite(dur):
                continue
            out.append(
                Candidate(
                    "coastdown",
                    "coast",
                    np.concatenate([spin, np.full(sc.samples(dur), math.nan)]),
                    {"v": v, "t_s": dur},
                )
            )
    return out


def _stop_time(prior: Prior, w: float) -> float:
    """Coast time from speed ``w`` to rest under the prior's friction (capped)."""
    p = prior.model.params
    tc = prior.coulomb_nm
    a = p.B / p.J
    w = abs(w)
    if tc > 0 and a > 0:
        return math.log1p(a * p.J * w / tc) / a
    if tc > 0:
        return p.J * w / tc
    return 3.0 / a if a > 0 else math.inf


def candidates(
    prior: Prior, limits: PlanLimits, sc: Scales, speed_now: float, position_now: float = 0.0
) -> list[Candidate]:
    """Every candidate segment from a state at ``speed_now`` (rad/s) and ``position_now``
    (rad). With a travel range, shorter levels and faster square waves join the family
    (a joint with a few turns of travel takes steps of a fraction of tau_m), and square
    waves start towards the middle of the range."""
    travel = limits.travel_rad is not None
    level_tau = ((0.125, 0.25, 0.5) if travel else ()) + LEVEL_TAU
    square_half = ((0.1, 0.2, 0.35) if travel else ()) + SQUARE_HALF_TAU
    out: list[Candidate] = []
    for frac in (*LEVELS, 0.0):
        v = frac * sc.v_top
        if frac == 0.0 and abs(speed_now) < 1e-9:
            continue  # 0 V at rest does nothing
        for k in level_tau:
            out.append(Candidate("level", "step", np.full(sc.samples(k * sc.unit_s), v), {"v": v}))
    for sign in (-1.0, 1.0):
        v = sign * sc.v_crawl
        for k in (*((1.0, 2.0) if travel else ()), 4.0, 8.0):
            out.append(Candidate("level", "step", np.full(sc.samples(k * sc.unit_s), v), {"v": v}))
    if abs(speed_now) > 0.02 * sc.v_top / max(prior.model.params.Ke, 1e-12):
        t_stop = _stop_time(prior, speed_now)
        for frac in DECAY_FRACTIONS:
            dur = min(frac * t_stop, DECAY_CAP_TAU * sc.unit_s)
            out.append(
                Candidate("decay", "coast", np.full(sc.samples(dur), math.nan), {"t_s": dur})
            )
    f_lo = 1.0 / (2.0 * math.pi * sc.unit_s)
    f_ny = 0.25 / sc.dt_s
    f_hi = min(f_ny, max(10.0 * f_lo, 1.0 / (2.0 * math.pi * max(sc.tau_e_s, sc.dt_s))))
    bands = [(0.2 * f_lo, min(3.0 * f_lo, f_ny)), (0.2 * f_lo, f_hi)]
    if travel:
        bands.append((min(2.0 * f_lo, 0.5 * f_hi), f_hi))
    for offset in (0.0,) if travel else (0.0, 0.5, -0.5):
        amp = (1.0 - abs(offset)) * sc.v_top
        for f0, f1 in bands:
            if not f1 > 1.5 * f0:
                continue
            for k in CHIRP_TAU:
                n = sc.samples(k / (2.0 * math.pi * f0))  # a few periods of f0
                n = min(n, sc.samples(40.0 * sc.unit_s))
                v = log_chirp(n, sc.dt_s, f0, f1, amp, offset * sc.v_top)
                out.append(
                    Candidate(
                        "chirp",
                        "sweep",
                        v,
                        {"offset": offset * sc.v_top, "amplitude": amp, "f0": f0, "f1": f1},
                    )
                )
    first = -1.0 if speed_now > 0 else 1.0  # start against the motion: a reversal first
    if travel:
        lo, hi = limits.travel_rad  # type: ignore[misc]
        off = position_now - 0.5 * (lo + hi)
        if abs(off) > 0.05 * (hi - lo):
            first = -math.copysign(1.0, off)  # towards the middle
    for a in (0.25, *SQUARE_AMPLITUDES) if travel else SQUARE_AMPLITUDES:
        for h in square_half:
            half = sc.samples(h * sc.unit_s)
            for cycles in SQUARE_CYCLES:
                # half a half-period first: the angle swings about where it started
                v = np.concatenate(
                    [np.full(max(half // 2, 1), first)]
                    + [np.full(half, first * (-1.0) ** (k + 1)) for k in range(2 * cycles - 1)]
                    + [np.full(half - max(half // 2, 1), first * (-1.0) ** (2 * cycles))]
                )
                out.append(
                    Candidate(
                        "square",
                        "square",
                        a * sc.v_top * v,
                        {"amplitude": a * sc.v_top, "half_s": half * sc.dt_s},
                    )
                )
    probe = PROBE_FACTOR * limits.voltage_max_v
    if probe * 0.999 > sc.v_top:
        for sign in (-1.0, 1.0):
            for k in (2.0, 4.0):
                out.append(
                    Candidate(
                        "level",
                        "step",
                        np.full(sc.samples(k * sc.unit_s), sign * probe),
                        {"v": sign * probe},
                        probe="voltage",
                    )
                )
    return out
