"""export-model end to end: identify a simulated session, export, replay in MuJoCo, close loops.

1. A default session on the simulated seed-000 motor (Coulomb friction, sensor
   noise) is identified (the linear model and the model with Coulomb friction).
2. The identified motor is written as MJCF and driven in MuJoCo with the
   session's recorded voltage (the coast-down excluded: MuJoCo's motor has no open
   armature); its speed is compared with the project's own simulation of the same
   identified model (RMS relative to the speed's RMS; goal 1 % for the linear model).
3. Cascade gains are designed on the identified linear model and the discrete
   loop is run on it and on the simulated true motor: overshoot and settling
   against the design's promise.

Run: ``.venv/bin/python benchmarks/bench_export.py`` (needs the ``mujoco`` package).
"""

from __future__ import annotations

import os
import time

import mujoco
import numpy as np

from pmdc_ident.core.control_design import TOLERANCES, check_gains, design_gains
from pmdc_ident.core.excitation import plan_for_motor, synthesize_run
from pmdc_ident.core.identification.identify import identify, merge_runs
from pmdc_ident.core.model import Model, simulate, simulate_linear
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.exports.mujoco_xml import mujoco_xml


def replay(xml: str, voltage: np.ndarray, dt_s: float) -> np.ndarray:
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    sub = round(dt_s / m.opt.timestep)
    w = np.empty(voltage.size)
    for k, v in enumerate(voltage):
        w[k] = d.qvel[0]
        d.ctrl[0] = v
        mujoco.mj_step(m, d, nstep=sub)
    return w


def rel_rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b**2)))


def main() -> None:
    print(f"load: {os.getloadavg()[0]:.1f} (1 min average) on {os.cpu_count()} cores")
    true = load_motor("seed000_ebike")
    dt = 1e-3
    run = synthesize_run(true.model, plan_for_motor(true, dt), true.sensors, seed=7)
    c0 = time.process_time()
    result = identify(merge_runs([run]), sources=(run.source,))
    print(f"identified in {time.process_time() - c0:.1f} s CPU: {result.model}")
    ident = MotorSpec("identified", result.model, limits=true.limits)
    linear = MotorSpec("identified_linear", Model(result.model.params), limits=true.limits)
    v = np.concatenate([s.voltage for s in run.segments if not np.isnan(s.voltage).any()])
    for spec, label in ((linear, "linear"), (ident, "with Coulomb friction")):
        for flavour in ("dcmotor", "general"):
            w_mj = replay(mujoco_xml(spec, flavour=flavour).xml, v, dt)
            ref = simulate(spec.model, v, dt).speed
            print(
                f"MuJoCo {flavour:7s} replay of {v.size * dt:.1f} s of recorded voltage, "
                f"identified model {label}: speed RMS {100 * rel_rms(w_mj, ref):.3f} % of the "
                f"project's simulation" + (" (goal 1 %)" if label == "linear" else "")
            )
    w_lin = simulate_linear(linear.model.params, v, dt).speed
    w_true = simulate(true.model, v, dt).speed
    print(
        f"(for scale: identified linear model vs true motor {100 * rel_rms(w_lin, w_true):.2f} %)"
    )
    p = linear.model.params
    design = design_gains(p, true.limits, sample_rate_hz=1000, speed_bandwidth_hz=5)
    pr = design.promised
    print(
        f"gains at 1 kHz, 5 Hz speed / {design.current_crossover_hz:.3g} Hz current crossover, "
        f"60 deg: promised {pr.step_rad_s:.3g} rad/s step overshoot {pr.overshoot_pct:.1f} % "
        f"(<= {pr.overshoot_pct + TOLERANCES['overshoot_pp']:.1f}), "
        f"settling {pr.settling_s:.3f} s "
        f"(<= {pr.settling_s * TOLERANCES['settling_factor']:.3f})"
    )
    for c in check_gains(design, linear, [true]):
        m = c.measured
        print(
            f"  on {c.plant}: overshoot {m.overshoot_pct:.1f} %, settling {m.settling_s:.3f} s: "
            f"{'within the promise' if c.ok else 'NOT within the promise'}"
        )


if __name__ == "__main__":
    main()
