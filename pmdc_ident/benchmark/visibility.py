"""How visible an effect is in a run, before and after a linear model absorbs it.

``raw``: RMS difference of the noise-free logged signals with and without the
effect (same plan, same sensors), in units of each signal's noise. ``residual``:
the same after the best linear motor (R, L, Ke = Kt, J, B refitted by least
squares on the noise-free signals with this module's own plant, from several
starts of L) has absorbed what it can, i.e. the part of the effect no linear
model explains. A run whose residual visibility is below one noise RMS gives any
method's linear baseline a gap within the noise: ``no_gap`` is then an honest
answer.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.optimize import least_squares

from pmdc_ident.benchmark import plant as pl
from pmdc_ident.benchmark.sensors import SensorSetup, offset_at

__all__ = ["Visibility", "linear_signals", "noise_sigmas", "visibility", "visibility_of"]

FloatArray = NDArray[np.float64]
_LIN = (pl.P_R, pl.P_L, pl.P_KE, pl.P_J, pl.P_B)
L_STARTS = (1.0, 0.3, 3.0, 10.0)  # starts of the refit's L, x the true L


@pl.jit
def _zoh_run(cmd: FloatArray, ad: FloatArray, bd: FloatArray, ao: FloatArray, out: FloatArray):  # type: ignore[no-untyped-def]
    x = np.zeros(ad.shape[0])
    y = np.zeros(ad.shape[0])
    for k in range(cmd.size):
        out[k, :] = x
        v = cmd[k]
        if math.isnan(v):
            x[0] = 0.0
            y[:] = ao @ x
            y[0] = 0.0
        else:
            y[:] = ad @ x + bd * v
        x[:] = y


def linear_signals(
    command_v: FloatArray, dt: float, p: FloatArray, s: SensorSetup
) -> tuple[FloatArray, FloatArray]:
    """Logged current and speed of the linear motor behind the case's sensor filters,
    by the exact zero-order-hold solution (states i, w, two current stages, one speed)."""
    r, ind, ke, kt, j, b = (p[k] for k in (pl.P_R, pl.P_L, pl.P_KE, pl.P_KT, pl.P_J, pl.P_B))
    ai, aw = 2 * math.pi * s.current_fc_hz, 2 * math.pi * s.speed_fc_hz
    a = np.zeros((6, 6))
    a[0, :2] = -r / ind, -ke / ind
    a[1, :2] = kt / j, -b / j
    a[2, 0], a[2, 2] = ai, -ai
    a[3, 2], a[3, 3] = ai, -ai
    a[4, 1], a[4, 4] = aw, -aw
    a[0, 5] = 1.0 / ind  # input column
    m = expm(a * dt)
    ad, bd = np.ascontiguousarray(m[:5, :5]), np.ascontiguousarray(m[:5, 5])
    a_open = a.copy()
    a_open[0, :] = 0.0
    ao = np.ascontiguousarray(expm(a_open * dt)[:5, :5])
    out = np.zeros((command_v.size, 5))
    _zoh_run(np.ascontiguousarray(command_v, dtype=np.float64), ad, bd, ao, out)
    i = out[:, 0] if ai == 0 else (out[:, 3] if s.current_order == 2 else out[:, 2])
    w = out[:, 1] if aw == 0 else out[:, 4]
    return i, w


@dataclass(frozen=True)
class Visibility:
    raw: float
    residual: float


def _signals(sim: pl.SimOutput, s: SensorSetup) -> tuple[FloatArray, FloatArray]:
    i = sim.current_filtered if s.current_fc_hz > 0 else sim.current
    w = sim.speed_filtered if s.speed_fc_hz > 0 else sim.speed
    return i + offset_at(sim.t, s), w


def noise_sigmas(s: SensorSetup, rate_hz: float) -> tuple[float, float]:
    sig_i = math.hypot(s.current_noise_a, s.current_lsb_a / math.sqrt(12.0))
    if s.speed_source == "tacho":
        return sig_i, max(s.speed_noise_rad_s, 1e-12)
    # difference quotient of a counted angle: quantisation noise of two counts
    return sig_i, 2 * math.pi / s.counts_per_rev * rate_hz / math.sqrt(6.0)


def visibility(
    command_v: FloatArray,
    rate_hz: float,
    p_effect: FloatArray,
    p_clean: FloatArray,
    sensors: SensorSetup,
    *,
    max_nfev: int = 200,
) -> Visibility:
    dt = 1.0 / rate_hz
    clean_sensors = SensorSetup(**{**sensors.__dict__, "offset_a": 0.0, "offset_end_a": 0.0})
    ref = _signals(pl.simulate_plant(command_v, dt, p_effect), sensors)
    clean = _signals(pl.simulate_plant(command_v, dt, p_clean), clean_sensors)
    return visibility_of(command_v, rate_hz, ref, clean, p_clean, sensors, max_nfev=max_nfev)


def visibility_of(
    command_v: FloatArray,
    rate_hz: float,
    ref: tuple[FloatArray, FloatArray],
    clean: tuple[FloatArray, FloatArray],
    p_clean: FloatArray,
    sensors: SensorSetup,
    *,
    max_nfev: int = 200,
) -> Visibility:
    """Visibility of the noise-free logged signals ``ref`` (current with its offset,
    speed, behind the sensors' filters) against ``clean``, the same run without the
    effect, made by any plant (the generator's, MuJoCo's)."""
    dt = 1.0 / rate_hz
    sig_i, sig_w = noise_sigmas(sensors, rate_hz)
    i_ref, w_ref = ref
    clean_sensors = SensorSetup(**{**sensors.__dict__, "offset_a": 0.0, "offset_end_a": 0.0})
    if p_clean[pl.P_ORD_W] == 2.0:
        msg = "the visibility fit models a first-order speed filter only"
        raise ValueError(msg)

    def resid(x: FloatArray) -> FloatArray:
        p = p_clean.copy()
        for k, idx in enumerate(_LIN):
            p[idx] = math.exp(x[k])
        p[pl.P_KT] = p[pl.P_KE]
        i, w = linear_signals(command_v, dt, p, clean_sensors)
        return np.concatenate([(i - i_ref) / sig_i, (w - w_ref) / sig_w])

    x0 = np.log([max(p_clean[k], 1e-12) for k in _LIN])
    n = i_ref.size
    ci, cw = clean
    r0 = np.concatenate([(ci - i_ref) / sig_i, (cw - w_ref) / sig_w])

    def rms_max(r: FloatArray) -> float:
        return max(float(np.sqrt(np.mean(r[:n] ** 2))), float(np.sqrt(np.mean(r[n:] ** 2))))

    raw = rms_max(r0)
    if raw < 1e-9:
        return Visibility(raw, raw)
    res = raw
    for l_factor in L_STARTS:
        # a lag or a filter is absorbed by a different L (a least-squares fit started
        # at the true L stops in a local optimum: delays of visibility 20 that any
        # linear fit with 3x the L predicts to the noise), so L starts in four places
        x = x0.copy()
        x[1] += math.log(l_factor)
        try:
            fit = least_squares(resid, x, x_scale=1.0, diff_step=1e-4, max_nfev=max_nfev)
        except (ValueError, FloatingPointError):
            continue
        res = min(rms_max(fit.fun), res)
    return Visibility(raw, res)
