"""A brushed DC motor simulated by MuJoCo's own ``<dcmotor>`` actuator (MuJoCo >= 4).

Equations and an integrator nobody in this project wrote: MuJoCo's DC motor holds
the armature current as its activation state (``L di/dt = v - R i - K w``), the
joint carries the rotor inertia (``armature``), viscous damping and, optionally, a
Coulomb ``frictionloss``. The command is held over each sample period (the
zero-order hold of a drive) and the state is read at each sample's start.

A benchmark/test dependency only: ``mujoco`` is imported inside :func:`simulate`,
and nothing in identify, diagnose or the nodes imports this module. Issue 23 grows
it into a benchmark plant.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["DcMotor", "mjcf", "simulate"]

FloatArray = NDArray[np.float64]

_XML = """<mujoco model="pmdc">
  <option timestep="{timestep}" gravity="0 0 0" integrator="{integrator}">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="rotor">
      <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>
      <joint name="shaft" type="hinge" axis="0 0 1" armature="{J}" damping="{B}"
             frictionloss="{frictionloss}" solreffriction="{solref} 1"/>
    </body>
  </worldbody>
  <actuator>
    <dcmotor name="motor" joint="shaft" resistance="{R}" motorconst="{K} {K}"
             inductance="{L} 0"/>
  </actuator>
</mujoco>"""


@dataclass(frozen=True)
class DcMotor:
    """MuJoCo's DC motor: one constant ``K`` (= Kt = Ke in SI units), winding ``R`` and
    ``L``, rotor inertia ``J``, viscous ``B``, Coulomb friction ``frictionloss`` (N*m)."""

    R: float
    L: float
    K: float
    J: float
    B: float
    frictionloss: float = 0.0


def mjcf(motor: DcMotor, timestep_s: float, integrator: str = "Euler") -> str:
    """The MJCF of ``motor`` (a friction constraint stiff at 0.5 ms, so a Coulomb torque
    is not smeared over MuJoCo's default 20 ms)."""
    return _XML.format(
        timestep=f"{timestep_s:.10g}",
        integrator=integrator,
        solref="0.0005",
        J=f"{motor.J:.10g}",
        B=f"{motor.B:.10g}",
        frictionloss=f"{motor.frictionloss:.10g}",
        R=f"{motor.R:.10g}",
        K=f"{motor.K:.10g}",
        L=f"{motor.L:.10g}",
    )


def simulate(
    motor: DcMotor,
    voltage: FloatArray,
    dt_s: float,
    *,
    substeps: int = 200,
    x0: tuple[float, float, float] = (0.0, 0.0, 0.0),
    integrator: str = "Euler",
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Current, speed and angle at each sample of ``voltage`` (V, held over each of its
    samples; MuJoCo cannot open the circuit, so NaN is refused), from ``x0`` = (i, w,
    theta). ``substeps`` MuJoCo steps per sample period.

    The integrator matters for the current: with ``Euler`` MuJoCo's dcmotor follows the
    exact zero-order-hold solution to 1e-5 A at 100 steps per sample (a small motor,
    L/R 0.5 ms, 1 kHz), while ``RK4`` lags it by about half a step (L read 4.5 % high at
    20 steps per sample, still 1.7 % of the current's first step at 100); the speed's
    error is first order in the step either way (0.14 rad/s of 300 at 100 steps)."""
    import mujoco

    v = np.asarray(voltage, dtype=float)
    if not np.isfinite(v).all():
        msg = "MuJoCo's dcmotor cannot open its armature: the voltage must be finite"
        raise ValueError(msg)
    model = mujoco.MjModel.from_xml_string(mjcf(motor, dt_s / substeps, integrator))
    data = mujoco.MjData(model)
    data.act[0], data.qvel[0], data.qpos[0] = x0
    n = v.size
    cur, spd, pos = np.empty(n), np.empty(n), np.empty(n)
    for k in range(n):
        cur[k], spd[k], pos[k] = data.act[0], data.qvel[0], data.qpos[0]
        data.ctrl[0] = v[k]
        mujoco.mj_step(model, data, substeps)
    return cur, spd, pos
