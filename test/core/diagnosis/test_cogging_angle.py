"""Cogging fitted in the measured shaft angle (core.diagnosis.cogging)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pmdc_ident.core.diagnosis import DiagnosisConfig
from pmdc_ident.core.diagnosis.candidates import data_scales
from pmdc_ident.core.diagnosis.cogging import angle_cogging, held_waves
from pmdc_ident.core.diagnosis.holdout import split_segments
from pmdc_ident.core.diagnosis.pipeline import _baseline
from pmdc_ident.core.diagnosis.scoring import estimate_noise
from pmdc_ident.core.diagnosis.search import Search
from pmdc_ident.core.effects import Cogging
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import load_motor


def test_a_held_wave_is_the_mean_of_the_wave_over_its_sample():
    theta = np.cumsum(np.full(200, 0.3))  # 0.3 rad per sample, 17 periods per turn
    s, c = held_waves(theta, 17.0)
    k = 50
    a, b = 17.0 * theta[k], 17.0 * theta[k + 1]  # the exact means over [a, b]
    assert s[k] == pytest.approx((math.cos(a) - math.cos(b)) / (b - a), abs=1e-12)
    assert c[k] == pytest.approx((math.sin(b) - math.sin(a)) / (b - a), abs=1e-12)


def test_cogging_is_read_off_the_measured_angle_with_its_count_and_phase():
    spec = load_motor("seed001_110v")
    p = spec.model.params
    plan = plan_for_motor(spec, 1e-3, SequenceConfig(sweep_duration_tau=20.0))
    clean = synthesize_run(Model(p), plan, None, seed=0)
    amp = 0.02 * data_scales(clean.segments, p.Kt).torque_nm
    truth = Cogging(amp, 17.0, 1.0)
    run = synthesize_run(Model(p, (truth,)), plan, spec.sensors, seed=2)
    segs = list(run.segments)
    search = Search(split_segments(segs), estimate_noise(segs), DiagnosisConfig(workers=1), None)
    base = _baseline(search)
    f, fit_gap = angle_cogging(search, base, [16, 17, 18])
    e = f.fit.model.effect("cogging")
    assert isinstance(e, Cogging) and e.periods_per_rev == 17.0
    # the count and the phase from the angle; the amplitude only to a factor (the fit
    # segments see the coast-down fast, its slow end where cogging shows is held out)
    assert abs(math.remainder(e.phase_rad - 1.0, 2 * math.pi)) < 0.2
    assert amp / 4 < e.torque_nm < 2 * amp
    assert f.gap < 0.5 * base.gap and math.isfinite(fit_gap)
