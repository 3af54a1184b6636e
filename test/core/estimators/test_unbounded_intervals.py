"""A parameter the data bound by nothing (relative sd in the hundreds) must give an
honest 'unbounded' answer, never an OverflowError from a Python float's ``**``.

The record's shape: generator blind seed 2 (--runs-per-effect 8) quadratic_drag_05,
a 24 V servo (R 0.6 ohm, L 0.9 mH) logged at 5 kHz in one direction. Its baseline
fit left L with a relative sd near 200; the fit's own identifiability pass squared
the ratio of that sd to its target as a Python float and raised (34, 'Numerical
result out of range'), which diagnose reported as 'the baseline linear model could
not be fitted'."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from pmdc_ident.core.estimators.output_error.fit import _flag_from_bound
from pmdc_ident.core.estimators.output_error.results import FitResult
from pmdc_ident.core.estimators.uncertainty import widen_interval
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import MotorParams


def _servo_fit(rel_sd_l: float) -> FitResult:
    p = MotorParams(R=0.6, L=0.9e-3, Ke=0.043, Kt=0.043, J=7.5e-5, B=2e-5)
    values = {"R": p.R, "L": p.L, "Ke": p.Ke, "Kt": p.Kt, "J": p.J, "B": p.B}
    free = ("R", "L", "Ke", "J", "B")
    stderr = {n: 0.01 * values[n] for n in free}
    stderr["L"] = rel_sd_l * p.L
    return FitResult(
        model=Model(p),
        values=values,
        ci95={n: (0.98 * values[n], 1.02 * values[n]) for n in free},
        stderr=stderr,
        covariance=np.eye(len(free)),
        covariance_names=free,
        identifiable={n: n != "L" for n in free},
        reasons={"L": "the 95 % interval spans more than a factor 2.7"},
        cost=1.0,
        n_samples=30_000,
        rms={"current": 0.06, "speed": 0.8},
        noise={"current": 0.06, "speed": 0.8},
        free=free,
        fixed={},
        closure=None,
        initial_states={},
        nfev=10,
        iterations=5,
        converged=True,
        message="",
        elapsed_s=0.0,
        fast_path=True,
    )


def test_an_inductance_bounded_by_nothing_at_5_khz_is_flagged_not_an_overflow():
    segs = [SimpleNamespace(dt=2e-4)]  # 5 kHz: L/R = 1.5 ms spans 7 samples
    for rel in (200.0, 1e4, math.inf):
        out = _flag_from_bound(_servo_fit(rel), segs, 0.0)
        assert out.identifiable["L"] is False
        assert out.ci95["L"] is None and out.stderr["L"] is None
        assert "LCR meter" in out.reasons["L"]


def test_widening_an_interval_bounded_by_nothing_gives_an_open_end_not_an_overflow():
    # a log-fitted parameter with relative sd 200 has a 95 % interval of e^+-392
    # (1e170) around its value; widened 2x for coloured residuals it leaves the float
    # range: that end is unbounded (inf and 0), not an OverflowError
    lo, hi = widen_interval(1e-3, (1e-3 * math.exp(-392.0), 1e-3 * math.exp(392.0)), 2.0)
    assert hi == math.inf and lo == 0.0
    lo, hi = widen_interval(2.0, (1.0, 4.0), 2.0)
    assert math.isclose(lo, 0.5) and math.isclose(hi, 8.0)


def test_a_parameter_run_off_beyond_a_float_is_unconstrained_without_a_warning(recwarn):
    # a failed cogging candidate's refit on a MuJoCo reveal record (the scooter, seed 7
    # run 9): J ran off to exp(400); its variance in physical units overflowed a float
    # and numpy printed "overflow encountered in multiply" to the user
    from pmdc_ident.core.estimators.output_error.results import _uncertainty

    info = (SimpleNamespace(name="R", log=True), SimpleNamespace(name="J", log=True))
    z = np.array([math.log(0.6), 400.0])
    prob = SimpleNamespace(
        n_total=2,
        n_global=2,
        info=info,
        values_at=lambda zz: {"R": math.exp(zz[0]), "J": math.exp(zz[1])},
        dvalue_dz=lambda zz: np.exp(zz),
    )
    r = np.full(100, 0.1)
    A = np.diag([1e4, 1.0])
    with np.errstate(all="warn"):
        unc = _uncertainty(prob, z, r, A, {})
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
    assert unc.identifiable["R"] and unc.stderr["R"] is not None
    assert unc.identifiable["J"] is False and unc.stderr["J"] is None
    assert "ran off" in unc.reasons["J"]
