"""Accuracy of the output-error fit against the Cramer-Rao bound (Monte Carlo).

A known motor is simulated once on the default plan (1 kHz); each Monte Carlo
run adds fresh white noise at the sensor levels (current 0.01 A, speed
0.05 rad/s) and fits from a start 5-10 % off. The Cramer-Rao bound is the
inverse Fisher information at the true parameters and noise levels, with the
per-segment initial states as nuisance parameters (Kt = Ke closure, as in the
fit). Printed per parameter: bias, RMS error, RMS error / CRB standard
deviation (goal <= 1.25), |bias| / spread (goal < 0.1), and the mean covariance
stderr of the fits / CRB (the reported intervals' calibration).

Cases: seed 001's motor with the linear model (the data come from the same
model: efficiency is the question), and seed 000's motor with Coulomb friction
(data from the 8-sub-step simulator, fit with one exact step per sample: this
also shows the bias of that model difference).
Run: ``.venv/bin/python benchmarks/bench_crb.py [N_RUNS [CASE...]]`` (default 100,
both cases).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from pmdc_ident.core.data import Segment
from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.estimators.output_error import fit_output_error
from pmdc_ident.core.estimators.output_error.parameters import model_values
from pmdc_ident.core.estimators.output_error.problem import Problem
from pmdc_ident.core.estimators.output_error.segments import initial_noise, prepare_segments
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import SensorSpec, load_motor
from pmdc_ident.core.params import MotorParams

NOISE = {"current": 0.01, "speed": 0.05}


def crb(segments, model: Model, free: list[str]) -> dict[str, float]:
    """CRB standard deviations (physical units) at the true model and noise."""
    segs = prepare_segments(segments, [])
    prob = Problem(segs, model, model_values(model), free, True, True, initial_noise(segs), {})
    prob.noise = dict(NOISE)
    z = prob.z0()
    _r, A, _g = prob.evaluate(z, True)
    cov_z = np.linalg.inv(A)
    d = prob.dvalue_dz(z)
    return {n: float(math.sqrt(cov_z[j, j]) * d[j]) for j, n in enumerate(free)}


def run_case(name: str, effects: tuple, n_runs: int, rng: np.random.Generator) -> None:
    spec = load_motor(name)
    truth = Model(spec.model.params.replace(Kt=spec.model.params.Ke), effects)
    plan = plan_for_motor(spec, 1e-3)
    clean = synthesize_run(truth, plan, SensorSpec(), seed=0)
    p = truth.params
    free = ["R", "L", "Ke", "J", "B"] + [f"{e.NAME}.torque_nm" for e in effects]
    bound = crb(clean.segments, truth, free)
    true_vals = model_values(truth)
    est: dict[str, list[float]] = {k: [] for k in free}
    se: dict[str, list[float]] = {k: [] for k in free}
    t0 = time.perf_counter()
    for _ in range(n_runs):
        segs = [
            Segment(
                s.label,
                s.t,
                s.voltage,
                current=s.current + rng.normal(0, NOISE["current"], s.n),
                speed=s.speed + rng.normal(0, NOISE["speed"], s.n),
            )
            for s in clean.segments
        ]
        f = rng.uniform(0.9, 1.1, 5)
        start = Model(
            MotorParams(
                R=p.R * f[0],
                L=p.L * f[1],
                Ke=p.Ke * f[2],
                Kt=p.Ke * f[2],
                J=p.J * f[3],
                B=p.B * f[4],
            ),
            tuple(type(e)(e.torque_nm * rng.uniform(0.9, 1.1)) for e in effects),
        )
        res = fit_output_error(segs, start, check_inductance=False)
        for k in free:
            est[k].append(res.values[k])
            se[k].append(res.stderr[k] or float("nan"))
    wall = time.perf_counter() - t0
    print(
        f"\n{name} ({'+'.join(e.NAME for e in effects) or 'linear'} model), {n_runs} runs of "
        f"{clean.segments[0].dt_s * 1e3:g} ms x {sum(s.n for s in clean.segments)} samples, "
        f"{wall / n_runs:.3f} s per fit"
    )
    print(
        f"  {'parameter':<28}{'true':>12}{'bias':>12}{'rms err':>12}{'CRB std':>12}"
        f"{'rms/CRB':>9}{'|bias|/sd':>10}{'se/CRB':>8}"
    )
    for k in free:
        e = np.array(est[k]) - true_vals[k]
        rms = float(np.sqrt(np.mean(e**2)))
        bias = float(np.mean(e))
        sd = float(np.std(e, ddof=1))
        print(
            f"  {k:<28}{true_vals[k]:>12.5g}{bias:>12.3g}{rms:>12.3g}{bound[k]:>12.3g}"
            f"{rms / bound[k]:>9.3f}{abs(bias) / sd:>10.3f}{np.nanmean(se[k]) / bound[k]:>8.3f}"
        )


CASES = {
    "seed001_110v": (),
    "seed000_ebike": (CoulombFriction(0.0256),),
}


def main(argv: list[str]) -> None:
    n_runs = int(argv[0]) if argv else 100
    names = argv[1:] or list(CASES)
    rng = np.random.default_rng(2026)
    for name in names:
        run_case(name, CASES[name], n_runs, rng)
    print(
        f"\n(with {n_runs} runs the sampling error of |bias|/sd is about {1 / n_runs**0.5:.2f}"
        f" and of rms/CRB about {1 / (2 * n_runs) ** 0.5:.2f})"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
