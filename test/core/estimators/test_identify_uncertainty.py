"""The covariance intervals agree with a parametric bootstrap on a small problem."""

from __future__ import annotations

from pmdc_ident.core.estimators.output_error import fit_output_error
from pmdc_ident.core.estimators.uncertainty import parametric_bootstrap
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.motors import load_motor


def test_bootstrap_spread_matches_covariance_stderr_within_sampling_error():
    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(staircase=False, coast=False, sweep_duration_tau=20.0)
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=8)
    fit = fit_output_error(run.segments, spec.model)
    bs = parametric_bootstrap(fit, run.segments, n=12, seed=1)
    assert set(bs["parameters"]) == {"R", "L", "Ke", "J", "B"}
    for name, row in bs["parameters"].items():
        # the std of 12 draws scatters by ~20 % (1/sqrt(2*11)); 0.5-2 is a wide band
        assert 0.5 < row["ratio"] < 2.0, (name, row)


def test_intervals_widen_for_coloured_residuals_and_not_for_white_ones():
    from pmdc_ident.core.estimators.uncertainty import coloured_noise_factor, widen_interval

    spec = load_motor("seed001_110v")
    cfg = SequenceConfig(staircase=False, coast=False, sweep_duration_tau=20.0)
    run = synthesize_run(spec.model, plan_for_motor(spec, 2e-3, cfg), spec.sensors, seed=8)
    fit = fit_output_error(run.segments, spec.model)
    white = coloured_noise_factor(fit, run.segments)
    assert all(0.7 < f < 1.5 for f in white.values())
    # a model missing 20 % of the viscous friction leaves slow, coloured residuals
    wrong = fit_output_error(
        run.segments, spec.model, fixed={"B": 0.8 * spec.model.params.B}, refine_noise=False
    )
    assert max(coloured_noise_factor(wrong, run.segments).values()) > 5.0
    assert widen_interval(2.0, (1.0, 4.0), 2.0) == (0.5, 8.0)
    assert widen_interval(0.0, (-1.0, 1.0), 3.0) == (-3.0, 3.0)
