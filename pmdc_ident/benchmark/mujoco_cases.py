"""Benchmark cases simulated by MuJoCo's ``<dcmotor>`` (``benchmark --plant mujoco``).

The same user's test plan, the same drivers' sensors (:mod:`.sensors`) and the same
ladders of sizes as the generator's cases (:mod:`.cases`), on six motors (the five
of :data:`~.motors.MOTORS` and a 1.5 kW 48 V traction motor), with the effects of
:mod:`.mujoco_truth` simulated by MuJoCo (:mod:`.mujoco_plant`). A run's visibility is
measured as for the generator: what the best linear motor (refitted to the noise-free
logged signals) leaves, in noise RMS.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pmdc_ident.benchmark import mujoco_plant as mp
from pmdc_ident.benchmark.cases import (
    Case,
    Draw,
    Recording,
    base_vector,
    command,
    context,
    finish_case,
    session_samples,
)
from pmdc_ident.benchmark.motors import ALL_MOTORS, BenchMotor
from pmdc_ident.benchmark.mujoco_truth import (
    MJ_COMPOUNDS,
    MJ_EQUATIONS,
    MJ_OOV_NAMES,
    MJ_VOCABULARY,
    MjEffect,
    draw_mj_effect,
    lugre,
    mj_eligible,
)
from pmdc_ident.benchmark.plant import SimOutput
from pmdc_ident.benchmark.sensors import Measured, SensorSetup, measure
from pmdc_ident.benchmark.visibility import Visibility, linear_signals, visibility_of

__all__ = ["base_plant", "build_mj_cases", "plant_and_chain", "record_mj", "simulate_measured"]

PLANT = "mujoco"


def base_plant(m: BenchMotor) -> mp.MjPlant:
    p = m.params
    return mp.MjPlant(R=p.R, L=p.L, K=p.Ke, J=p.J, B=p.B, gear=m.gear_ratio)


def plant_and_chain(m: BenchMotor, effects: tuple[MjEffect, ...]) -> tuple[mp.MjPlant, mp.Chain]:
    plant, chain = base_plant(m), mp.Chain()
    for e in effects:
        settings = dict(e.plant)
        if "passive" in settings:
            settings["passive"] = plant.passive + tuple(settings["passive"])  # type: ignore[arg-type]
        plant = replace(plant, **settings)  # type: ignore[arg-type]
        chain = replace(chain, **dict(e.chain))  # type: ignore[arg-type]
    return plant, chain


def _eligible(names: tuple[str, ...], m: BenchMotor, rate: float, equation: str | None) -> bool:
    return all(mj_eligible(n, m, rate, equation if len(names) == 1 else None) for n in names)


def _pick(
    names: tuple[str, ...],
    equation: str | None,
    rng: np.random.Generator,
    k: int,
    max_samples: int,
) -> tuple[BenchMotor, float]:
    pairs = [
        (m, r)
        for m in ALL_MOTORS.values()
        for r in m.rates_hz
        if _eligible(names, m, r, equation) and session_samples(m, r) <= max_samples
    ]
    if not pairs:
        msg = f"no motor and rate can show {'+'.join(names)} ({equation})"
        raise ValueError(msg)
    motors = sorted({m.name for m, _ in pairs})
    name = motors[(k + int(rng.integers(len(motors)))) % len(motors)]
    rates = [r for m, r in pairs if m.name == name]
    return ALL_MOTORS[name], float(rng.choice(rates))


def _compound(names: tuple[str, ...], level: int, ctx, rng: np.random.Generator):  # type: ignore[no-untyped-def]
    if names == ("coulomb_friction", "stribeck_friction"):
        a = draw_mj_effect(names[0], level, ctx, rng)
        b = draw_mj_effect(names[1], level, ctx, rng)
        if a.equation == "lugre":  # one bristle model for both: Fc, Fs = Fc + Ts
            m = ctx.motor
            tc = a.size / 100.0 * m.torque_rated_nm
            ts = b.size / 100.0 * m.torque_rated_nm
            vs = dict(b.plant)["lugre"][4] / m.gear_ratio  # type: ignore[index]
            both = lugre(tc, tc + ts, vs, m, ctx.rate_hz)
            a = replace(a, plant=(("lugre", both),))
            b = replace(b, plant=())
        return a, b
    return tuple(draw_mj_effect(n, level, ctx, rng) for n in names)


def make_mj_case(
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
    motor, rate = _pick(effect_names, equation, rng, k, max_samples)
    one_dir = bool(rng.random() < 0.25)
    ctx = context(motor, rate, one_dir)
    lev = int(rng.integers(4)) if level is None else level
    if kind == "compound":
        effects = _compound(effect_names, lev, ctx, rng)
    else:
        effects = tuple(draw_mj_effect(n, lev, ctx, rng, equation) for n in effect_names)
    return finish_case(name, kind, motor, rate, one_dir, effects, rng, plant=PLANT)  # type: ignore[arg-type]


def build_mj_cases(
    runs_per_effect: int,
    clean: int,
    oov_per_name: int,
    compounds: int,
    seed: int,
    effects: tuple[str, ...] = MJ_VOCABULARY,
    max_samples: int = 10**9,
) -> list[Case]:
    """The MuJoCo plant's cases: levels balanced over the ladder (largest first),
    equations cycled, motors rotated; effect-free, out-of-vocabulary and paired runs."""
    draw = Draw(make_mj_case, MJ_EQUATIONS, lambda _name: 4, MJ_OOV_NAMES, MJ_COMPOUNDS)
    rng = np.random.default_rng(10_000 + seed)  # not the generator's draw
    names = tuple(e for e in effects if e in MJ_VOCABULARY)
    return draw.cases(rng, names, (runs_per_effect, clean, oov_per_name, compounds), max_samples)


def _filters(s: SensorSetup) -> mp.Filters:
    return mp.Filters(s.current_fc_hz, s.current_order, s.speed_fc_hz)


def simulate_measured(
    m: BenchMotor,
    effects: tuple[MjEffect, ...],
    sensors: SensorSetup,
    voltage: np.ndarray,
    dt_s: float,
    seed: int,
) -> tuple[SimOutput, Measured]:
    """Any voltage sequence (a benchmark session, a designed plan) played on MuJoCo's
    motor with ``effects``, and what the driver's sensors log of it (noise from ``seed``)."""
    plant, chain = plant_and_chain(m, effects)
    sim = mp.simulate_plant(plant, voltage, dt_s, chain=chain, filters=_filters(sensors))
    return sim, measure(sim, sensors, np.random.default_rng(seed))


def record_mj(case: Case, *, with_visibility: bool = True) -> tuple[Recording, Visibility | None]:
    """The run as the driver logs it (MuJoCo's motor, the drive and sensors outside it),
    and how visible its effects are."""
    m = case.bench_motor
    labels, bounds, v = command(m, case.rate_hz, case.one_direction)
    dt = 1.0 / case.rate_hz
    sim, meas = simulate_measured(m, case.effects, case.sensors, v, dt, case.seed)  # type: ignore[arg-type]
    rec = Recording(labels, bounds, dt, v, meas.current, meas.position, meas.speed)
    vis = None
    if with_visibility and case.effects:
        s = case.sensors
        i = sim.current_filtered if s.current_fc_hz > 0 else sim.current
        w = sim.speed_filtered if s.speed_fc_hz > 0 else sim.speed
        from pmdc_ident.benchmark.sensors import offset_at

        ref = (i + offset_at(sim.t, s), w)
        clean_s = SensorSetup(**{**s.__dict__, "offset_a": 0.0, "offset_end_a": 0.0})
        p_clean = _clean_vector(case)
        clean = linear_signals(v, dt, p_clean, clean_s)
        vis = visibility_of(v, case.rate_hz, ref, clean, p_clean, s)
    return rec, vis


def _clean_vector(case: Case):  # type: ignore[no-untyped-def]
    from pmdc_ident.benchmark import plant as pl

    p = base_vector(case.bench_motor)
    s = case.sensors
    p[pl.P_FC_I] = s.current_fc_hz
    p[pl.P_ORD_I] = float(s.current_order)
    p[pl.P_FC_W] = s.speed_fc_hz
    p[pl.P_ORD_W] = 1.0
    return p
