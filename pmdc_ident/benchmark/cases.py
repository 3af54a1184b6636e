"""Benchmark cases: a motor, a rate, the user's test plan, sensors and effects.

Each case is recorded with the session's default sequence
(:func:`~pmdc_ident.core.excitation.default_plan`: staircase, steps both ways, a
log chirp, a coast-down) or its one-direction form (no reverse step), sized from
the motor's datasheet time constant and voltage, as the identification node
plans it. :func:`record` simulates it with :mod:`.plant`, reads it through the
driver's sensors (:mod:`.sensors`) and returns the segments' arrays, labelled
as the session labels them; the truth stays in the :class:`Case`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.benchmark import plant as pl
from pmdc_ident.benchmark.motors import ALL_MOTORS, MOTORS, BenchMotor
from pmdc_ident.benchmark.sensors import SensorSetup, measure
from pmdc_ident.benchmark.truth import (
    EQUATIONS,
    LADDERS,
    OOV_NAMES,
    VOCABULARY,
    Context,
    TrueEffect,
    apply_effects,
    draw_effect,
)
from pmdc_ident.benchmark.visibility import Visibility, visibility
from pmdc_ident.core.excitation import SequenceConfig, default_plan
from pmdc_ident.core.motors import Limits

__all__ = ["Case", "Draw", "Recording", "build_cases", "make_case", "record"]

FloatArray = NDArray[np.float64]
COMPOUNDS: tuple[tuple[str, str], ...] = (
    ("coulomb_friction", "stribeck_friction"),
    ("coulomb_friction", "quadratic_drag"),
    ("coulomb_friction", "brush_drop"),
    ("load_torque", "resistance_drift"),
    ("coulomb_friction", "cogging"),
    ("delay", "current_offset"),
)


@dataclass(frozen=True)
class Case:
    """One generated run and its truth (never written to the run file)."""

    name: str
    kind: str  # "effect", "clean", "compound", "oov"
    motor: str
    rate_hz: float
    one_direction: bool
    effects: tuple[TrueEffect, ...]
    sensors: SensorSetup
    seed: int
    visibility: float = math.nan  # residual visibility (filled by the runner)
    visibility_raw: float = math.nan
    plant: str = "generator"  # who simulates it: the generator's RK4 plant or "mujoco"

    @property
    def truth(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    @property
    def bench_motor(self) -> BenchMotor:
        return ALL_MOTORS[self.motor]


@dataclass(frozen=True)
class Recording:
    """The arrays of one run as a driver logs them, cut into the plan's segments."""

    labels: tuple[str, ...]
    bounds: tuple[tuple[int, int], ...]
    dt_s: float
    voltage: FloatArray = field(repr=False)
    current: FloatArray = field(repr=False)
    position: FloatArray = field(repr=False)
    speed: FloatArray | None = field(repr=False)


def plan_config(one_direction: bool) -> SequenceConfig:
    return SequenceConfig(step_directions=(1,) if one_direction else (1, -1))


def command(motor: BenchMotor, rate_hz: float, one_direction: bool):  # type: ignore[no-untyped-def]
    p = motor.params
    limits = Limits(
        voltage_max_v=motor.voltage_rated_v,
        current_max_a=1.5 * motor.voltage_rated_v / p.R,
        speed_max_rad_s=2.0 * motor.speed_no_load_rad_s,
    )
    plan = default_plan(
        1.0 / rate_hz, limits, p.mechanical_time_constant_s, plan_config(one_direction)
    )
    labels = tuple(s.label for s in plan.segments)
    sizes = [s.voltage.size for s in plan.segments]
    stops = np.cumsum(sizes)
    bounds = tuple((int(a - n), int(a)) for a, n in zip(stops, sizes, strict=True))
    return labels, bounds, np.concatenate([s.voltage for s in plan.segments])


def base_vector(motor: BenchMotor) -> FloatArray:
    p = motor.params
    return pl.new_params(p.R, p.L, p.Ke, p.Kt, p.J, p.B)


@cache
def context(motor: BenchMotor, rate_hz: float, one_direction: bool) -> Context:
    # a few motor/rate pairs serve hundreds of cases: the clean session is simulated
    # once per pair (building a draw: 16 s -> 2 s), the Context is frozen and read only
    _, _, v = command(motor, rate_hz, one_direction)
    sim = pl.simulate_plant(v, 1.0 / rate_hz, base_vector(motor))
    i2 = np.where(np.isnan(v), 0.0, sim.current**2)
    i2.setflags(write=False)  # shared by every case of the pair
    return Context(motor, rate_hz, v.size / rate_hz, float(np.sqrt(i2.max())), i2)


def draw_sensors(motor: BenchMotor, rate_hz: float, rng: np.random.Generator) -> SensorSetup:
    ds = motor.sensors
    source = str(rng.choice(ds.speed_sources))
    order = int(rng.choice([1, 2]))
    return SensorSetup(
        current_range_a=ds.current_range_a,
        current_adc_bits=ds.current_adc_bits,
        current_noise_a=ds.current_noise_a * rng.uniform(0.5, 2.0),
        current_fc_hz=rate_hz * rng.uniform(1.5, 5.0) * order,
        current_order=order,
        counts_per_rev=motor.counts_per_rev,
        speed_source=source,
        speed_noise_rad_s=ds.tacho_noise_rad_s * rng.uniform(0.5, 2.0),
        speed_fc_hz=rate_hz * rng.uniform(1.5, 5.0) if source == "tacho" else 0.0,
    )


def eligible(name: str, motor: BenchMotor, rate_hz: float) -> bool:
    """Where an effect can show in data at all (physics, not the diagnosis)."""
    if name == "inductance_saturation":
        return motor.inductance_visible(rate_hz)
    if name == "cogging":
        if not (motor.cogging_motor_periods or motor.gear_teeth_output):
            return False  # ironless rotor
        rev_per_s = 0.5 * motor.speed_no_load_rad_s / (2 * math.pi)
        options = [n * motor.gear_ratio for n in motor.cogging_motor_periods]
        options += [motor.gear_teeth_output] if motor.gear_teeth_output else []
        return any(n * rev_per_s <= 0.5 * rate_hz for n in options)
    return True


def session_samples(motor: BenchMotor, rate_hz: float) -> int:
    """Samples of the default session (about 100 mechanical time constants)."""
    return int(100 * motor.params.mechanical_time_constant_s * rate_hz)


def _pick_motor_rate(
    names: tuple[str, ...], rng: np.random.Generator, k: int, max_samples: int
) -> tuple[BenchMotor, float]:
    pairs = [
        (m, r)
        for m in MOTORS.values()
        for r in m.rates_hz
        if all(eligible(n, m, r) for n in names if n in VOCABULARY)
        and session_samples(m, r) <= max_samples
    ]
    motors = sorted({m.name for m, _ in pairs})
    name = motors[(k + int(rng.integers(len(motors)))) % len(motors)]
    rates = [r for m, r in pairs if m.name == name]
    return MOTORS[name], float(rng.choice(rates))


def _compound(
    names: tuple[str, ...], level: int, ctx: Context, rng: np.random.Generator
) -> tuple[TrueEffect, ...]:
    if names == ("coulomb_friction", "stribeck_friction"):
        fam = int(rng.integers(3))
        a = draw_effect(names[0], level, ctx, rng, ("karnopp", "karnopp", "lugre")[fam])
        b = draw_effect(names[1], level, ctx, rng, ("exp", "lorentz", "lugre_gauss")[fam])
        if fam == 2:  # one bristle model for the sum of both torques
            tc = dict(a.settings)[pl.P_TC] + dict(b.settings)[pl.P_TS]
            z0 = 1e-4
            sig0 = min(tc / z0, ctx.motor.params.J * (2 * math.pi * 3000.0) ** 2)
            extra = ((pl.P_SIG0, sig0), (pl.P_SIG1, 2.0 * math.sqrt(sig0 * ctx.motor.params.J)))
            b = TrueEffect(b.name, b.equation, b.level, b.size, b.unit, b.settings + extra)
        return a, b
    return tuple(draw_effect(n, level, ctx, rng) for n in names)


def make_case(
    name: str,
    kind: str,
    effect_names: tuple[str, ...],
    rng: np.random.Generator,
    *,
    k: int = 0,
    level: int | None = None,
    equation: str | None = None,
    max_samples: int = 10**9,
) -> Case:
    motor, rate = _pick_motor_rate(effect_names, rng, k, max_samples)
    one_dir = bool(rng.random() < 0.25)
    ctx = context(motor, rate, one_dir)
    lev = int(rng.integers(4)) if level is None else level
    if kind == "compound":
        effects = _compound(effect_names, lev, ctx, rng)
    else:
        effects = tuple(draw_effect(n, lev, ctx, rng, equation) for n in effect_names)
    return finish_case(name, kind, motor, rate, one_dir, effects, rng)


def finish_case(
    name: str,
    kind: str,
    motor: BenchMotor,
    rate: float,
    one_dir: bool,
    effects: tuple[Any, ...],
    rng: np.random.Generator,
    plant: str = "generator",
) -> Case:
    """The case with its sensors drawn (a current offset effect sets theirs) and its
    noise seed: the last draws of every plant's case, in this order."""
    sensors = draw_sensors(motor, rate, rng)
    for e in effects:
        if e.name == "current_offset":
            o0, o1, tau = e.offset
            sensors = SensorSetup(**{**sensors.__dict__, "offset_a": o0, "offset_end_a": o1,
                                     "offset_tau_s": tau})  # fmt: skip
    seed = int(rng.integers(2**31))
    return Case(name, kind, motor.name, rate, one_dir, effects, sensors, seed, plant=plant)


def build_cases(
    runs_per_effect: int,
    clean: int,
    oov_per_name: int,
    compounds: int,
    seed: int,
    effects: tuple[str, ...] = VOCABULARY,
    max_samples: int = 10**9,
) -> list[Case]:
    """The benchmark's cases: levels balanced over the ladder, equations cycled.

    ``max_samples`` keeps only motor/rate pairs whose session is that short (CI)."""
    counts = (runs_per_effect, clean, oov_per_name, compounds)
    draw = Draw(make_case, EQUATIONS, lambda name: len(LADDERS[name][1]), OOV_NAMES, COMPOUNDS)
    return draw.cases(np.random.default_rng(seed), effects, counts, max_samples)


@dataclass(frozen=True)
class Draw:
    """How a plant's cases are drawn (the generator's, :mod:`.mujoco_cases`' alike): per
    effect, runs at levels balanced over its ladder (largest first: --quick sees big
    effects) with its equations cycled from a drawn start; then effect-free,
    out-of-vocabulary and paired runs, each made by the plant's ``make``."""

    make: Callable[..., Case]
    equations: Mapping[str, tuple[str, ...]]
    n_levels: Callable[[str], int]
    oov_names: tuple[str, ...]
    pairs: tuple[tuple[str, str], ...]

    def cases(
        self,
        rng: np.random.Generator,
        effects: tuple[str, ...],
        counts: tuple[int, int, int, int],
        max_samples: int,
    ) -> list[Case]:
        """``counts``: runs per effect, effect-free runs, runs per out-of-vocabulary
        name, paired runs."""
        runs_per_effect, clean, oov_per_name, compounds = counts
        make, cases = self.make, []
        for name in effects:
            eqs = self.equations[name]
            offset = int(rng.integers(len(eqs)))
            n_levels = self.n_levels(name)
            for k in range(runs_per_effect):
                level = n_levels - 1 - (k % n_levels)
                eq = eqs[(k + offset) % len(eqs)]
                cases.append(make(f"{name}_{k:02d}", "effect", (name,), rng, k=k, level=level,
                                  equation=eq, max_samples=max_samples))  # fmt: skip
        for k in range(clean):
            cases.append(make(f"clean_{k:02d}", "clean", (), rng, k=k, max_samples=max_samples))
        for name in self.oov_names:
            for k in range(oov_per_name):
                cases.append(
                    make(f"{name}_{k:02d}", "oov", (name,), rng, k=k, max_samples=max_samples)
                )
        for k in range(compounds):
            pair = self.pairs[k % len(self.pairs)]
            cases.append(make(f"pair_{k:02d}", "compound", pair, rng, k=k, level=2 + k % 2,
                              max_samples=max_samples))  # fmt: skip
        return cases


def sensor_vector(case: Case, effects: tuple[TrueEffect, ...]) -> FloatArray:
    """The plant's parameter vector with ``effects`` and the case's analog sensor filters."""
    p = apply_effects(base_vector(case.bench_motor), effects)
    s = case.sensors
    p[pl.P_FC_I] = s.current_fc_hz
    p[pl.P_ORD_I] = float(s.current_order)
    p[pl.P_FC_W] = s.speed_fc_hz
    p[pl.P_ORD_W] = 1.0
    return p


def record(case: Case, *, with_visibility: bool = True) -> tuple[Recording, Visibility | None]:
    """The run as the driver logs it, and how visible its effects are (:mod:`.visibility`)."""
    labels, bounds, v = command(case.bench_motor, case.rate_hz, case.one_direction)
    p_clean = sensor_vector(case, ())
    p_eff = sensor_vector(case, case.effects)
    sim = pl.simulate_plant(v, 1.0 / case.rate_hz, p_eff)
    m = measure(sim, case.sensors, np.random.default_rng(case.seed))
    rec = Recording(labels, bounds, 1.0 / case.rate_hz, v, m.current, m.position, m.speed)
    vis = None
    if with_visibility and case.effects:
        vis = visibility(v, case.rate_hz, p_eff, p_clean, case.sensors)
    return rec, vis
