"""The benchmark's effects: several equations per vocabulary name, graded sizes.

None of the equations is the candidate's own (``core/effects.py``) except where
the physics has one form (a constant load torque, a constant offset, a sign-law
Coulomb friction), and each name always has at least two that differ:

=====================  ===========================================================
name                   equations (``equation`` field)
=====================  ===========================================================
coulomb_friction       karnopp (sign law, stick), tanh (smoothed), lugre (bristles)
stribeck_friction      exp (first-power), lorentz (1/(1+x^2)), lugre_gauss
                       (breakaway torque alone, without a Coulomb base)
quadratic_drag         power (|w|^n, n in 1.6-2.4 but not 2), transition
                       (laminar -> turbulent: c w sqrt(w_tr^2 + w^2))
load_torque            constant, lead_screw (efficiency: lifting T/eta, lowering
                       T eta), hanging_mass (gravity on a load inertia behind a
                       compliant cable)
brush_drop             tanh, saturating (1 - exp), power (|i|^0.2-0.4)
dead_zone              hard (zero inside, unshifted outside), soft (v - d tanh(v/d))
cogging                harmonics (1st + 2nd + 3rd), clipped (trapezoid), eccentric
                       (amplitude modulated once per motor turn); on geared motors
                       from the motor (periods x ratio per output turn) or from the
                       gear mesh (output teeth per turn)
resistance_drift       integral (R(T) in the heating), first_order (winding to
                       ambient, tau fitted by nobody), two_node (winding + housing,
                       magnets weaken with the housing temperature)
delay                  transport (fractional samples), lag (first order),
                       transport_lag (half each)
current_offset         constant, warm_up (offset drifts to a fraction, first order)
inductance_saturation  sech2 (flux tanh), frohlich (psi = a i/(1 + |i|/Is)),
                       piecewise (linear fall between two currents)
=====================  ===========================================================

The vocabulary is the effects registry's (``core.effects.EFFECT_TYPES``): every
effect that declares a ``BENCHMARK_LADDER``, in registry order. Sizes are graded on
that ladder of four levels per name (``LADDERS``), in a user's units: % of rated
torque (``T_rated`` = Kt x rated current; drag at the no-load speed), % of rated
voltage, % of R (rise over the session), samples of delay (the report adds ms), % of
rated current, % fall of L at the session's peak current. The equations stay here,
written apart from the candidates' (``GENERATORS`` draws each name); a test checks that
every laddered effect has its equations and generator, and every default candidate its
ladder.

Out-of-vocabulary effects (``OOV_NAMES``) have no candidate: a torque ripple at a
frequency unrelated to the angle, backlash to a load inertia, a supply that sags
with current, a two-mass resonance, armature reaction (field weakening at high
current).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.benchmark import plant as pl
from pmdc_ident.benchmark.motors import BenchMotor
from pmdc_ident.core.effects import EFFECT_TYPES

__all__ = [
    "EQUATIONS",
    "GENERATORS",
    "LADDERS",
    "OOV_NAMES",
    "VOCABULARY",
    "Context",
    "TrueEffect",
    "apply_effects",
    "draw_effect",
]

FloatArray = NDArray[np.float64]

VOCABULARY: tuple[str, ...] = tuple(
    n for n, cls in EFFECT_TYPES.items() if cls.BENCHMARK_LADDER is not None
)
OOV_NAMES: tuple[str, ...] = (
    "torque_ripple",
    "backlash",
    "supply_sag",
    "two_mass_resonance",
    "armature_reaction",
)
EQUATIONS: dict[str, tuple[str, ...]] = {
    "coulomb_friction": ("karnopp", "tanh", "lugre"),
    "stribeck_friction": ("exp", "lorentz", "lugre_gauss"),
    "quadratic_drag": ("power", "transition"),
    "load_torque": ("constant", "lead_screw", "hanging_mass"),
    "brush_drop": ("tanh", "saturating", "power"),
    "dead_zone": ("hard", "soft"),
    "cogging": ("harmonics", "clipped", "eccentric"),
    "resistance_drift": ("integral", "first_order", "two_node"),
    "delay": ("transport", "lag", "transport_lag"),
    "current_offset": ("constant", "warm_up"),
    "inductance_saturation": ("sech2", "frohlich", "piecewise"),
    **{n: ("oov",) for n in OOV_NAMES},
}
# (unit, four graded sizes), from each effect's BENCHMARK_LADDER
LADDERS: dict[str, tuple[str, tuple[float, ...]]] = {
    n: (ladder.unit, ladder.sizes)
    for n, cls in EFFECT_TYPES.items()
    if (ladder := cls.BENCHMARK_LADDER) is not None
}
ALPHA_CU = 0.00393  # 1/K


@dataclass(frozen=True)
class Context:
    """What an effect is sized against: the motor, the rate and a clean session."""

    motor: BenchMotor
    rate_hz: float
    duration_s: float
    peak_current_a: float
    current_sq: FloatArray = field(repr=False)  # i^2 of the clean session (0 when open)


@dataclass(frozen=True)
class TrueEffect:
    """One generated effect: its name, equation, size and plant settings."""

    name: str
    equation: str
    level: int  # index into LADDERS[name]; -1 for out-of-vocabulary effects
    size: float  # in ``unit``
    unit: str
    settings: tuple[tuple[int, float], ...] = ()  # (plant.P_* index, value)
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor offset start, end, tau

    @property
    def in_vocabulary(self) -> bool:
        return self.name in VOCABULARY

    def describe(self) -> dict[str, object]:
        names = {v: k for k, v in vars(pl).items() if k.startswith("P_") and isinstance(v, int)}
        return {
            "name": self.name,
            "equation": self.equation,
            "level": self.level,
            "size": self.size,
            "unit": self.unit,
            "settings": {names.get(i, str(i)): v for i, v in self.settings},
            "offset": list(self.offset),
        }


def apply_effects(p: FloatArray, effects: tuple[TrueEffect, ...]) -> FloatArray:
    q = p.copy()
    for e in effects:
        for i, v in e.settings:
            q[i] = v
    return q


def _size(name: str, level: int) -> tuple[str, float]:
    unit, sizes = LADDERS[name]
    return unit, sizes[level]


def _lugre(tc_plus_ts: float, m: BenchMotor) -> list[tuple[int, float]]:
    """Bristle stiffness for a presliding angle of ~1e-4 rad, damped critically."""
    z0 = 1e-4
    sig0 = tc_plus_ts / z0
    # keep the bristle resonance below ~3 kHz (a stiffer one changes nothing measurable)
    sig0 = min(sig0, m.params.J * (2 * math.pi * 3000.0) ** 2)
    return [(pl.P_FRIC, 3.0), (pl.P_SIG0, sig0), (pl.P_SIG1, 2.0 * math.sqrt(sig0 * m.params.J))]


def _friction(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    m = ctx.motor
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm
    w0 = m.speed_no_load_rad_s
    s: list[tuple[int, float]] = []
    if name == "coulomb_friction":
        s.append((pl.P_TC, t))
        if eq == "karnopp":
            s.append((pl.P_FRIC, 1.0))
        elif eq == "tanh":
            s += [(pl.P_FRIC, 2.0), (pl.P_WT, rng.uniform(0.005, 0.02) * w0)]
        else:
            s += _lugre(t, m)
    else:  # stribeck: breakaway torque alone
        s += [(pl.P_TS, t), (pl.P_WS, rng.uniform(0.02, 0.08) * w0)]
        if eq == "exp":
            s += [(pl.P_FRIC, 1.0), (pl.P_STRIB, 1.0)]
        elif eq == "lorentz":
            s += [(pl.P_FRIC, 1.0), (pl.P_STRIB, 3.0)]
        else:
            s += [(pl.P_STRIB, 2.0), *_lugre(t, m)]
    return TrueEffect(name, eq, level, size, unit, tuple(s))


def _torques(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    m = ctx.motor
    p = m.params
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm
    w0 = m.speed_no_load_rad_s
    s: list[tuple[int, float]] = []
    if name == "quadratic_drag":
        if eq == "power":
            n = float(rng.choice([rng.uniform(1.6, 1.85), rng.uniform(2.15, 2.4)]))
            s += [(pl.P_DRAG, 1.0), (pl.P_CQ, t / w0**n), (pl.P_NEXP, n)]
        else:
            wtr = rng.uniform(0.1, 0.3) * w0
            s += [(pl.P_DRAG, 2.0), (pl.P_CQ, t / (w0 * math.hypot(wtr, w0))), (pl.P_WTR, wtr)]
    elif name == "load_torque":
        t *= float(rng.choice([-1.0, 1.0]))
        s.append((pl.P_TL, t))
        if eq == "constant":
            s.append((pl.P_LOAD, 1.0))
        elif eq == "lead_screw":
            s += [(pl.P_LOAD, 2.0), (pl.P_ETA, rng.uniform(0.85, 0.95))]
        else:  # hanging mass: its inertia behind a cable, resonance far above tau_m
            jl = rng.uniform(0.1, 0.5) * p.J
            f_c = min(
                rng.uniform(8.0, 15.0) / (2 * math.pi * p.mechanical_time_constant_s),
                0.2 * ctx.rate_hz,
            )
            kc = (2 * math.pi * f_c) ** 2 / (1.0 / p.J + 1.0 / jl)
            cc = 2 * 0.5 * math.sqrt(kc * jl)
            s += [(pl.P_LOAD, pl.GRAVITY_LOAD), (pl.P_COUPLE, 1.0), (pl.P_JL, jl),
                  (pl.P_KC, kc), (pl.P_CC, cc)]  # fmt: skip
    else:  # cogging
        s += _cogging(eq, t, ctx, rng)
    return TrueEffect(name, eq, level, size, unit, tuple(s))


def cogging_periods(ctx: Context, rng: np.random.Generator) -> float:
    """Periods per measured turn, resolvable at the rate at half the no-load speed."""
    m = ctx.motor
    rev_per_s = 0.5 * m.speed_no_load_rad_s / (2 * math.pi)
    options = [float(n) * m.gear_ratio for n in m.cogging_motor_periods]
    if m.gear_teeth_output:
        options.append(float(m.gear_teeth_output))
    ok = [n for n in options if n * rev_per_s <= 0.5 * ctx.rate_hz]
    if not ok:
        msg = f"no cogging of {m.name} is resolvable at {ctx.rate_hz:g} Hz"
        raise ValueError(msg)
    return float(rng.choice(ok))


def _cogging(eq: str, t: float, ctx: Context, rng: np.random.Generator) -> list[tuple[int, float]]:
    n = cogging_periods(ctx, rng)
    s = [(pl.P_NP, n), (pl.P_PH, rng.uniform(-math.pi, math.pi))]
    if eq == "harmonics":
        a2, a3 = rng.uniform(0.2, 0.5), rng.uniform(0.0, 0.3)
        ph2, ph3 = rng.uniform(-math.pi, math.pi, 2)
        th = np.linspace(0, 2 * math.pi, 2001)
        wave = np.sin(th) + a2 * np.sin(2 * th + ph2) + a3 * np.sin(3 * th + ph3)
        peak = float(np.max(np.abs(wave)))
        s += [(pl.P_COG, 1.0), (pl.P_TCOG, t / peak), (pl.P_A2, a2), (pl.P_A3, a3),
              (pl.P_PH2, ph2), (pl.P_PH3, ph3)]  # fmt: skip
    elif eq == "clipped":
        s += [(pl.P_COG, 2.0), (pl.P_TCOG, t)]
    else:
        s += [(pl.P_COG, 3.0), (pl.P_TCOG, t), (pl.P_ECC, rng.uniform(0.2, 0.5)),
              (pl.P_NECC, ctx.motor.gear_ratio)]  # fmt: skip
    return s


def _thermal_unit(ctx: Context, tau_w: float, tau_h: float, cratio: float, eq: str) -> float:
    """Largest winding temperature rise for a heating gain of 1 K/J at R (no feedback)."""
    dt = 1.0 / ctx.rate_hz
    r = ctx.motor.params.R
    tw = th = 0.0
    peak = 0.0
    for q in ctx.current_sq:
        heat = q * r
        if eq == "integral":
            tw += heat * dt
        elif eq == "first_order":
            tw += (heat - tw / tau_w) * dt
        else:
            dtw = heat - (tw - th) / tau_w
            th += (cratio * (tw - th) / tau_w - th / tau_h) * dt
            tw += dtw * dt
        peak = max(peak, tw)
    return max(peak, 1e-30)


def _electrical(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    m = ctx.motor
    unit, size = _size(name, level)
    s: list[tuple[int, float]] = []
    offset = (0.0, 0.0, 0.0)
    if name == "brush_drop":
        vb = size / 100.0 * m.voltage_rated_v
        i0 = rng.uniform(0.02, 0.1) * m.current_rated_a
        if eq == "tanh":
            s += [(pl.P_BRUSH, 1.0), (pl.P_VB, vb), (pl.P_I0, i0)]
        elif eq == "saturating":
            s += [(pl.P_BRUSH, 2.0), (pl.P_VB, vb), (pl.P_I0, i0)]
        else:  # vb at rated current
            pw = rng.uniform(0.2, 0.4)
            s += [(pl.P_BRUSH, 3.0), (pl.P_VB, vb / m.current_rated_a**pw), (pl.P_I0, i0),
                  (pl.P_PW, pw)]  # fmt: skip
    elif name == "dead_zone":
        s += [(pl.P_DZ, 1.0 if eq == "hard" else 2.0), (pl.P_VD, size / 100 * m.voltage_rated_v)]
    elif name == "resistance_drift":
        session = ctx.duration_s
        tau_w = session * rng.uniform(0.2, 3.0)
        tau_h, cratio = 20.0 * tau_w, 0.3
        unit_rise = _thermal_unit(ctx, tau_w, tau_h, cratio, eq)
        k = size / 100.0 / ALPHA_CU / unit_rise
        s += [(pl.P_KHEAT, k), (pl.P_TAUW, tau_w), (pl.P_TAUH, tau_h), (pl.P_CRATIO, cratio)]
        s.append((pl.P_THERM, {"integral": 1.0, "first_order": 2.0, "two_node": 3.0}[eq]))
        if eq == "two_node":
            s.append((pl.P_BETA, -0.0012))  # NdFeB-like, 1/K at the housing temperature
    elif name == "delay":
        d = size / ctx.rate_hz
        if eq == "transport":
            s.append((pl.P_DELAY, d))
        elif eq == "lag":
            s.append((pl.P_LAG, d))
        else:
            s += [(pl.P_DELAY, 0.5 * d), (pl.P_LAG, 0.5 * d)]
    elif name == "current_offset":
        o = size / 100.0 * m.current_rated_a * float(rng.choice([-1.0, 1.0]))
        if eq == "constant":
            offset = (o, o, 0.0)
        else:  # warm-up: starts at 1.5x, settles at 0.5x the nominal size
            offset = (1.5 * o, 0.5 * o, rng.uniform(0.3, 1.0) * ctx.duration_s)
    else:  # inductance saturation: L falls by `size` % at the session's peak current
        s += _saturation(eq, size / 100.0, ctx.peak_current_a, rng)
    return TrueEffect(name, eq, level, size, unit, tuple(s), offset)


def _saturation(eq: str, fall: float, ip: float, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    keep = 1.0 - fall
    if eq == "sech2":
        rho = rng.uniform(0.05, 0.8) * keep
        x = math.acosh(1.0 / math.sqrt((keep - rho) / (1.0 - rho)))
        return [(pl.P_LS, 1.0), (pl.P_ISAT, ip / x), (pl.P_LRHO, rho)]
    if eq == "frohlich":
        return [(pl.P_LS, 2.0), (pl.P_ISAT, ip / (1.0 / math.sqrt(keep) - 1.0))]
    i1 = rng.uniform(0.2, 0.5) * ip
    i2 = rng.uniform(1.05, 1.3) * ip
    f = (ip - i1) / (i2 - i1)
    rho = max(1.0 - fall / f, 0.05)
    return [(pl.P_LS, 3.0), (pl.P_ISAT, i1), (pl.P_I2, i2), (pl.P_LRHO, rho)]


def _oov(name: str, ctx: Context, rng: np.random.Generator) -> TrueEffect:
    m = ctx.motor
    p = m.params
    tr = m.torque_rated_nm
    f_m = 1.0 / (2 * math.pi * p.mechanical_time_constant_s)
    s: list[tuple[int, float]]
    if name == "torque_ripple":
        size = rng.uniform(10.0, 25.0)
        f = math.exp(rng.uniform(math.log(2 * f_m), math.log(0.1 * ctx.rate_hz)))
        s = [(pl.P_RIP_T, size / 100 * tr), (pl.P_RIP_F, f)]
        unit = "% rated torque"
    elif name in ("backlash", "two_mass_resonance"):
        jl = rng.uniform(1.0, 3.0) * p.J
        f_c = min(rng.uniform(3.0, 8.0) * f_m * math.sqrt(1 + jl / p.J), 0.15 * ctx.rate_hz)
        kc = (2 * math.pi * f_c) ** 2 / (1.0 / p.J + 1.0 / jl)
        zeta = 0.05 if name == "two_mass_resonance" else 0.3
        s = [(pl.P_COUPLE, 1.0), (pl.P_JL, jl), (pl.P_KC, kc),
             (pl.P_CC, 2 * zeta * math.sqrt(kc * jl)), (pl.P_BL, 0.0)]  # fmt: skip
        size, unit = jl / p.J * 100.0, "% of J (load inertia)"
        if name == "backlash":
            gap = math.radians(rng.uniform(1.0, 4.0))
            s += [(pl.P_COUPLE, 2.0), (pl.P_GAP, gap)]
            size, unit = math.degrees(gap), "deg of play"
    elif name == "supply_sag":
        size = rng.uniform(50.0, 150.0)
        s = [(pl.P_SAG_RS, size / 100 * p.R), (pl.P_VBUS, m.voltage_rated_v)]
        unit = "% of R (supply resistance)"
    else:  # armature reaction
        size = rng.uniform(15.0, 30.0)
        s = [(pl.P_AR, size / 100.0), (pl.P_AR_I, 0.5 * m.voltage_rated_v / p.R)]
        unit = "% flux loss at half the stall current (limit)"
    return TrueEffect(name, "oov", -1, float(size), unit, tuple(s))


# the generator of each vocabulary name (its equations are in EQUATIONS)
GENERATORS = {
    "coulomb_friction": _friction,
    "stribeck_friction": _friction,
    "quadratic_drag": _torques,
    "load_torque": _torques,
    "cogging": _torques,
    "brush_drop": _electrical,
    "dead_zone": _electrical,
    "resistance_drift": _electrical,
    "delay": _electrical,
    "current_offset": _electrical,
    "inductance_saturation": _electrical,
}


def draw_effect(
    name: str, level: int, ctx: Context, rng: np.random.Generator, equation: str | None = None
) -> TrueEffect:
    """One effect of ``name`` at ladder ``level`` (an equation drawn unless given)."""
    if name in OOV_NAMES:
        return _oov(name, ctx, rng)
    eq = equation or str(rng.choice(EQUATIONS[name]))
    if eq not in EQUATIONS.get(name, ()):
        msg = f"{name} has no equation {eq!r}; known: {EQUATIONS.get(name)}"
        raise ValueError(msg)
    return GENERATORS[name](name, eq, level, ctx, rng)
