"""Drift monitor on the simulator: heating tracked and flagged, no false alarm, CPU per sample.

1. Heating (``resistance_drift``) on seed 000 under a random walk of speed
   set-points: the worst |R_hat/R_true - 1| after a 5 s start, and how long after
   the true R crosses the WARN threshold (+10 %) the monitor flags it.
2. Ten minutes of the same motor without any drift effect: WARN/ERROR reports
   (false alarms) and the latched suggestion.
3. CPU of the monitor core at 1 kHz: process time per sample, fed one sample at a
   time and in batches of 20, against a naive reference (a numpy Kalman update of
   the same 3 + 1 parameters on every sample, no filters), in the same run.

4. With ``--node``: the monitor node at 1 kHz over real DDS (loopback, domain 16)
   beside the simulated driver and a voltage-step publisher: its CPU (process time
   over 20 s, twice), against a reference process that only receives the same
   three topics raw (the floor cost of taking 3000 messages/s in rclpy).

Run: ``.venv/bin/python benchmarks/bench_monitor.py [--minutes 10] [--node]``. The
core runs faster than real time here.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

import numpy as np

from pmdc_ident.core.control_design import design_gains
from pmdc_ident.core.effects import ResistanceDrift
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.core.service_run import simulate_service
from pmdc_ident.node_logic.drift_monitor import DriftLevel, DriftMonitor


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


_REFERENCE = """
import signal, rclpy
from rclpy.experimental import EventsExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
stop = []
signal.signal(signal.SIGINT, lambda *a: stop.append(1))
n = rclpy.create_node("receive_only")
q = QoSProfile(depth=2000, reliability=ReliabilityPolicy.RELIABLE)
for t in ("voltage_applied", "current", "encoder"):
    n.create_subscription(JointState, t, lambda raw: None, q, raw=True)
ex = EventsExecutor()
ex.add_node(n)
while not stop:
    ex.spin_once(timeout_sec=0.05)
"""
_DRIVE = """
import signal, time, rclpy
from rclpy.signals import SignalHandlerOptions
from std_msgs.msg import Float64
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
stop = []
signal.signal(signal.SIGINT, lambda *a: stop.append(1))
n = rclpy.create_node("steps")
pub = n.create_publisher(Float64, "voltage_cmd", 10)
levels, t0 = [6.0, 14.0, -8.0, 3.0, 18.0, -12.0], time.monotonic()
while not stop:
    pub.publish(Float64(data=levels[int((time.monotonic() - t0) / 0.7) % 6]))
    time.sleep(0.02)
"""


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def node_cpu(window_s: float = 20.0, repeats: int = 2) -> None:
    from pmdc_ident.process.bringup import node_env as ros_env

    env = ros_env(16)
    py = sys.executable
    procs = {
        "driver": [py, "-m", "pmdc_ident.nodes.driver_node"],
        "monitor": [py, "-m", "pmdc_ident.nodes.monitor_node"],
        "receive-only reference": [py, "-c", _REFERENCE],
        "steps": [py, "-c", _DRIVE],
    }
    running = {
        k: subprocess.Popen(c, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for k, c in procs.items()
    }
    try:
        time.sleep(10.0)  # start-up, discovery, the monitor's first compile
        for rep in range(repeats):
            a = {k: _cpu_s(p.pid) for k, p in running.items()}
            w0 = time.perf_counter()
            time.sleep(window_s)
            wall = time.perf_counter() - w0
            b = {k: _cpu_s(p.pid) for k, p in running.items()}
            share = {k: 100 * (b[k] - a[k]) / wall for k in running}
            print(
                f"node at 1 kHz, window {rep + 1}: monitor_node {share['monitor']:.1f} % of one "
                f"core (goal < 15 %), receive-only reference "
                f"{share['receive-only reference']:.1f} %, driver {share['driver']:.1f} %; "
                f"load {os.getloadavg()[0]:.1f}"
            )
    finally:
        for p in running.values():
            p.send_signal(2)
        for p in running.values():
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--heating-minutes", type=float, default=5.0)
    ap.add_argument("--k", type=float, default=5e-4, help="resistance_drift coefficient")
    ap.add_argument("--node", action="store_true", help="also measure the node over DDS")
    ap.add_argument("--node-only", action="store_true", help="only the node measurement")
    args = ap.parse_args()
    if args.node_only:
        node_cpu()
        return
    print(f"load: {os.getloadavg()[0]:.1f} (1 min average) on {os.cpu_count()} cores")
    spec = load_motor("seed000_ebike")
    design = design_gains(
        spec.model.params, spec.limits, sample_rate_hz=1000, speed_bandwidth_hz=5
    )
    for seed in (11, 21, 31):
        heating(spec, design, args.heating_minutes, args.k, seed)
    clean(spec, design, args.minutes)
    cpu(spec, design)
    if args.node:
        node_cpu()


if __name__ == "__main__":
    main()
