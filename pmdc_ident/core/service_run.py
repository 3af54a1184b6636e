"""A motor in normal service (no test sequence): speed set-points on a random walk.

What a drift monitor sees on a robot: a speed controller (the cascade of
:mod:`pmdc_ident.core.control_design`) follows set-points that wander, hold and
reverse, sampled at the driver's rate with the sensors' noise and quantisation.
Used by the monitor's tests and ``benchmarks/bench_monitor.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.control_design import CascadeController, GainDesign
from pmdc_ident.core.model import Plant
from pmdc_ident.core.motors import MotorSpec

__all__ = ["ServiceRun", "random_walk_setpoints", "simulate_service"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class ServiceRun:
    """Sampled signals of a run in service (SI), and the true R over time."""

    t: FloatArray
    voltage: FloatArray  # applied command, V
    current: FloatArray  # measured, A
    speed: FloatArray  # measured, rad/s
    setpoint: FloatArray
    true_resistance_ohm: FloatArray


def random_walk_setpoints(
    n: int, dt_s: float, speed_max_rad_s: float, rng: np.random.Generator, hold_s: float = 2.0
) -> FloatArray:
    """Set-points held for random times (mean ``hold_s``), each a random step from the
    last, within +-70 % of the speed limit; now and then a stop."""
    out = np.empty(n)
    k, value = 0, 0.0
    top = 0.7 * speed_max_rad_s
    while k < n:
        hold = max(1, int(rng.exponential(hold_s) / dt_s))
        out[k : k + hold] = value
        k += hold
        value = (
            0.0
            if rng.random() < 0.1
            else float(np.clip(value + rng.normal(0, 0.3 * top), -top, top))
        )
    return out


def simulate_service(
    spec: MotorSpec,
    design: GainDesign,
    duration_s: float,
    *,
    seed: int = 0,
    setpoints: FloatArray | None = None,
) -> ServiceRun:
    """Run ``spec``'s model (with its effects) under the cascade at the design's rate."""
    dt = design.sample_period_s
    n = int(round(duration_s / dt))
    rng = np.random.default_rng(seed)
    sp = (
        setpoints
        if setpoints is not None
        else random_walk_setpoints(n, dt, spec.limits.speed_max_rad_s, rng)
    )
    # A reference ramp-limited to what the current limit can accelerate comfortably.
    p = spec.model.params
    ramp = 0.3 * p.Kt * spec.limits.current_max_a / p.J * dt
    plant = Plant(spec.model, dt)
    ctrl = CascadeController(design)
    s = spec.sensors
    t = np.arange(n) * dt
    v_out, i_out, w_out, r_out = (np.empty(n) for _ in range(4))
    ref, v_next = 0.0, 0.0
    noise_i = rng.normal(0.0, s.current_noise_a, n) if s.current_noise_a else np.zeros(n)
    noise_w = rng.normal(0.0, s.speed_noise_rad_s, n) if s.speed_noise_rad_s else np.zeros(n)
    for k in range(n):
        # as the simulated driver reads them: true value + Gaussian noise
        i_meas = plant.current_a + noise_i[k]
        w_meas = plant.speed_rad_s + noise_w[k]
        ref += float(np.clip(sp[k] - ref, -ramp, ramp))
        v = ctrl.update(ref, w_meas, i_meas)
        i_out[k], w_out[k], v_out[k] = i_meas, w_meas, v_next
        r_out[k] = plant.resistance_ohm  # the winding as the plant heats (and cools) it
        plant.step(v_next)
        v_next = v
    return ServiceRun(t, v_out, i_out, w_out, sp, r_out)
