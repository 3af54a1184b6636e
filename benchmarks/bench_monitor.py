"""Drift monitor on the simulator: heating tracked and flagged, no false alarm, CPU per sample.

1. Heating (``resistance_drift``) on seed 000 under a random walk of speed
   set-points: the worst |R_hat/R_true - 1| after a 5 s start, and how long after
   the true R crosses the WARN threshold (+10 %) the monitor flags it.
2. Ten minutes of the same motor without any drift effect: WARN/ERROR reports
   (false alarms) and the latched suggestion.
3. CPU of the monitor core at 1 kHz: process time per sample, fed one sample at a
   time and in batches of 20, against a naive reference (a numpy Kalman update of
   the same 3 + 1 parameters on every sample, no filters), in the same run.

Run: ``.venv/bin/python benchmarks/bench_monitor.py [--minutes 10]``. The core runs
faster than real time here; the node's CPU at 1 kHz is measured by
``benchmarks/bench_monitor.py --node`` (see the README).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from pmdc_ident.core.control_design import design_gains
from pmdc_ident.core.drift_monitor import DriftLevel, DriftMonitor
from pmdc_ident.core.effects import ResistanceDrift
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.core.service_run import simulate_service


def heating(spec: MotorSpec, design, minutes: float, k_per_a2s: float, seed: int) -> None:
    true = MotorSpec(
        spec.name, spec.model.with_effects(ResistanceDrift(k_per_a2s)), spec.sensors, spec.limits
    )
    run = simulate_service(true, design, 60.0 * minutes, seed=seed)
    mon = DriftMonitor(spec)
    reports = []
    for a in range(0, run.t.size, 20):
        sl = slice(a, a + 20)
        reports += mon.process(run.t[sl], run.voltage[sl], run.current[sl], run.speed[sl])
    t = np.array([r.t_s for r in reports])
    r_hat = np.array([r.quantity("resistance").value for r in reports])
    r_true = np.interp(t, run.t, run.true_resistance_ohm)
    err = np.abs(r_hat / r_true - 1.0)[t > 5.0]
    r0 = spec.model.params.R
    cross = run.t[np.argmax(run.true_resistance_ohm > 1.10 * r0)]
    warn = [r.quantity("resistance").level >= DriftLevel.WARN for r in reports]
    flagged = t[np.argmax(warn)] if any(warn) else float("nan")
    print(
        f"heating k={k_per_a2s:g}/(A^2 s), {minutes:g} min, seed {seed}: R {r0:.4g} -> "
        f"{run.true_resistance_ohm[-1]:.4g} ohm; "
        f"tracking error max {100 * err.max():.2f} %, rms {100 * np.sqrt(np.mean(err**2)):.2f} % "
        f"(goal 2 %); WARN threshold crossed at {cross:.1f} s, flagged at {flagged:.1f} s: "
        f"delay {flagged - cross:.1f} s (goal 10 s)"
    )


def clean(spec: MotorSpec, design, minutes: float) -> None:
    run = simulate_service(spec, design, 60.0 * minutes, seed=12)
    mon = DriftMonitor(spec)
    reports = []
    for a in range(0, run.t.size, 20):
        sl = slice(a, a + 20)
        reports += mon.process(run.t[sl], run.voltage[sl], run.current[sl], run.speed[sl])
    bad = [r for r in reports if r.level > DriftLevel.OK]
    worst = max((abs(r.quantity("resistance").drift) for r in reports[50:]), default=0.0)
    print(
        f"effect-free {minutes:g} min (random walk of speed set-points): {len(bad)} WARN/ERROR "
        f"reports of {len(reports)}, suggestion latched: {mon.suggest_reidentify}; "
        f"largest |R drift| estimate {100 * worst / spec.model.params.R:.2f} % (WARN at 10 %)"
    )


def naive(t, v, i, w, spec: MotorSpec) -> None:
    """Reference: a Kalman update of [R, Ke, d] and [Tf] with numpy on every sample."""
    p = spec.model.params
    th, pe = np.array([p.R, p.Ke, 0.0]), np.eye(3) * 1e-2
    tm, pm = np.array([0.0]), np.eye(1) * 1e-2
    for k in range(1, t.size):
        h = t[k] - t[k - 1]
        phi = np.array([i[k], w[k], (v[k - 1] - v[k - 2]) / h if k > 1 else 0.0])
        y = v[k - 1] - p.L * (i[k] - i[k - 1]) / h
        s = phi @ pe @ phi + 1e-2
        g = pe @ phi / s
        th = th + g * (y - phi @ th)
        pe = pe - np.outer(g, phi @ pe) + np.eye(3) * 1e-9
        phm = np.array([np.sign(w[k])])
        ym = p.Kt * i[k] - p.J * (w[k] - w[k - 1]) / h - p.B * w[k]
        sm = phm @ pm @ phm + 1e-4
        gm = pm @ phm / sm
        tm = tm + gm * (ym - phm @ tm)
        pm = pm - np.outer(gm, phm @ pm) + 1e-9


def cpu(spec: MotorSpec, design) -> None:
    run = simulate_service(spec, design, 20.0, seed=13)
    n = run.t.size
    DriftMonitor(spec).process(run.t[:100], run.voltage[:100], run.current[:100], run.speed[:100])
    figures = {}
    for batch in (1, 20):
        mon = DriftMonitor(spec)
        c0, w0 = time.process_time(), time.perf_counter()
        for a in range(0, n, batch):
            sl = slice(a, a + batch)
            mon.process(run.t[sl], run.voltage[sl], run.current[sl], run.speed[sl])
        figures[batch] = ((time.process_time() - c0) / n, (time.perf_counter() - w0) / n)
    m = min(n, 5000)
    c0 = time.process_time()
    naive(run.t[:m], run.voltage[:m], run.current[:m], run.speed[:m], spec)
    ref = (time.process_time() - c0) / m
    for batch, (c, wall) in figures.items():
        print(
            f"monitor core, batches of {batch:2d}: {c * 1e6:.1f} us CPU/sample "
            f"({wall * 1e6:.1f} us wall) "
            f"= {100 * c * 1000:.2f} % of one core at 1 kHz; naive numpy reference "
            f"{ref * 1e6:.1f} us/sample: ratio {ref / c:.1f}x"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--heating-minutes", type=float, default=5.0)
    ap.add_argument("--k", type=float, default=5e-4, help="resistance_drift coefficient")
    args = ap.parse_args()
    print(f"load: {os.getloadavg()[0]:.1f} (1 min average) on {os.cpu_count()} cores")
    spec = load_motor("seed000_ebike")
    design = design_gains(
        spec.model.params, spec.limits, sample_rate_hz=1000, speed_bandwidth_hz=5
    )
    for seed in (11, 21, 31):
        heating(spec, design, args.heating_minutes, args.k, seed)
    clean(spec, design, args.minutes)
    cpu(spec, design)


if __name__ == "__main__":
    main()
