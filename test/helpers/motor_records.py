"""Recordings of a DC motor made without the project's simulator (for the gate's tests).

An explicit RK4 integration of ``L di/dt = V - R i - Ke w`` and
``J dw/dt = Kt i - B w - Tc sign(w) - T_load`` with many sub-steps per sample
(the voltage held over each sample, an empty cell = armature open: i = 0), so
the tests do not only check the package's model against itself. Written to CSV
with any headers and unit factors a logger might use.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class Motor:
    R: float = 2.0
    L: float = 2e-3
    Ke: float = 0.05
    Kt: float = 0.05
    J: float = 2e-5
    B: float = 2e-6
    Tc: float = 0.0
    T_load: float = 0.0
    mu: float = 0.0  # friction mu |Kt i| against the motion (a gearbox's mesh losses)


@dataclass
class Record:
    t: np.ndarray
    voltage: np.ndarray
    current: np.ndarray
    speed: np.ndarray
    position: np.ndarray
    labels: list[str] = field(default_factory=list)

    def columns(self) -> dict[str, np.ndarray]:
        return {
            "t": self.t,
            "voltage": self.voltage,
            "current": self.current,
            "position": self.position,
            "speed": self.speed,
        }


def _deriv(m: Motor, v: float, i: float, w: float, is_open: bool) -> tuple[float, float]:
    di = 0.0 if is_open else (v - m.R * i - m.Ke * w) / m.L
    drive = (0.0 if is_open else m.Kt * i) - m.T_load
    # what friction can hold at rest, and its size while turning
    level = m.Tc + (m.mu * abs(m.Kt * i) if m.mu and not is_open else 0.0)
    if abs(w) > 1e-9:
        fric = level * math.copysign(1.0, w)
    else:
        fric = math.copysign(min(abs(drive), level), drive) if level else 0.0
    return di, (drive - m.B * w - fric) / m.J


def simulate(
    m: Motor,
    voltage: np.ndarray,
    rate_hz: float,
    *,
    substeps: int = 20,
    noise_current: float = 0.0,
    noise_speed: float = 0.0,
    counts_per_rev: int | None = None,
    seed: int = 0,
    labels: list[str] | None = None,
    controller=None,  # (k, speed measured at k) -> voltage over [k, k+1): closed loop
) -> Record:
    """RK4 over ``voltage`` (NaN = open armature) from rest; measured signals with noise.

    With ``controller``, ``voltage`` only sets the length: each sample's voltage is
    ``controller(k, measured speed)`` (noise included, as a real loop sees it).
    """
    dt = 1.0 / rate_hz
    h = dt / substeps
    n = voltage.size
    i_out, w_out, th_out = np.empty(n), np.empty(n), np.empty(n)
    i = w = th = 0.0
    voltage = np.array(voltage, dtype=float)
    rng = np.random.default_rng(seed)  # current noise drawn first, then speed noise
    cur_noise = rng.normal(0.0, noise_current, n) if noise_current else np.zeros(n)
    spd_noise = rng.normal(0.0, noise_speed, n) if noise_speed else np.zeros(n)
    for k in range(n):
        i_out[k], w_out[k], th_out[k] = i, w, th
        if controller is not None:
            voltage[k] = controller(k, w + spd_noise[k])
        v = float(voltage[k])
        is_open = math.isnan(v)
        if is_open:
            i = 0.0
        for _ in range(substeps):
            a1 = _deriv(m, v, i, w, is_open)
            a2 = _deriv(m, v, i + 0.5 * h * a1[0], w + 0.5 * h * a1[1], is_open)
            a3 = _deriv(m, v, i + 0.5 * h * a2[0], w + 0.5 * h * a2[1], is_open)
            a4 = _deriv(m, v, i + h * a3[0], w + h * a3[1], is_open)
            w_new = w + h / 6 * (a1[1] + 2 * a2[1] + 2 * a3[1] + a4[1])
            th += 0.5 * h * (w + w_new)
            i += h / 6 * (a1[0] + 2 * a2[0] + 2 * a3[0] + a4[0])
            if m.Tc and w != 0.0 and w * w_new < 0:
                # through zero: friction stops the rotor unless the drive breaks it away
                # (then it turns on; clamping every crossing lost up to a sub-step's motion)
                drive = (0.0 if is_open else m.Kt * i) - m.T_load
                level = m.Tc + (m.mu * abs(m.Kt * i) if m.mu and not is_open else 0.0)
                if abs(drive) <= level:
                    w_new = 0.0
            w = w_new
    cur = i_out + cur_noise
    spd = w_out + spd_noise
    if counts_per_rev:
        q = 2 * math.pi / counts_per_rev
        th_out = np.floor(th_out / q) * q
    return Record(np.arange(n) * dt, voltage.astype(float), cur, spd, th_out, labels or [])


def filtered_current(
    m: Motor,
    voltage: np.ndarray,
    rate_hz: float,
    tau_s: float,
    *,
    up: int = 20,
    noise_current: float = 0.005,
    noise_speed: float = 0.05,
    seed: int = 0,
) -> Record:
    """A record whose current sensor sits behind a first-order RC filter of ``tau_s``
    (simulated ``up`` times faster than it is sampled, filtered, then decimated)."""
    fine = simulate(m, np.repeat(voltage, up), rate_hz * up, substeps=1)
    a = math.exp(-1.0 / (tau_s * rate_hz * up))
    f = np.empty_like(fine.current)
    f[0] = fine.current[0]
    for k in range(1, f.size):
        f[k] = a * f[k - 1] + (1 - a) * fine.current[k]
    rng = np.random.default_rng(seed)
    n = voltage.size
    return Record(
        fine.t[::up],
        np.asarray(voltage, dtype=float),
        f[::up] + rng.normal(0, noise_current, n),
        fine.speed[::up] + rng.normal(0, noise_speed, n),
        fine.position[::up],
    )


def steps(levels: list[float | None], seconds_each: float, rate_hz: float) -> np.ndarray:
    """A staircase of held voltages (``None`` = armature open)."""
    n = int(round(seconds_each * rate_hz))
    return np.concatenate([np.full(n, np.nan if v is None else v) for v in levels])


def prbs(n: int, amplitude: float, hold: int, seed: int = 1) -> np.ndarray:
    """A pseudo-random binary voltage (+- amplitude, held for whole multiples of ``hold``)."""
    rng = np.random.default_rng(seed)
    bits = rng.integers(0, 2, size=n // hold + 1) * 2 - 1
    return np.repeat(bits * amplitude, hold)[:n].astype(float)


def continuous_voltage(rate_hz: int = 1000) -> np.ndarray:
    """One unlabeled log's voltage: rest, steps to 6 and 12 V, a chirp, a PRBS, a hold,
    an open-armature coast (NaN), a step to 0 V."""
    t = np.arange(3000) / rate_hz
    chirp = 6 * np.sin(2 * np.pi * (t + 0.5 * 19 / 3 * t**2))
    return np.concatenate(
        [
            np.zeros(300),
            np.full(800, 6.0),
            np.full(800, 12.0),
            chirp,
            prbs(2000, 6.0, 15, seed=2),
            np.full(800, 10.0),
            np.full(1500, np.nan),
            np.zeros(600),
        ]
    )


def speed_pi(ref: np.ndarray, rate_hz: float = 1000.0) -> Callable[[int, float], float]:
    """A PI speed controller (volts out, +-24 V) following ``ref`` (rad/s, one value per
    sample): the ``controller`` of :func:`simulate` for a closed-loop record."""
    integral = [0.0]

    def pi(k: int, w: float) -> float:
        integral[0] += (ref[k] - w) / rate_hz
        return float(np.clip(0.05 * (ref[k] - w) + 2.0 * integral[0], -24, 24))

    return pi


def write_csv(
    path: Path,
    record: Record,
    *,
    headers: dict[str, str] | None = None,
    scale: dict[str, float] | None = None,
    drop: tuple[str, ...] = (),
) -> Path:
    """The record as CSV; ``headers`` renames columns, ``scale`` multiplies them (a slip)."""
    headers = headers or {}
    scale = scale or {}
    cols = {k: v * scale.get(k, 1.0) for k, v in record.columns().items() if k not in drop}
    names = list(cols)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        row = [headers.get(k, k) for k in names]
        if record.labels:
            row.append(headers.get("segment", "segment"))
        w.writerow(row)
        for k in range(record.t.size):
            vals = ["" if math.isnan(cols[c][k]) else repr(float(cols[c][k])) for c in names]
            if record.labels:
                vals.append(record.labels[k])
            w.writerow(vals)
    return path
