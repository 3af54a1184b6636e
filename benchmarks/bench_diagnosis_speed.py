"""Diagnosis speed: a 60 s, 1 kHz session with the whole effect vocabulary.

Goal (issue 6): under 30 s wall on the 2-core development machine. Prints the
wall and CPU time of ``diagnose`` and, as the naive reference measured in the
same run, one candidate fit done the textbook way (scipy ``least_squares`` with
finite differences over :func:`pmdc_ident.core.model.simulate`, measured
initial states), scaled by the number of candidate fits the diagnosis makes.

Run: ``.venv/bin/python benchmarks/bench_diagnosis_speed.py`` (``make bench``).
"""

from __future__ import annotations

import os
import resource
import time

import numpy as np
from scipy.optimize import least_squares

from pmdc_ident.core.diagnosis import diagnose
from pmdc_ident.core.diagnosis.candidates import predict
from pmdc_ident.core.diagnosis.holdout import split_segments
from pmdc_ident.core.effects import CoulombFriction
from pmdc_ident.core.excitation import SequenceConfig, plan_for_motor, synthesize_run
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import load_motor
from pmdc_ident.core.params import MotorParams

DT_S = 1e-3
TARGET_S = 60.0


def _cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def session():
    spec = load_motor("seed000_ebike")
    base = plan_for_motor(spec, DT_S)
    # lengthen the sweep so the session lasts TARGET_S
    sweep_tau = 40.0 + (TARGET_S - base.duration_s) / spec.model.params.mechanical_time_constant_s
    plan = plan_for_motor(spec, DT_S, SequenceConfig(sweep_duration_tau=sweep_tau))
    return spec, plan, synthesize_run(spec.model, plan, spec.sensors, seed=1)


def naive_candidate_fit(segments, p0: MotorParams, tc0: float) -> tuple[float, int]:
    """Textbook output error: least_squares, 2-point differences, full simulate."""
    names = ["R", "Ke", "J", "B"]

    def model_of(x: np.ndarray) -> Model:
        v = dict(zip(names, np.exp(x[:4]), strict=True))
        p = p0.replace(**v, Kt=v["Ke"])
        return Model(p, (CoulombFriction(float(np.exp(x[4]))),))

    def resid(x: np.ndarray) -> np.ndarray:
        preds = predict(model_of(x), segments, substeps=8)
        out = []
        for s, pr in zip(segments, preds, strict=True):
            out.append((pr.current - s.current) / 0.01)
            out.append((pr.speed - s.speed) / 0.05)
        return np.concatenate(out)

    x0 = np.log([p0.R, p0.Ke, p0.J, max(p0.B, 1e-9), tc0])
    t0 = time.perf_counter()
    sol = least_squares(resid, x0, method="trf", diff_step=1e-6, max_nfev=30)
    return time.perf_counter() - t0, int(sol.nfev)


def main() -> None:
    spec, plan, run = session()
    n = plan.n_samples
    print(
        f"session: {plan.duration_s:.1f} s at {1 / DT_S:g} Hz = {n} samples, "
        f"{len(run.segments)} segments; load average {os.getloadavg()[0]:.1f} "
        f"on {os.cpu_count()} cores"
    )
    diagnose(run.segments[:2])  # warm-up: numba kernels from cache
    fits: list[str] = []
    c0, t0 = _cpu_s(), time.perf_counter()
    res = diagnose(run, progress=lambda m: fits.append(m))
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    n_fits = sum(1 for m in fits if m.startswith(("candidate", "combination", "baseline")))
    print(
        f"diagnose: {wall:.1f} s wall, {cpu:.1f} s CPU, {n_fits} model fits; verdict "
        f"{res.verdict.status.value} {list(res.verdict.effects)}, shrink {res.shrink:.0%}"
    )
    print(f"goal: < 30 s wall -> {'met' if wall < 30.0 else 'NOT met'}")

    split = split_segments(run.segments)
    p = spec.model.params
    naive_s, nfev = naive_candidate_fit(list(split.fit), p.replace(B=p.B * 2), 0.01)
    est = naive_s * n_fits
    print(
        f"naive reference: one Coulomb candidate fit by least_squares + finite "
        f"differences = {naive_s:.1f} s ({nfev} evaluations); x {n_fits} fits = "
        f"{est:.0f} s estimated"
    )
    print(f"ratio naive / diagnose (wall): {est / wall:.1f}x")


if __name__ == "__main__":
    main()
