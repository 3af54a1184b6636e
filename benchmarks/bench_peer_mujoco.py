"""A peer side by side: MuJoCo's identifier (``mujoco.sysid``, ``dcmotor``) against ours.

    .venv/bin/python benchmarks/bench_peer_mujoco.py [--motors a,b,c] [--duration-s 60]

MuJoCo is an optional benchmark dependency, never a runtime one: it is in
``requirements-dev.txt`` (``make venv`` installs it) or ``pip install
"mujoco[sysid]==4.0.0"``. Both identifiers get, in one process, the same
simulated runs at 1 kHz (50 s of the default sequence: staircase, steps both ways, log
chirp; the coast-down's open armature is left out because MuJoCo's voltage-driven
``dcmotor`` cannot open its circuit) of three motors: the seed-001 110 V motor
(linear), the seed-000 e-bike motor (with its Coulomb friction) and a small 12 V
motor.

MuJoCo is given its best settings, found by simulating the true motor against
our exact model before fitting (``--check-settings`` prints that comparison):

* a 0.1 ms time step (a tenth of the sample period), the Euler integrator;
* the voltage held over each sample period (zero-order hold, as the driver does),
  not interpolated; the measured current and speed as each segment's initial state;
* joint ``frictionloss`` for Coulomb friction, made stiff (``solreffriction`` 0.5 ms
  instead of the default 20 ms, which smears friction over tens of ms);
* a maximum-likelihood residual (current and speed errors divided by their noise
  standard deviations, the weights ours uses), through sysid's
  ``modify_residual`` hook;
* a start close to the truth (R +10 %, L -10 %, K +5 %, J -10 %, B and friction
  +20 %), box bounds a factor 5 either side, ``x_scale`` = the start, MuJoCo's own
  Levenberg-Marquardt (``optimizer="mujoco"``), threads on both cores.

Ours is the whole ``identify()`` pipeline (classical chain, equation error, output
error with the Coulomb model selected when significant, held-out validation)
from the same in-memory run, with no start given. Errors are against the truth
under the closure both models share (one constant K = Kt = Ke, so J, B and the
friction torque are reported scaled by Ke/Kt).

Each identifier fits every motor twice: the noisy run (timed: wall and CPU time
of all threads, and the ratio; the errors a user sees, with ours' standard error
for scale) and the same run without sensor noise, whose error is each method's
bias. Both are weighted least-squares fits of the same samples with the same
weights, so their scatter from noise is the same and the bias decides which is
the more accurate: ours must be no more biased on any parameter.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pmdc_ident._blas import limit_blas_threads  # noqa: E402

limit_blas_threads()  # both sides: one BLAS thread (MuJoCo's rollout threads are its own)

import numpy as np  # noqa: E402

from pmdc_ident.core.data import Segment  # noqa: E402
from pmdc_ident.core.effects import CoulombFriction  # noqa: E402
from pmdc_ident.core.excitation import (  # noqa: E402
    SequenceConfig,
    TestPlan,
    plan_for_motor,
    synthesize_run,
)
from pmdc_ident.core.identification.identify import identify  # noqa: E402
from pmdc_ident.core.model import Model, simulate  # noqa: E402
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec, load_motor  # noqa: E402
from pmdc_ident.core.params import MotorParams  # noqa: E402

try:
    import mujoco
    from mujoco import sysid
except ImportError:  # pragma: no cover - depends on the environment
    mujoco = None
    sysid = None

INSTALL_HINT = (
    "bench_peer_mujoco: MuJoCo's identifier is not installed; it is an optional benchmark "
    'dependency: .venv/bin/pip install "mujoco[sysid]==4.0.0" -c constraints.txt '
    "(or make venv, which installs requirements-dev.txt)"
)

DT_S = 1e-3  # the runs' sample period
DRIVEN_S = 50.0  # seconds of data per motor
SUBSTEPS = 10  # MuJoCo steps per sample period: 0.1 ms at 1 kHz
FRICTION_SOLREF_S = 5e-4  # frictionloss constraint time constant (MuJoCo default 0.02 s)
NAMES = ("R", "L", "K", "J", "B", "Tc")

XML = """<mujoco model="pmdc">
  <option timestep="{dt}" gravity="0 0 0" integrator="Euler"><flag contact="disable"/></option>
  <worldbody>
    <body name="rotor">
      <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>
      <joint name="shaft" type="hinge" axis="0 0 1" armature="{J}" damping="{B}"
             frictionloss="{Tc}" solreffriction="{solref} 1"/>
    </body>
  </worldbody>
  <actuator>
    <dcmotor name="motor" joint="shaft" resistance="{R}" motorconst="{K} {K}"
             inductance="{L} 0"/>
  </actuator>
  <sensor><jointvel name="speed" joint="shaft"/></sensor>
</mujoco>"""


def small_12v() -> MotorSpec:
    """A small 12 V hobby motor (the diagnosis benchmark's archetype), no effects."""
    return MotorSpec(
        name="small_12v",
        model=Model(MotorParams(R=2.0, L=1.0e-3, Ke=0.012, Kt=0.012, J=4.0e-6, B=2.0e-7)),
        sensors=SensorSpec(current_noise_a=0.005, speed_noise_rad_s=0.05),
        limits=Limits(voltage_max_v=12.0, current_max_a=10.0, speed_max_rad_s=1500.0),
    )


def motor(name: str) -> MotorSpec:
    return small_12v() if name == "small_12v" else load_motor(name)


def driven_plan(spec: MotorSpec) -> TestPlan:
    """The default sequence without the coast-down, its holds and sweep scaled to DRIVEN_S."""
    base = plan_for_motor(spec, DT_S, SequenceConfig(coast=False))
    k = DRIVEN_S / base.duration_s
    cfg = SequenceConfig(
        coast=False, staircase_hold_tau=6.0 * k, step_hold_tau=6.0 * k, sweep_duration_tau=40.0 * k
    )
    return plan_for_motor(spec, DT_S, cfg)


def truth(spec: MotorSpec) -> dict[str, float]:
    """The parameters under the closure K = Kt = Ke (J, B, friction scaled by Ke/Kt)."""
    p = spec.model.params
    s = p.Ke / p.Kt
    tc = sum(e.torque_nm for e in spec.model.effects if isinstance(e, CoulombFriction))
    out = {"R": p.R, "L": p.L, "K": p.Ke, "J": p.J * s, "B": p.B * s}
    if tc:
        out["Tc"] = tc * s
    return out


def mjcf(values: dict[str, float], dt_s: float) -> str:
    v = {"Tc": 0.0, **values}
    return XML.format(dt=dt_s / SUBSTEPS, solref=FRICTION_SOLREF_S, **v)


# ---------------------------------------------------------------------------
# MuJoCo
# ---------------------------------------------------------------------------
@dataclass
class _Measured:
    current: np.ndarray
    speed: np.ndarray


def _build(params, spec):  # type: ignore[no-untyped-def]
    """sysid BuildModelFn: the candidate parameters into the dcmotor and the joint."""
    v = {n: float(params[n].value[0]) for n in NAMES if n in params}
    act = spec.actuator("motor")
    act.set_to_dcmotor(motorconst=[v["K"], v["K"]], resistance=v["R"], inductance=[v["L"], 0.0])
    joint = spec.joint("shaft")
    joint.armature = v["J"]
    joint.damping = [v["B"], 0.0, 0.0]  # damping polynomial: the linear term only
    joint.frictionloss = v.get("Tc", 0.0)
    return spec.compile()


def fit_mujoco(
    segments: list[Segment], start: dict[str, float], noise: tuple[float, float]
) -> tuple[dict[str, float], int]:
    """mujoco.sysid on every segment (one trajectory each); returns values and iterations."""
    dt = segments[0].dt_s
    spec = mujoco.MjSpec.from_string(mjcf(start, dt))
    model0 = spec.compile()
    act_col = 1 + model0.nq + model0.nv + int(model0.actuator_actadr[0])  # state: time first
    sigma_i, sigma_w = noise
    measured: dict[int, _Measured] = {}

    def modify_residual(params, pred, meas, model, return_pred_all, state=None, **_):  # type: ignore[no-untyped-def]
        m = measured[id(meas)]
        # state row j is the state after fine step j: sample k >= 1 is row k*SUBSTEPS - 1
        rows = np.arange(1, m.speed.size) * SUBSTEPS - 1
        r_i = (m.current[1:] - state[rows, act_col]) / sigma_i
        r_w = (m.speed[1:] - pred.data[rows, 0]) / sigma_w
        return np.concatenate([r_i, r_w]), pred, meas

    groups = []
    for k, seg in enumerate(segments):
        # voltage held over each sample period; sysid rolls out one step fewer than the
        # control samples it gets, hence the one extra (unused) sample at the end
        n_fine = (seg.n - 1) * SUBSTEPS + 1
        t_fine = seg.t[0] + np.arange(n_fine) * (dt / SUBSTEPS)
        control = sysid.TimeSeries(t_fine, np.repeat(seg.voltage, SUBSTEPS)[:n_fine, None])
        meas = sysid.TimeSeries.from_names(seg.t, seg.speed[:, None], model0, names=["speed"])
        measured[id(meas)] = _Measured(seg.current, seg.speed)
        x0 = sysid.create_initial_state(
            model0, np.zeros(model0.nq), np.array([seg.speed[0]]), np.array([seg.current[0]])
        )
        groups.append(sysid.ModelSequences(f"seg{k}", spec, seg.label, x0, control, meas))

    params = sysid.ParameterDict()
    for name, value in start.items():
        params.add(sysid.Parameter(name, nominal=value, min_value=value / 5, max_value=value * 5))
    residual_fn = sysid.build_residual_fn(
        models_sequences=groups,
        build_model=_build,
        modify_residual=modify_residual,
        resample_true=False,
    )
    x_scale = np.array([start[n] for n in start])
    opt, res = sysid.optimize(
        initial_params=params,
        residual_fn=residual_fn,
        optimizer="mujoco",
        verbose=False,
        x_scale=x_scale,
    )
    iterations = max(len(res.extras.get("objective", [])) - 1, 0)  # the log holds the start too
    return {n: float(opt[n].value[0]) for n in start}, iterations


# ---------------------------------------------------------------------------
# The comparison
# ---------------------------------------------------------------------------
def _timed(fn):  # type: ignore[no-untyped-def]
    t0, c0 = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - t0, time.process_time() - c0


def ours_values(res) -> dict[str, float]:  # type: ignore[no-untyped-def]
    by_name = {k: e.value for k, e in res.parameters.items()}
    out = {"R": by_name["R"], "L": by_name["L"], "K": by_name["Ke"]}
    out["J"], out["B"] = by_name["J"], by_name["B"]
    tc = by_name.get("coulomb_friction.torque_nm")
    if tc is not None:
        out["Tc"] = tc
    return out


def check_settings(spec: MotorSpec, segments: list[Segment]) -> None:
    """RMS of MuJoCo's simulation of the true motor against our exact model, per signal."""
    tr = truth(spec)
    m = mujoco.MjModel.from_xml_string(mjcf(tr, segments[0].dt_s))
    d = mujoco.MjData(m)
    closure = Model(
        MotorParams(R=tr["R"], L=tr["L"], Ke=tr["K"], Kt=tr["K"], J=tr["J"], B=tr["B"]),
        (CoulombFriction(tr["Tc"]),) if "Tc" in tr else (),
    )
    seg = max(segments, key=lambda s: s.n)
    ref = simulate(closure, seg.voltage, seg.dt_s, x0=(seg.current[0], seg.speed[0], 0.0))
    mujoco.mj_resetData(m, d)
    d.qvel[0], d.act[0] = seg.speed[0], seg.current[0]
    cur, spd = np.empty(seg.n), np.empty(seg.n)
    for k in range(seg.n):
        cur[k], spd[k] = d.act[0], d.qvel[0]
        d.ctrl[0] = seg.voltage[k]
        mujoco.mj_step(m, d, SUBSTEPS)
    ei = np.sqrt(np.mean((cur - ref.current) ** 2)) / np.std(ref.current)
    ew = np.sqrt(np.mean((spd - ref.speed) ** 2)) / np.std(ref.speed)
    print(f"  settings check on {seg.label}: MuJoCo vs exact model RMS/std i {ei:.1e}, w {ew:.1e}")


def _errors(values: dict[str, float], tr: dict[str, float]) -> dict[str, float]:
    return {k: values.get(k, math.nan) / v - 1 for k, v in tr.items()}


def compare(name: str, check: bool) -> tuple[float, float, bool]:
    """Both identifiers on the noisy run (timed) and on the same run without noise (bias)."""
    spec = motor(name)
    plan = driven_plan(spec)
    run = synthesize_run(spec.model, plan, spec.sensors, seed=1)
    segments = list(run.segments)
    quiet = replace(spec.sensors, current_noise_a=0.0, speed_noise_rad_s=0.0)
    clean = list(synthesize_run(spec.model, plan, quiet, seed=1).segments)
    tr = truth(spec)
    noise = (spec.sensors.current_noise_a, spec.sensors.speed_noise_rad_s)
    n = sum(s.n for s in segments)
    print(
        f"== {name}: {len(segments)} driven segments, {n * DT_S:.1f} s at {1 / DT_S:.0f} Hz "
        f"({', '.join(sorted({s.label.rstrip('_0123456789') for s in segments}))})"
    )
    if check:
        check_settings(spec, segments)
    factors = dict(zip(NAMES, (1.1, 0.9, 1.05, 0.9, 1.2, 1.2), strict=True))
    start = {k: v * factors[k] for k, v in tr.items()}
    res, w_ours, c_ours = _timed(lambda: identify(segments, sources=(name,)))
    (mj, iters), w_mj, c_mj = _timed(lambda: fit_mujoco(segments, start, noise))
    ours_clean = ours_values(identify(clean, sources=(name,)))
    mj_clean, _ = fit_mujoco(clean, start, noise)
    e_ours, e_mj = _errors(ours_values(res), tr), _errors(mj, tr)
    b_ours, b_mj = _errors(ours_clean, tr), _errors(mj_clean, tr)
    sigma = {k: _stderr(res, k) / tr[k] for k in tr}
    print(
        f"  {'':4} {'truth':>11} | noisy run: {'ours':>9} {'MuJoCo':>9} {'ours 1 sd':>9} | "
        f"bias (noise-free): {'ours':>9} {'MuJoCo':>9}"
    )
    as_good = True
    for k, v in tr.items():
        as_good &= abs(b_ours[k]) <= abs(b_mj[k])
        print(
            f"  {k:4} {v:11.5g} | {'':11}{e_ours[k]:+9.4%} {e_mj[k]:+9.4%} {_pct(sigma[k]):>9} | "
            f"{'':19}{b_ours[k]:+9.1e} {b_mj[k]:+9.1e}"
        )
    print(
        f"  time (noisy run): ours {w_ours:.2f} s wall {c_ours:.2f} s CPU | MuJoCo {w_mj:.2f} s "
        f"wall {c_mj:.2f} s CPU ({iters} iterations) | ours faster x{w_mj / w_ours:.1f} wall, "
        f"x{c_mj / c_ours:.1f} CPU; bias no larger than MuJoCo's on every parameter: {as_good}"
    )
    return w_mj / w_ours, c_mj / c_ours, as_good


def _pct(x: float) -> str:
    return f"{x:.4%}" if math.isfinite(x) else "flagged"  # ours reports no interval


def _stderr(res, name: str) -> float:  # type: ignore[no-untyped-def]
    """Ours' standard error of a parameter (closure names), NaN when it reports none."""
    key = {"K": "Ke", "Tc": "coulomb_friction.torque_nm"}.get(name, name)
    est = res.parameters.get(key)
    return math.nan if est is None or est.stderr is None else float(est.stderr)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--motors", default="seed001_110v,seed000_ebike,small_12v")
    ap.add_argument("--check-settings", action="store_true", help="print MuJoCo's sim error")
    args = ap.parse_args(argv)
    if mujoco is None or not hasattr(sysid, "optimize"):
        print(INSTALL_HINT, file=sys.stderr)
        return 2
    load = os.getloadavg()[0]
    print(f"mujoco {mujoco.__version__}; load average {load:.2f}, {os.cpu_count()} CPUs")
    # warm-up: compile our kernels so that neither side pays a one-off cost
    spec = load_motor("seed001_110v")
    warm = synthesize_run(spec.model, plan_for_motor(spec, DT_S), spec.sensors, seed=0)
    identify(warm.segments[:3], sources=("warm-up",))
    ratios = [compare(name, args.check_settings) for name in args.motors.split(",")]
    print(
        f"== over {len(ratios)} motors: ours faster x{min(r[0] for r in ratios):.1f} or more "
        f"(wall), x{min(r[1] for r in ratios):.1f} or more (CPU); bias no larger than "
        f"MuJoCo's on every parameter of every motor: {all(r[2] for r in ratios)}"
    )
    print(f"load average after {os.getloadavg()[0]:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
