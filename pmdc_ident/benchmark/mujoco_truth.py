"""The MuJoCo plant's effects: what ``<dcmotor>``, the joint, a second body or the drive
adds, in graded sizes, and which candidate is the right name for each.

Each effect is drawn as settings of :class:`~.mujoco_plant.MjPlant` (what MuJoCo
simulates), of :class:`~.mujoco_plant.Chain` (what the drive does outside MuJoCo) or of
the current sensor's offset. The sizes are the project's ladders in users' units (the
effects registry's ``BENCHMARK_LADDER``, as for the generator), the equations MuJoCo's.

``TRUTH_TABLE`` says, for every equation, which candidate is the right name and why.
It was written before any MuJoCo run was diagnosed (docs/mujoco.md prints it; a test
keeps the two equal), and scoring follows it: a run is right when its first name is
the table's (ties as for the generator), an out-of-vocabulary run when it ends
``unexplained``.

``inductance_saturation`` has no MuJoCo equation (``<dcmotor>``'s L is a constant)
and is not in this plant's vocabulary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pmdc_ident.benchmark.motors import BenchMotor
from pmdc_ident.benchmark.truth import ALPHA_CU, LADDERS, Context

__all__ = [
    "MJ_COMPOUNDS",
    "MJ_EQUATIONS",
    "MJ_OOV_NAMES",
    "MJ_VOCABULARY",
    "TRUTH_TABLE",
    "MjEffect",
    "TruthRow",
    "draw_mj_effect",
    "mj_eligible",
]


@dataclass(frozen=True)
class TruthRow:
    name: str  # the effect the run carries (vocabulary name or out-of-vocabulary name)
    equation: str
    where: str  # who simulates it: <dcmotor>, the joint, a second body, the drive ...
    mechanism: str  # the MuJoCo model or the outside equation
    right: str  # the right first name (or "unexplained")
    why: str


TRUTH_TABLE: tuple[TruthRow, ...] = (
    TruthRow("coulomb_friction", "frictionloss", "joint",
             "frictionloss = T (MuJoCo's dry-friction constraint, solreffriction = a fifth "
             "of a sample)", "coulomb_friction",
             "a torque of constant size against the motion, holding the rotor at rest: "
             "the candidate's law, solved by MuJoCo's constraint solver"),
    TruthRow("coulomb_friction", "lugre", "<dcmotor>",
             "lugre = sigma0 sigma1 Fc Fc vs (static = Coulomb: no Stribeck fall), "
             "bristles deflecting 1e-4 rad", "coulomb_friction",
             "LuGre's bristles have no candidate: their pre-sliding travel (1e-4 rad) is "
             "under one encoder count and settles within a sample, so what the data show "
             "is a constant torque against the motion with stiction: Coulomb friction"),
    TruthRow("stribeck_friction", "lugre_gauss", "<dcmotor>",
             "lugre = sigma0 sigma1 Fc Ts vs: g(v) = Fc + (Ts - Fc) exp(-(v/vs)^2) with a "
             "Coulomb floor Fc of 2 % of Ts (MuJoCo's bristle equation diverges where g "
             "falls to 0)", "stribeck_friction",
             "a breakaway torque that falls with speed: the Stribeck candidate's extra "
             "torque (its Gaussian shape); the floor is at most 1 % of rated torque, under "
             "Coulomb friction's detection limit, and the bristles only carry the torque "
             "through zero speed"),
    TruthRow("quadratic_drag", "quadratic", "joint",
             "damping = B b: -(B w + b w|w|)", "quadratic_drag",
             "a torque growing as w|w|: the candidate's law, in MuJoCo's polynomial damping"),
    TruthRow("quadratic_drag", "quadratic_cubic", "joint",
             "damping = B b c: -(B w + b w|w| + c w^3), the cubic 30-60 % of the drag at "
             "the no-load speed", "quadratic_drag",
             "a drag growing faster than w, odd in w: the quadratic candidate is the nearest "
             "(as for the generator's |w|^n, n != 2)"),
    TruthRow("load_torque", "applied", "joint",
             "qfrc_applied = -T, constant", "load_torque",
             "a constant torque whatever the direction"),
    TruthRow("load_torque", "hanging_mass", "second body",
             "a mass m on a slide joint under gravity, tied to the shaft by a fixed tendon "
             "x - r theta with a spring and a damper (a cable on a drum, its resonance "
             "8-15x the mechanical bandwidth, damping ratio 0.5): m g r, with m r^2 = 10-50 % "
             "of J",
             "load_torque",
             "gravity through the cable is a constant torque whatever the direction; the "
             "added inertia is absorbed by J, the cable's stretch by nothing (a small "
             "resonance far above the mechanical time constant)"),
    TruthRow("cogging", "motor", "<dcmotor>",
             "cogging = A poles phase: A sin(poles theta_motor + phase), poles = the motor's "
             "slots x poles (x the gear ratio per output turn)", "cogging",
             "a torque periodic in the shaft angle"),
    TruthRow("cogging", "gear_mesh", "passive <dcmotor>",
             "a second, passive dcmotor (input none, motorconst 0) on the output with "
             "cogging = A teeth phase", "cogging",
             "a torque periodic in the output angle (the mesh's teeth per turn)"),
    TruthRow("cogging", "two_harmonics", "<dcmotor> + passive <dcmotor>",
             "the motor's cogging plus a passive dcmotor at twice its poles, 20-50 % of its "
             "amplitude", "cogging",
             "a torque periodic in the shaft angle with a second harmonic; the candidate "
             "fits the strongest period"),
    TruthRow("resistance_drift", "thermal_fast", "<dcmotor>",
             "thermal = R_th C 0 alpha 25 25 (copper alpha = 0.00393/K), tau = R_th C = "
             "0.2-1 session: R (1 + alpha T), dT/dt = (R(T) i^2 - T/R_th) / C",
             "resistance_drift",
             "the winding heats and R rises: the candidate's first-order heating (MuJoCo's "
             "heat is R(T) i^2, the candidate's R i^2, and MuJoCo's L rises with R: second "
             "order)"),
    TruthRow("resistance_drift", "thermal_slow", "<dcmotor>",
             "the same with tau = 3-30 sessions (nearly the heat integral)",
             "resistance_drift", "R rising with the heat put in: the candidate's heat integral"),
    TruthRow("delay", "transport", "<dcmotor>",
             "delay = d, nsample: the command read from MuJoCo's own ctrl history",
             "delay", "the command reaches the motor late"),
    TruthRow("delay", "lag", "the drive (outside MuJoCo)",
             "a first-order lag of the drive's output on the command, at every MuJoCo step",
             "delay", "the candidate's second form (a transport delay then a lag)"),
    TruthRow("delay", "transport_lag", "<dcmotor> + the drive",
             "MuJoCo's delay of half the size, then the drive's lag of the other half",
             "delay", "the candidate's second form"),
    TruthRow("dead_zone", "hard", "the drive (outside MuJoCo)",
             "commands within +-V become 0, others pass unchanged", "dead_zone",
             "the driver ignores small commands"),
    TruthRow("dead_zone", "soft", "the drive (outside MuJoCo)",
             "v - V tanh(v / V)", "dead_zone", "the driver ignores small commands (softly)"),
    TruthRow("brush_drop", "tanh", "outside MuJoCo, from MuJoCo's current",
             "Vb tanh(i / i0) subtracted from the terminal voltage at every MuJoCo step "
             "(i0 2-10 % of the rated current)", "brush_drop",
             "MuJoCo's motor has no contact drop: it is added to the voltage MuJoCo's winding "
             "sees, with the sign of MuJoCo's current"),
    TruthRow("current_offset", "constant", "the current sensor",
             "a constant offset before the ADC", "current_offset",
             "the sensor reads non-zero at zero current"),
    TruthRow("current_offset", "warm_up", "the current sensor",
             "an offset from 1.5x to 0.5x its size, first order over the session",
             "current_offset", "the sensor reads non-zero at zero current (drifting)"),
    TruthRow("backlash", "oov", "second body",
             "a load inertia (1-3 J) on a second hinge with +-1-4 deg of free play "
             "(joint limits, stiff end stops)", "unexplained",
             "no candidate has free play"),
    TruthRow("flexible_coupling", "oov", "second body",
             "a load inertia (1-3 J) on a second hinge with a joint spring and a light "
             "damper (a two-mass resonance 3-8x the mechanical bandwidth)", "unexplained",
             "no candidate has a second inertia"),
    TruthRow("torque_saturation", "oov", "<dcmotor>",
             "saturation = T 0 0: K i clamped at 35-70 % of the session's peak torque",
             "unexplained",
             "no candidate limits the torque at high current (inductance_saturation changes "
             "L, not the torque; the current still flows)"),
    TruthRow("current_rate_limit", "oov", "<dcmotor>",
             "saturation = 0 0 r: di/dt clamped at 20-50 % of a rated step's initial slope",
             "unexplained", "no candidate limits the current's slope"),
)  # fmt: skip

# the MuJoCo plant's vocabulary: names with MuJoCo equations, in the ladders' order
MJ_EQUATIONS: dict[str, tuple[str, ...]] = {}
for _row in TRUTH_TABLE:
    MJ_EQUATIONS.setdefault(_row.name, ())
    MJ_EQUATIONS[_row.name] += (_row.equation,)
MJ_OOV_NAMES: tuple[str, ...] = tuple(r.name for r in TRUTH_TABLE if r.right == "unexplained")
MJ_VOCABULARY: tuple[str, ...] = tuple(n for n in LADDERS if n in MJ_EQUATIONS)
MJ_COMPOUNDS: tuple[tuple[str, str], ...] = (
    ("coulomb_friction", "stribeck_friction"),
    ("coulomb_friction", "quadratic_drag"),
    ("coulomb_friction", "brush_drop"),
    ("load_torque", "resistance_drift"),
    ("coulomb_friction", "cogging"),
    ("delay", "current_offset"),
)
Z_PRESLIDING_RAD = 1e-4  # the bristles' deflection at the friction level
STRIBECK_FLOOR = 0.02  # a Stribeck-only LuGre's Coulomb level, of its static torque


@dataclass(frozen=True)
class MjEffect:
    """One effect drawn for the MuJoCo plant: its name, equation, size and settings
    (fields of :class:`~.mujoco_plant.MjPlant` and :class:`~.mujoco_plant.Chain`)."""

    name: str
    equation: str
    level: int  # index into LADDERS[name]; -1 out of vocabulary
    size: float
    unit: str
    plant: tuple[tuple[str, object], ...] = ()
    chain: tuple[tuple[str, object], ...] = ()
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)  # sensor offset start, end, tau

    @property
    def in_vocabulary(self) -> bool:
        return self.name in MJ_VOCABULARY

    def describe(self) -> dict[str, object]:
        return {
            "name": self.name,
            "equation": self.equation,
            "level": self.level,
            "size": self.size,
            "unit": self.unit,
            "settings": {k: _jsonable(v) for k, v in (*self.plant, *self.chain)},
            "offset": list(self.offset),
        }


def _jsonable(v: object) -> object:
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    if hasattr(v, "__dataclass_fields__"):
        return {k: _jsonable(getattr(v, k)) for k in v.__dataclass_fields__}  # type: ignore[attr-defined]
    return v


def _size(name: str, level: int) -> tuple[str, float]:
    unit, sizes = LADDERS[name]
    return unit, sizes[level]


def _motor_periods(m: BenchMotor, rate_hz: float) -> list[float]:
    """The motor's cogging periods per motor turn that the rate resolves at the output
    (at half the no-load speed)."""
    rev_per_s = 0.5 * m.speed_no_load_rad_s / (2 * math.pi)
    return [
        float(p) for p in m.cogging_motor_periods if p * m.gear_ratio * rev_per_s <= 0.5 * rate_hz
    ]


def _mesh_ok(m: BenchMotor, rate_hz: float) -> bool:
    rev_per_s = 0.5 * m.speed_no_load_rad_s / (2 * math.pi)
    return bool(m.gear_teeth_output) and m.gear_teeth_output * rev_per_s <= 0.5 * rate_hz


def mj_eligible(name: str, m: BenchMotor, rate_hz: float, equation: str | None = None) -> bool:
    """Where the effect can show in data at all (physics, not the diagnosis)."""
    if name == "cogging":
        if equation == "gear_mesh":
            return _mesh_ok(m, rate_hz)
        if equation in ("motor", "two_harmonics"):
            return bool(_motor_periods(m, rate_hz))
        return bool(_motor_periods(m, rate_hz)) or _mesh_ok(m, rate_hz)
    if name == "current_rate_limit":
        return m.inductance_visible(rate_hz)
    return True


def cogging_equations(m: BenchMotor, rate_hz: float) -> tuple[str, ...]:
    return tuple(e for e in MJ_EQUATIONS["cogging"] if mj_eligible("cogging", m, rate_hz, e))


def _bristles(level_nm: float, m: BenchMotor, rate_hz: float) -> tuple[float, float]:
    """sigma0, sigma1 at the motor shaft: ``Z_PRESLIDING_RAD`` of deflection at the
    friction level, the bristle resonance kept under 3 kHz and twice the sample rate (a
    stiffer one changes nothing measurable); no bristle damping: MuJoCo takes the force
    sigma1 dz/dt from dz/dt at a step's start while it integrates z exactly, which made
    the friction depend on the step (a step and a sine through zero: 4.7 rad/s RMS off
    a static Stribeck friction at 50 steps per sample, 1.2 at 200; 0.48 at any step
    without it, docs/mujoco.md)."""
    jm = m.params.J / m.gear_ratio**2
    f_max = min(3000.0, 2.0 * rate_hz)
    sig0 = min(level_nm / Z_PRESLIDING_RAD, jm * (2 * math.pi * f_max) ** 2)
    return sig0, 0.0


def lugre(coulomb_nm: float, static_nm: float, vs: float, m: BenchMotor, rate_hz: float):  # type: ignore[no-untyped-def]
    """A ``lugre`` attribute (motor shaft units) for friction levels at the output."""
    n = m.gear_ratio
    sig0, sig1 = _bristles(max(static_nm, coulomb_nm) / n, m, rate_hz)
    return (sig0, sig1, coulomb_nm / n, static_nm / n, vs * n)


def _friction(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm
    w0 = m.speed_no_load_rad_s
    if name == "coulomb_friction":
        if eq == "frictionloss":
            return MjEffect(name, eq, level, size, unit, (("frictionloss", t),))
        vs = 0.05 * w0  # no Stribeck fall: static = Coulomb makes vs irrelevant
        return MjEffect(name, eq, level, size, unit, (("lugre", lugre(t, t, vs, m, ctx.rate_hz)),))
    vs = rng.uniform(0.02, 0.08) * w0
    floor = STRIBECK_FLOOR * t
    return MjEffect(name, eq, level, size, unit, (("lugre", lugre(floor, t, vs, m, ctx.rate_hz)),))


def _drag(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm
    w0 = m.speed_no_load_rad_s
    if eq == "quadratic":
        return MjEffect(name, eq, level, size, unit, (("damping2", t / w0**2),))
    share = rng.uniform(0.3, 0.6)  # of the drag at w0 from the cubic term
    s = (("damping2", (1 - share) * t / w0**2), ("damping3", share * t / w0**3))
    return MjEffect(name, eq, level, size, unit, s)


def _load(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    p = m.params
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm * float(rng.choice([-1.0, 1.0]))
    if eq == "applied":
        return MjEffect(name, eq, level, size, unit, (("applied_nm", t),))
    jl = rng.uniform(0.1, 0.5) * p.J  # m r^2
    r = jl * 9.81 / abs(t)  # m g r = |t|
    mass = abs(t) / (9.81 * r)
    f_c = min(
        rng.uniform(8.0, 15.0) / (2 * math.pi * p.mechanical_time_constant_s), 0.2 * ctx.rate_hz
    )
    m_eff = 1.0 / (1.0 / mass + r * r / p.J)  # the mass against the rotor seen at the cable
    k = (2 * math.pi * f_c) ** 2 * m_eff
    s = (
        ("lift_mass_kg", mass),
        ("drum_radius_m", r if t > 0 else -r),  # lowering with +w: a load that drives
        ("cable_stiffness", k),
        ("cable_damping", 2 * 0.5 * math.sqrt(k * m_eff)),
    )
    return MjEffect(name, eq, level, size, unit, s)


def _cogging(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    unit, size = _size(name, level)
    t = size / 100.0 * m.torque_rated_nm  # peak torque at the output
    n = m.gear_ratio
    phase = rng.uniform(-math.pi, math.pi)
    if eq == "gear_mesh":
        from pmdc_ident.benchmark.mujoco_plant import Passive

        s = (("passive", (Passive(t, float(m.gear_teeth_output), phase, 1.0),)),)
        return MjEffect(name, eq, level, size, unit, s)
    p = float(rng.choice(_motor_periods(m, ctx.rate_hz)))
    if eq == "motor":
        return MjEffect(name, eq, level, size, unit, (("cogging", (t / n, p, phase)),))
    from pmdc_ident.benchmark.mujoco_plant import Passive

    a2, ph2 = rng.uniform(0.2, 0.5), rng.uniform(-math.pi, math.pi)
    th = np.linspace(0.0, 2 * math.pi, 2001)
    peak = float(np.max(np.abs(np.sin(th + phase) + a2 * np.sin(2 * th + ph2))))
    a1 = t / n / peak
    s = (
        ("cogging", (a1, p, phase)),
        # the passive actuator's angle is gear x the joint's: 2p per motor turn
        ("passive", (Passive(a2 * a1, 2.0 * p, ph2, n),)),
    )
    return MjEffect(name, eq, level, size, unit, s)


def thermal_unit_rise(ctx: Context, tau_s: float) -> float:
    """The winding's largest temperature rise (K) for a capacitance of 1 J/K and a time
    constant ``tau_s``, heated by R i^2 of the clean session (no feedback of R(T))."""
    dt = 1.0 / ctx.rate_hz
    r = ctx.motor.params.R
    a = math.exp(-dt / tau_s)
    x = 0.0
    peak = 0.0
    for q in ctx.current_sq:
        x = x * a + q * r * tau_s * (1.0 - a)
        peak = max(peak, x)
    return max(peak, 1e-30)


def _thermal(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    unit, size = _size(name, level)
    if eq == "thermal_fast":
        tau = ctx.duration_s * rng.uniform(0.2, 1.0)
    else:
        tau = ctx.duration_s * math.exp(rng.uniform(math.log(3.0), math.log(30.0)))
    c = ALPHA_CU * thermal_unit_rise(ctx, tau) / (size / 100.0)  # alpha T_peak = size
    return MjEffect(name, eq, level, size, unit, (("thermal", (tau / c, c, ALPHA_CU)),))


def _drive(name: str, eq: str, level: int, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    unit, size = _size(name, level)
    if name == "dead_zone":
        c = (
            ("dead_zone", 1 if eq == "hard" else 2),
            ("dead_zone_v", size / 100 * m.voltage_rated_v),
        )
        return MjEffect(name, eq, level, size, unit, chain=c)
    if name == "brush_drop":
        i0 = rng.uniform(0.02, 0.1) * m.current_rated_a
        c = (("brush_v", size / 100 * m.voltage_rated_v), ("brush_knee_a", i0))
        return MjEffect(name, eq, level, size, unit, chain=c)
    if name == "current_offset":
        o = size / 100.0 * m.current_rated_a * float(rng.choice([-1.0, 1.0]))
        if eq == "constant":
            return MjEffect(name, eq, level, size, unit, offset=(o, o, 0.0))
        tau = rng.uniform(0.3, 1.0) * ctx.duration_s
        return MjEffect(name, eq, level, size, unit, offset=(1.5 * o, 0.5 * o, tau))
    d = size / ctx.rate_hz  # delay
    if eq == "transport":
        return MjEffect(name, eq, level, size, unit, (("delay_s", d),))
    if eq == "lag":
        return MjEffect(name, eq, level, size, unit, chain=(("lag_s", d),))
    return MjEffect(name, eq, level, size, unit, (("delay_s", 0.5 * d),), (("lag_s", 0.5 * d),))


def _oov(name: str, ctx: Context, rng: np.random.Generator) -> MjEffect:
    m = ctx.motor
    p = m.params
    f_m = 1.0 / (2 * math.pi * p.mechanical_time_constant_s)
    if name in ("backlash", "flexible_coupling"):
        jl = rng.uniform(1.0, 3.0) * p.J
        f_c = min(rng.uniform(3.0, 8.0) * f_m * math.sqrt(1 + jl / p.J), 0.15 * ctx.rate_hz)
        if name == "backlash":
            gap = math.radians(rng.uniform(1.0, 4.0))
            s = (("load_inertia", jl), ("backlash_rad", gap),
                 ("limit_timeconst_s", 1.0 / (2 * math.pi * f_c)))  # fmt: skip
            return MjEffect(name, "oov", -1, math.degrees(gap), "deg of play", s)
        kc = (2 * math.pi * f_c) ** 2 / (1.0 / p.J + 1.0 / jl)
        zeta = rng.uniform(0.05, 0.1)
        s = (("load_inertia", jl), ("coupling_stiffness", kc),
             ("coupling_damping", 2 * zeta * math.sqrt(kc * jl)))  # fmt: skip
        return MjEffect(name, "oov", -1, jl / p.J * 100.0, "% of J (load inertia)", s)
    n = m.gear_ratio
    if name == "torque_saturation":
        share = rng.uniform(0.35, 0.7)
        t = share * p.Kt * ctx.peak_current_a / n  # at the motor shaft
        s = (("saturation", (t, 0.0, 0.0)),)
        return MjEffect(name, "oov", -1, share * 100, "% of the session's peak torque", s)
    share = rng.uniform(0.2, 0.5)  # current_rate_limit
    return MjEffect(
        name, "oov", -1, share * 100, "% of a rated step's initial di/dt",
        (("saturation", (0.0, 0.0, share * m.voltage_rated_v / p.L)),),
    )  # fmt: skip


_GENERATORS = {
    "coulomb_friction": _friction,
    "stribeck_friction": _friction,
    "quadratic_drag": _drag,
    "load_torque": _load,
    "cogging": _cogging,
    "resistance_drift": _thermal,
    "delay": _drive,
    "dead_zone": _drive,
    "brush_drop": _drive,
    "current_offset": _drive,
}


def draw_mj_effect(
    name: str, level: int, ctx: Context, rng: np.random.Generator, equation: str | None = None
) -> MjEffect:
    """One MuJoCo effect of ``name`` at ladder ``level`` (an equation drawn unless given)."""
    if name in MJ_OOV_NAMES:
        return _oov(name, ctx, rng)
    options = MJ_EQUATIONS.get(name, ())
    if name == "cogging":
        options = cogging_equations(ctx.motor, ctx.rate_hz)
    eq = equation if equation in options else None
    eq = eq or str(rng.choice(options))
    if eq not in MJ_EQUATIONS.get(name, ()):
        msg = f"{name} has no MuJoCo equation {eq!r}; known: {MJ_EQUATIONS.get(name)}"
        raise ValueError(msg)
    return _GENERATORS[name](name, eq, level, ctx, rng)


def resized(e: MjEffect, size: float, m: BenchMotor, rate_hz: float) -> MjEffect:
    """``e`` at another size in its unit (a torque effect: LuGre friction, cogging), its
    drawn shape kept: the reveal benchmark's effect at a chosen fraction of rated torque
    (``benchmarks/bench_design.py --reveal --plant mujoco``)."""
    f = size / e.size
    n = m.gear_ratio
    plant: list[tuple[str, object]] = []
    for key, v in e.plant:
        if key == "lugre":  # motor-shaft units; :func:`lugre` takes the output's
            _s0, _s1, fc, ts, vs = v  # type: ignore[misc]
            v = lugre(fc * n * f, ts * n * f, vs / n, m, rate_hz)
        elif key == "cogging":
            a, periods, phase = v  # type: ignore[misc]
            v = (a * f, periods, phase)
        elif key == "passive":
            v = tuple(replace(q, amplitude_nm=q.amplitude_nm * f) for q in v)  # type: ignore[attr-defined]
        else:
            msg = f"{e.name} ({e.equation}): cannot resize its {key!r}"
            raise ValueError(msg)
        plant.append((key, v))
    if e.chain or any(e.offset):
        msg = f"{e.name} ({e.equation}): only torque effects are resized"
        raise ValueError(msg)
    return replace(e, size=size, plant=tuple(plant))
