"""Where the diagnosis' baseline starts: the linear model's output-error cost has more
than one minimum where the fit side tells little, and a start in the wrong basin left a
misfit that an effect then "closed" on effect-free records (session 8, issue 25)."""

from __future__ import annotations

from functools import cache

import pytest

from pmdc_ident.benchmark.motors import MOTORS
from pmdc_ident.core.design import Prior, plan_experiment, session_limits
from pmdc_ident.core.design.information import Noise
from pmdc_ident.core.diagnosis.config import DiagnosisConfig
from pmdc_ident.core.diagnosis.holdout import split_segments
from pmdc_ident.core.diagnosis.pipeline import _baseline, _fit_gap
from pmdc_ident.core.diagnosis.scoring import estimate_noise
from pmdc_ident.core.diagnosis.search import Search
from pmdc_ident.core.estimators.start import equation_error_start
from pmdc_ident.core.excitation import SensorSpec, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import Limits

SCOOTER = MOTORS["scooter_24v"]  # 9.78:1, 508 encoder counts per output turn
DT = 1e-3


@cache
def _crawls():  # type: ignore[no-untyped-def]
    """A cogging reveal plan (crawls there and back, no designed part) on an
    effect-free geared scooter motor, logged with its coarse encoder and no speed."""
    p = SCOOTER.params
    prior = Prior(Model(p), Noise(0.08, position_sd=0.004), "test")
    driver = Limits(24.0, 1.5 * 24.0 / p.R, 120.0)
    lim = session_limits(prior, driver, DT)
    plan = plan_experiment(prior, driver, DT, limits=lim, reveal=("cogging",)).plan
    spec = SensorSpec(current_noise_a=0.08, encoder_counts_per_rev=SCOOTER.counts_per_rev)
    run = synthesize_run(Model(p), plan, spec, seed=1, signals=("current", "position"))
    return list(run.segments)


def test_a_smoothed_equation_error_start_is_not_pulled_to_zero_by_a_coarse_encoder():
    """At a crawl the speed differentiated from the encoder is a count every few
    samples and zeros between: noise in the regressor of V = R i + Ke w pulls Ke towards
    zero. On signals averaged over a fiftieth of each segment it is not."""
    fit = split_segments(_crawls()).fit
    p = SCOOTER.params
    assert equation_error_start(fit, {}).Ke < 0.7 * p.Ke  # 0.12 against 0.73
    smooth = equation_error_start(fit, {}, smooth=True)
    assert smooth.Ke == pytest.approx(p.Ke, rel=0.05)
    assert smooth.R == pytest.approx(p.R, rel=0.15)


def test_the_baseline_stands_on_the_start_that_fits_its_segments_best():
    """From the equation-error start alone the fit stopped at R 5.8 against 0.34 ohm and
    Ke 0.14 against 0.73 (5 noise variances on its own segments); fitted from every
    start, the one that fits the fit side best stands: the truth's basin."""
    segs = _crawls()
    split = split_segments(segs)
    noise = estimate_noise(segs)
    search = Search(split, noise, DiagnosisConfig(), None)
    base = _baseline(search)
    got, p = base.fit.model.params, SCOOTER.params
    assert got.Ke == pytest.approx(p.Ke, rel=0.01)
    assert got.R == pytest.approx(p.R, rel=0.05)
    assert got.J == pytest.approx(p.J, rel=0.05)
    assert _fit_gap(base, split.fit, noise) < 0.5
