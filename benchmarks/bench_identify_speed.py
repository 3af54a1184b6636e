"""Speed of the output-error fit: 60 s of 1 kHz data, all four test types.

Fits the seeds' linear model (seed 001's motor) and the Coulomb model (seed
000's motor) with :func:`fit_output_error` (exact ZOH kernel, analytic
sensitivities, per-segment initial states), after a warm-up that compiles the
numba kernels. In the same run, a naive reference - ``scipy.integrate.solve_ivp``
inside ``scipy.optimize.least_squares`` with a finite-difference Jacobian, the
textbook way - fits the linear case from the same start; the ratio of wall
times is printed. Run: ``.venv/bin/python benchmarks/bench_identify_speed.py``
(``--no-naive`` skips the slow reference; by default both methods are timed on
the run's two step segments, ``--full-naive`` times the naive fit on all 60 s,
which takes tens of minutes). Wall and CPU time are both printed:
on a shared machine the CPU time is the figure other processes do not distort.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import least_squares

from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.estimators.output_error import fit_output_error
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import load_motor
from pmdc_ident.core.params import MotorParams

DT_S = 1e-3
TARGET_S = 60.0


def plan_60s(spec):
    """Scale the default plan so the session lasts ~60 s (all four test types)."""
    tau = spec.model.params.mechanical_time_constant_s
    base = plan_for_motor(spec, DT_S)
    coast = next(s for s in base.segments if s.label == "coast")
    open_s = float(np.isnan(coast.voltage).sum()) * DT_S
    k = (TARGET_S - open_s) / (base.duration_s - open_s)
    cfg = SequenceConfig(
        staircase_hold_tau=6.0 * k,
        step_hold_tau=6.0 * k,
        sweep_duration_tau=40.0 * k,
        coast_spinup_tau=6.0 * k,
        coast_open_s=open_s,
    )
    plan = plan_for_motor(spec, DT_S, cfg)
    return plan, tau


def start_model(p: MotorParams, effects=()) -> Model:
    return Model(
        MotorParams(
            R=p.R * 1.1, L=p.L * 0.9, Ke=p.Ke * 1.05, Kt=p.Ke * 1.05, J=p.J * 0.9, B=p.B * 1.2
        ),
        effects,
    )


def naive_fit(segments, m0: Model, noise: dict[str, float]):
    """solve_ivp (RK45, max_step = dt so no voltage step is skipped) in least_squares."""
    names = ("R", "L", "Ke", "J", "B")
    x0 = np.log([getattr(m0.params, n) for n in names])

    def simulate_seg(p, seg):
        R, L, Ke, J, B = p
        v = seg.voltage
        t = seg.t - seg.t[0]
        is_open = np.isnan(v)

        def f(tt, x):
            k = min(int(tt / DT_S), v.size - 1)
            if is_open[k]:
                return [0.0, -B / J * x[1]]
            return [(v[k] - R * x[0] - Ke * x[1]) / L, (Ke * x[0] - B * x[1]) / J]

        y0 = [seg.current[0], seg.speed[0]]
        sol = solve_ivp(f, (0, t[-1]), y0, t_eval=t, max_step=DT_S, rtol=1e-6, atol=1e-9)
        i = np.where(is_open, 0.0, sol.y[0])
        return i, sol.y[1]

    def resid(z):
        p = np.exp(z)
        out = []
        for seg in segments:
            i, w = simulate_seg(p, seg)
            out.append((i - seg.current) / noise["current"])
            out.append((w - seg.speed) / noise["speed"])
        return np.concatenate(out)

    sol = least_squares(resid, x0, method="trf", x_scale="jac")
    return dict(zip(names, np.exp(sol.x), strict=True)), sol.nfev


def main(argv: list[str]) -> None:
    # warm-up: compile the kernels on a small problem
    spec1 = load_motor("seed001_110v")
    small = synthesize_run(spec1.model, plan_for_motor(spec1, DT_S), spec1.sensors, seed=0)
    fit_output_error(small.segments[:3], start_model(spec1.model.params))
    fit_output_error(small.segments[:3], start_model(spec1.model.params, (CoulombFriction(0.01),)))

    results = {}
    for name, effects in (("seed001_110v", ()), ("seed000_ebike", (CoulombFriction(0.02),))):
        spec = load_motor(name)
        plan, _ = plan_60s(spec)
        run = synthesize_run(spec.model, plan, spec.sensors, seed=1)
        m0 = start_model(spec.model.params, effects)
        t0, c0 = time.perf_counter(), time.process_time()
        res = fit_output_error(run.segments, m0)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        true = spec.model.params
        err = max(abs(res.values[k] / getattr(true, k) - 1) for k in ("R", "Ke"))
        results[name] = (wall, cpu, res, run, m0)
        print(
            f"{name}: {plan.duration_s:.1f} s at {1 / DT_S:.0f} Hz, {res.n_samples} samples, "
            f"{len(run.segments)} segments, model {'+'.join(res.model.effect_names) or 'linear'}: "
            f"fit {wall:.3f} s wall, {cpu:.3f} s CPU ({res.iterations} iterations, "
            f"{res.nfev} evaluations), "
            f"max |rel err| R, Ke = {err:.2e}"
        )
    if "--no-naive" in argv:
        return
    wall, cpu, res, run, m0 = results["seed001_110v"]
    true = load_motor("seed001_110v").model.params
    if "--full-naive" in argv:
        segs = list(run.segments)
        what = "the whole 60 s run"
    else:
        # The naive fit of 60 s takes tens of minutes on a loaded 2-core machine: both
        # methods are timed on the two step segments of the same run instead (the fast
        # fit's fixed costs weigh more on less data, so this ratio is conservative).
        segs = [s for s in run.segments if s.label.startswith("step")]
        what = f"the step segments of the same run ({sum(s.n for s in segs)} samples)"
    t0, c0 = time.perf_counter(), time.process_time()
    small = fit_output_error(segs, m0)
    fw, fc = time.perf_counter() - t0, time.process_time() - c0
    print(f"naive reference (solve_ivp inside least_squares) on {what} ...", flush=True)
    t0, c0 = time.perf_counter(), time.process_time()
    vals, nfev = naive_fit(segs, m0, small.noise)
    naive, naive_cpu = time.perf_counter() - t0, time.process_time() - c0
    err = max(abs(vals[k] / getattr(true, k) - 1) for k in vals)
    err_fast = max(abs(small.values[k] / getattr(true, k) - 1) for k in vals)
    print(
        f"naive: {naive:.1f} s wall, {naive_cpu:.1f} s CPU ({nfev} residual evaluations "
        "plus finite-difference Jacobians), "
        f"max |rel err| {err:.2e}; fast fit on the same data {fw:.3f} s wall / {fc:.3f} s CPU "
        f"(max |rel err| {err_fast:.2e}) -> speed-up x{naive / fw:.0f} (wall), "
        f"x{naive_cpu / fc:.0f} (CPU)"
    )


if __name__ == "__main__":
    main(sys.argv[1:])
