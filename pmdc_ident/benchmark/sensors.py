"""Sensor models of real drivers: what ends up in the user's log.

* Current: Hall or shunt amplifier -> analog anti-alias RC filter (first order
  with its corner at 1.5-5x the sample rate, or second order at 3-10x; simulated
  inside the plant) -> white noise -> ADC quantisation (10 or 12 bits over the
  driver's range); an offset (the ``current_offset`` effect) sits before the ADC.
  The filters' group delay stays within 0.03-0.11 sample periods: a sensor that
  lags by a good part of a sample is a delay the user should be told about, so
  effect-free runs keep their sensors faster than that.
* Angle: a quadrature encoder on the motor shaft; the log holds whole counts
  (floor) at the measured shaft, ``counts_per_motor_rev x gear ratio`` per turn.
* Speed: either absent (the tool differentiates the counted angle, as with the
  project's own firmware), or a tachogenerator: analog speed with noise through a
  first-order filter at 1.5-5x the sample rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.benchmark.plant import SimOutput

__all__ = ["Measured", "SensorSetup", "measure"]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class SensorSetup:
    current_range_a: float
    current_adc_bits: int
    current_noise_a: float
    current_fc_hz: float  # analog corner (0 = none)
    current_order: int
    counts_per_rev: float
    speed_source: str  # "position" or "tacho"
    speed_noise_rad_s: float
    speed_fc_hz: float
    offset_a: float = 0.0  # current sensor offset at the start of the record
    offset_end_a: float = 0.0  # offset it drifts to (warm-up), first order
    offset_tau_s: float = 0.0  # 0: constant offset

    @property
    def current_lsb_a(self) -> float:
        return 2.0 * self.current_range_a / 2**self.current_adc_bits


@dataclass(frozen=True)
class Measured:
    current: FloatArray
    position: FloatArray
    speed: FloatArray | None


def offset_at(t: FloatArray, s: SensorSetup) -> FloatArray:
    if s.offset_tau_s <= 0.0:
        return np.full(t.shape, s.offset_a)
    return s.offset_end_a + (s.offset_a - s.offset_end_a) * np.exp(-t / s.offset_tau_s)


def measure(sim: SimOutput, s: SensorSetup, rng: np.random.Generator) -> Measured:
    """Sensor readings of one simulated record (noise drawn from ``rng``)."""
    i_analog = sim.current_filtered if s.current_fc_hz > 0 else sim.current
    i = i_analog + offset_at(sim.t, s) + rng.normal(0.0, s.current_noise_a, sim.current.size)
    lsb = s.current_lsb_a
    i = np.clip(np.round(i / lsb) * lsb, -s.current_range_a, s.current_range_a)
    step = 2.0 * math.pi / s.counts_per_rev
    pos = np.floor(sim.position / step + 1e-9) * step
    speed = None
    if s.speed_source == "tacho":
        w = sim.speed_filtered if s.speed_fc_hz > 0 else sim.speed
        speed = w + rng.normal(0.0, s.speed_noise_rad_s, w.size)
    return Measured(i, pos, speed)
