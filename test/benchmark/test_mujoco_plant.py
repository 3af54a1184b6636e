"""The MuJoCo plant (``benchmark --plant mujoco``): physics, sizes, truth table, CLI."""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest
from helpers.paths import REPO

from pmdc_ident.benchmark import mujoco_plant as mp
from pmdc_ident.benchmark.cases import base_vector, command, draw_sensors
from pmdc_ident.benchmark.motors import ALL_MOTORS, MOTORS
from pmdc_ident.benchmark.mujoco_cases import build_mj_cases, plant_and_chain, record_mj
from pmdc_ident.benchmark.mujoco_truth import (
    ALPHA_CU,
    MJ_EQUATIONS,
    MJ_OOV_NAMES,
    MJ_VOCABULARY,
    TRUTH_TABLE,
)
from pmdc_ident.benchmark.report import truth_table_text
from pmdc_ident.benchmark.visibility import linear_signals, noise_sigmas
from pmdc_ident.cli import main

pytest.importorskip("mujoco")

ALLOWED = {
    "pmdc_ident.core.params",
    "pmdc_ident.core.excitation",
    "pmdc_ident.core.motors",
    "pmdc_ident.core._jit",
    "pmdc_ident.core.effects",
    "pmdc_ident.exports.mujoco_replay",  # MuJoCo's warnings caught (no equation)
}


def test_the_mujoco_plant_imports_nothing_of_the_candidate_library():
    root = REPO / "pmdc_ident" / "benchmark"
    for mod in ("mujoco_plant", "mujoco_truth", "mujoco_cases"):
        tree = ast.parse((root / f"{mod}.py").read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("pmdc_ident"):
                assert node.module.startswith("pmdc_ident.benchmark") or node.module in ALLOWED


def test_six_motors_from_under_1_w_to_over_1_kw_and_the_vocabulary():
    powers = [m.power_rated_w for m in ALL_MOTORS.values()]
    assert len(ALL_MOTORS) >= 6 and min(powers) < 1.0 and max(powers) > 1000.0
    assert set(MOTORS) < set(ALL_MOTORS)  # the generator's draw keeps its five
    # every vocabulary name MuJoCo can express, and what it cannot
    assert "inductance_saturation" not in MJ_VOCABULARY and len(MJ_VOCABULARY) == 10
    assert {"backlash", "flexible_coupling", "torque_saturation"} <= set(MJ_OOV_NAMES)
    assert all(r.right in (r.name, "unexplained") for r in TRUTH_TABLE)
    assert len(MJ_EQUATIONS["cogging"]) == 3 and len(MJ_EQUATIONS["coulomb_friction"]) == 2


def test_the_truth_table_in_docs_is_the_one_scoring_uses():
    assert truth_table_text() in (REPO / "docs" / "mujoco.md").read_text()


@pytest.mark.parametrize("name", ["coreless_6v", "gearmotor_12v", "industrial_180v"])
def test_without_effects_mujoco_follows_the_exact_linear_motor(name):
    # MuJoCo's dcmotor at 50 Euler steps per sample against the exact zero-order-hold
    # solution, behind the same sensor filters: within a tenth of the sensors' noise
    m = MOTORS[name]
    rate = m.rates_hz[0]
    _, _, v = command(m, rate, False)
    s = draw_sensors(m, rate, np.random.default_rng(3))
    p = m.params
    plant = mp.MjPlant(R=p.R, L=p.L, K=p.Ke, J=p.J, B=p.B, gear=m.gear_ratio)
    sim = mp.simulate_plant(plant, v, 1 / rate, filters=mp.Filters(s.current_fc_hz,
                            s.current_order, s.speed_fc_hz))  # fmt: skip
    i_ref, w_ref = linear_signals(v, 1 / rate, base_vector(m), s)
    sig_i, sig_w = noise_sigmas(s, rate)
    i = sim.current_filtered if s.current_fc_hz > 0 else sim.current
    w = sim.speed_filtered if s.speed_fc_hz > 0 else sim.speed
    assert np.sqrt(np.mean((i - i_ref) ** 2)) < 0.1 * sig_i
    assert np.sqrt(np.mean((w - w_ref) ** 2)) < 0.1 * sig_w
    opened = np.flatnonzero(np.isnan(v))
    assert np.all(sim.current[opened[1:]] == 0.0)  # the open armature carries no current


def _steady(case, *, whole: bool = False):  # type: ignore[no-untyped-def]
    """Torque beyond the viscous, % of rated, and V - R i - K w, % of rated voltage, at the
    end of the top staircase level; and the simulation, of the record up to that sample
    (a third of it: the plant is causal, the same values there) or ``whole``."""
    m = case.bench_motor
    labels, bounds, v = command(m, case.rate_hz, case.one_direction)
    plant, chain = plant_and_chain(m, case.effects)
    j = bounds[labels.index("staircase_06")][1] - 2
    sim = mp.simulate_plant(plant, v if whole else v[: j + 1], 1 / case.rate_hz, chain=chain)
    p = m.params
    i, w = sim.current[j], sim.speed[j]
    torque = (p.Kt * i - p.B * w) / m.torque_rated_nm * 100
    drop = (v[j] - p.R * i - p.Ke * w) / m.voltage_rated_v * 100
    return torque, drop, sim


@pytest.mark.parametrize("equation", ["frictionloss", "lugre"])
def test_coulomb_friction_is_the_ladder_s_torque_whatever_mujoco_model_carries_it(equation):
    for case in build_mj_cases(2, 0, 0, 0, 5, effects=("coulomb_friction",), max_samples=5000):
        if case.effects[0].equation != equation:
            continue
        torque, _, _ = _steady(case)
        assert torque == pytest.approx(case.effects[0].size, rel=0.05, abs=0.5)


@pytest.mark.parametrize(
    ("name", "equation"),
    [("stribeck_friction", "lugre_gauss"), ("cogging", "motor"), ("cogging", "two_harmonics"),
     ("cogging", "gear_mesh")],
)  # fmt: skip
def test_a_reveal_benchmark_effect_resized_keeps_its_shape(name, equation):
    """``bench_design --reveal --plant mujoco`` plays an effect at a chosen % of rated
    torque: every torque term scales, the Stribeck speed and cogging periods stay."""
    from pmdc_ident.benchmark.mujoco_truth import draw_mj_effect, resized
    from pmdc_ident.benchmark.truth import Context

    m = ALL_MOTORS["scooter_24v"]  # geared: LuGre's terms are at the motor shaft
    ctx = Context(m, 2000.0, 10.0, m.current_rated_a, np.zeros(1))
    e = draw_mj_effect(name, 3, ctx, np.random.default_rng(1), equation)
    r = resized(e, 15.0, m, ctx.rate_hz)
    assert (r.size, r.equation) == (15.0, equation)
    f = 15.0 / e.size
    for (key, a), (_, b) in zip(e.plant, r.plant, strict=True):
        if key == "lugre":  # sigma0 follows the level, the fall's speed stays
            assert b[3] * m.gear_ratio == pytest.approx(0.15 * m.torque_rated_nm)
            assert (b[2], b[4]) == pytest.approx((f * a[2], a[4]))
        elif key == "cogging":
            assert b == pytest.approx((f * a[0], a[1], a[2]))
        else:
            assert [q.amplitude_nm for q in b] == pytest.approx([f * q.amplitude_nm for q in a])
            assert [q.poles for q in b] == [q.poles for q in a]


def test_brush_drop_outside_mujoco_and_heating_inside_it_have_their_sizes():
    for case in build_mj_cases(2, 0, 0, 0, 5, effects=("brush_drop",), max_samples=5000):
        _, drop, sim = _steady(case)
        m = case.bench_motor
        c = dict(case.effects[0].chain)
        labels, bounds, _ = command(m, case.rate_hz, case.one_direction)
        i = sim.current[bounds[labels.index("staircase_06")][1] - 2]
        expected = c["brush_v"] * math.tanh(i / c["brush_knee_a"]) / m.voltage_rated_v * 100
        assert c["brush_v"] / m.voltage_rated_v * 100 == case.effects[0].size
        assert drop == pytest.approx(expected, rel=0.02)
    for case in build_mj_cases(2, 0, 0, 0, 5, effects=("resistance_drift",), max_samples=5000):
        _, _, sim = _steady(case, whole=True)  # the peak over the session
        # the ladder's rise of R at its peak (MuJoCo heats by R(T) i^2: a little more)
        rise = ALPHA_CU * float(np.max(sim.winding_rise_k)) * 100
        assert 0.95 * case.effects[0].size <= rise <= 1.3 * case.effects[0].size


def test_a_run_is_a_csv_a_driver_logs_and_its_visibility_is_measured():
    case = build_mj_cases(1, 0, 0, 0, 5, effects=("load_torque",), max_samples=5000)[0]
    rec, vis = record_mj(case)
    assert vis is not None and vis.raw > vis.residual > 1.0
    assert rec.current.size == rec.position.size == rec.voltage.size
    step = 2 * math.pi / case.sensors.counts_per_rev
    assert np.allclose(rec.position / step, np.round(rec.position / step))  # whole counts


def test_quick_mujoco_benchmark_prints_its_table_and_cpu_per_run(tmp_path, capsys):
    # one effect run and one effect-free run, in the two workers of --jobs 2 (a load
    # torque run beside them added ~3 CPU-s and checked nothing more here)
    rc = main(
        [
            "benchmark",
            "--plant",
            "mujoco",
            "--quick",
            "--effects",
            "coulomb_friction",
            "--clean",
            "1",
            "--jobs",
            "2",
            "--quiet",
            "--report",
            str(tmp_path),
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0
    assert "| effect-free runs: false attribution | 0 (0%) | 1 |" in out
    assert "| coulomb_friction | 100% | 100% |" in out
    assert "simulating +" in out and "diagnosing" in out  # CPU per run
    assert "| simulate CPU per run (median / max) |" in out
    assert (tmp_path / "benchmark.md").read_text().count("right name") == 1  # the truth table
    assert main(["benchmark", "--plant", "mujoco", "--effects", "inductance_saturation"]) == 2
