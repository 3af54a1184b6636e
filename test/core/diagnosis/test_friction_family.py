"""The friction family: Stribeck curves of either common shape, fitted and named;
friction seen through the signal chain's lag named without the lag; friction fitted
where the samples cannot resolve L."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from helpers.gradients import assert_gradient_matches_fd

from pmdc_ident.core.data import Segment
from pmdc_ident.core.diagnosis import DiagnosisConfig, VerdictStatus, diagnose
from pmdc_ident.core.diagnosis.candidates import data_scales, fit_model
from pmdc_ident.core.diagnosis.holdout import split_segments
from pmdc_ident.core.diagnosis.pipeline import _baseline, _setting_scan
from pmdc_ident.core.diagnosis.scoring import estimate_noise
from pmdc_ident.core.diagnosis.search import Fitted, Search
from pmdc_ident.core.effects import CoulombFriction, Delay, StribeckFriction
from pmdc_ident.core.estimators.output_error.parameters import model_values
from pmdc_ident.core.estimators.output_error.problem import Problem
from pmdc_ident.core.estimators.output_error.segments import initial_noise, prepare_segments
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model, simulate
from pmdc_ident.core.motors import Limits, load_motor
from pmdc_ident.core.params import MotorParams


def test_an_exponential_stribeck_fall_is_simulated_as_its_equation():
    # coasting with the armature open: J dw/dt = -B w - Ts exp(-w/ws), integrated here
    # by a fine explicit step, independent of the kernel
    p = load_motor("seed001_110v").model.params
    ts, ws, w0, dt = 3.0, 20.0, 60.0, 1e-3
    n = 1500
    x0 = [0.0, w0, 0.0]
    sim = simulate(
        Model(p, (StribeckFriction(ts, ws, 1.0),)), np.full(n, np.nan), dt, x0=x0, substeps=8
    )
    w, h = w0, dt / 200
    ref = [w]
    for _ in range(n - 1):
        for _ in range(200):
            w -= h * (p.B * w + ts * math.exp(-abs(w) / ws)) / p.J if w > 0 else 0.0
        ref.append(max(w, 0.0))
    assert sim.speed == pytest.approx(np.array(ref), abs=2e-3 * w0)
    gauss = simulate(Model(p, (StribeckFriction(ts, ws),)), np.full(n, np.nan), dt, x0=x0)
    assert np.max(np.abs(gauss.speed - sim.speed)) > 0.05 * w0  # the shapes differ


def _turning_segment(p, dt: float = 2e-3, n: int = 1500) -> Segment:  # type: ignore[no-untyped-def]
    """A record that never stops (no friction events): speeds from near zero to top."""
    t = np.arange(n) * dt
    v = 0.5 * 110.0 * (1.3 + np.sin(2 * np.pi * 1.5 * t)) / 2.0
    model = Model(p, (StribeckFriction(0.5, 15.0, 1.0),))
    x0 = [0.1, 20.0, 0.0]
    sim = simulate(model, v, dt, x0=x0)
    return Segment("sweep", t, v, sim.current, speed=sim.speed, position=sim.position)


def test_the_fast_path_gradient_of_an_exponential_stribeck_fall_is_exact():
    p = load_motor("seed001_110v").model.params
    seg = _turning_segment(p)
    assert seg.speed.min() > 0.0
    m = Model(p.replace(R=p.R * 1.03), (StribeckFriction(0.4, 12.0, 1.0),))
    free = ["R", "Ke", "B", "stribeck_friction.torque_nm", "stribeck_friction.speed_rad_s"]
    ps = prepare_segments([seg], [])
    prob = Problem(ps, m, model_values(m), free, True, True, initial_noise(ps), {})
    assert_gradient_matches_fd(prob, range(len(free)), free)


@pytest.mark.parametrize("shape", [1.0, 2.0])
def test_the_stribeck_candidate_takes_the_shape_of_the_data(shape):
    # a breakaway torque of 30 % of the RMS drive torque falling over 4 % of the top
    # speed: fitted in both shapes, the one the fit segments prefer is the truth's and
    # matches the held-out data to the noise
    spec = load_motor("seed001_110v")
    p = spec.model.params
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(sweep_duration_tau=10.0))
    clean = synthesize_run(Model(p), plan, None, seed=0)
    sc = data_scales(clean.segments, p.Kt)
    truth = StribeckFriction(0.3 * sc.torque_nm, 0.04 * sc.speed_rad_s, shape)
    run = synthesize_run(Model(p, (truth,)), plan, spec.sensors, seed=2)
    segs = list(run.segments)
    noise = estimate_noise(segs)
    base = Fitted((), fit_model(segs, Model(p), max_nfev=30), None, 0.0, 0.0)  # type: ignore[arg-type]
    search = Search(split_segments(segs), noise, DiagnosisConfig(), None)
    f = _setting_scan(search, base, sc, "stribeck_friction")
    e = f.fit.model.effect("stribeck_friction")
    assert isinstance(e, StribeckFriction) and e.shape_exponent == shape
    assert e.speed_rad_s == pytest.approx(truth.speed_rad_s, rel=0.2)
    assert f.gap < 0.2  # held out: to the noise


def test_friction_seen_through_the_signal_chains_lag_is_named_without_the_lag():
    # a Coulomb torque recorded through a 0.1 ms lag (at 1 kHz, below the 1/pi sample of
    # an anti-alias filter at Nyquist): the lag helps most alone, the friction on top of
    # it; the motor's effect is named, the signal chain is not
    spec = load_motor("seed001_110v")
    p = spec.model.params
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(sweep_duration_tau=20.0))
    quiet = replace(spec.sensors, current_noise_a=1e-3)
    clean = synthesize_run(Model(p), plan, None, seed=0)
    tc = 0.005 * data_scales(clean.segments, p.Kt).torque_nm
    model = Model(p, (Delay(0.1e-3), CoulombFriction(tc)))
    r = diagnose(synthesize_run(model, plan, quiet, seed=3), config=DiagnosisConfig(workers=1))
    assert r.verdict.status is VerdictStatus.EXPLAINED
    assert r.verdict.effects[:1] == ("coulomb_friction",)
    assert "delay" not in r.verdict.effects
    assert "chain lag" in r.verdict.message


def test_an_inductance_the_samples_cannot_resolve_is_held_where_friction_fits_can_start():
    # a 12 V gearmotor at 250 Hz: L/R = 31 us, 1/128 of a sample. An L run towards 0
    # (1e-6 of a sample's L/R) made every friction candidate's first step
    # undifferentiable ("the fit cannot start"); a fit starts or holds L at >= 1/100
    p = MotorParams(R=16.0, L=5e-4, Ke=0.34, Kt=0.34, J=1.2e-4, B=3.1e-4)
    seed = load_motor("seed001_110v")
    spec = replace(
        seed,
        model=Model(p),
        sensors=replace(seed.sensors, current_noise_a=8e-3, encoder_counts_per_rev=4800.0),
        limits=Limits(voltage_max_v=12.0, current_max_a=1.0, speed_max_rad_s=80.0),
    )
    dt, tc = 1 / 250, 0.004
    plan = plan_for_motor(spec, dt, SequenceConfig())
    run = synthesize_run(Model(p, (CoulombFriction(tc),)), plan, spec.sensors, seed=1)
    segs = list(run.segments)
    search = Search(split_segments(segs), estimate_noise(segs), DiagnosisConfig(workers=1), None)
    base = _baseline(search)
    if "L" in search.fixed:  # held: where the data can tell it
        assert search.fixed["L"] >= 0.01 * base.fit.model.params.R * dt
    tiny = Model(base.fit.model.params.replace(L=1e-6 * p.R * dt), (CoulombFriction(tc),))
    f = search.evaluate(("coulomb_friction",), tiny)
    assert f.gap < 0.1 * base.gap
