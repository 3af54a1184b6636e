"""Non-parametric frequency response from the sweep, with coherence.

Welch estimates (H1 = S_yv / S_vv) of I/V and w/V over the sweep segment,
with the magnitude-squared coherence that says where they can be trusted. The
parametric model's response (exact ZOH, so it is comparable up to Nyquist) is
evaluated on the same frequencies as a cross-check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import signal

from pmdc_ident.core.data import Segment
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.model import discretize_zoh
from pmdc_ident.core.params import MotorParams

__all__ = ["FrequencyResponse", "estimate_frequency_response", "model_frequency_response"]

FloatArray = NDArray[np.float64]
ComplexArray = NDArray[np.complex128]
COHERENCE_OK = 0.9


@dataclass(frozen=True)
class FrequencyResponse:
    freq_hz: FloatArray
    current_per_voltage: ComplexArray | None  # A/V
    speed_per_voltage: ComplexArray  # (rad/s)/V
    coherence_current: FloatArray | None
    coherence_speed: FloatArray
    dt_s: float
    label: str

    def mismatch_db(self, params: MotorParams) -> dict[str, float]:
        """Median |20 log10(H_model / H_data)| where the coherence is >= 0.9."""
        model = model_frequency_response(params, self.freq_hz, self.dt_s)
        out: dict[str, float] = {}
        pairs = (
            ("current_per_voltage", self.current_per_voltage, self.coherence_current),
            ("speed_per_voltage", self.speed_per_voltage, self.coherence_speed),
        )
        for key, data, coh in pairs:
            if data is None or coh is None:
                continue
            ok = (coh >= COHERENCE_OK) & (np.abs(data) > 0)
            if ok.sum() == 0:
                continue
            ratio = np.abs(model[key][ok]) / np.abs(data[ok])
            out[key] = float(np.median(np.abs(20 * np.log10(ratio))))
        return out


def estimate_frequency_response(seg: Segment, nperseg: int | None = None) -> FrequencyResponse:
    """Welch H1 estimate of I/V and w/V on one (sweep) segment."""
    if seg.voltage is None or np.isnan(seg.voltage).any():
        msg = f"segment {seg.label!r}: the frequency response needs a closed-armature voltage"
        raise DataError(msg)
    if seg.n < 64:
        msg = f"segment {seg.label!r}: too short for a frequency response ({seg.n} samples)"
        raise DataError(msg)
    fs = 1.0 / seg.dt_s
    n = nperseg or max(64, 2 ** int(math.log2(seg.n / 4)))
    v = seg.voltage
    w = seg.speed_or_derivative()
    kw = {"fs": fs, "nperseg": n, "detrend": "constant"}
    f, pvv = signal.welch(v, **kw)
    _, pvw = signal.csd(v, w, **kw)
    _, cw = signal.coherence(v, w, **kw)
    hi = hc = None
    if seg.current is not None:
        _, pvi = signal.csd(v, seg.current, **kw)
        _, hc = signal.coherence(v, seg.current, **kw)
        hi = pvi / np.where(pvv > 0, pvv, np.inf)
    keep = (f > 0) & (pvv > 1e-12 * pvv.max())
    hw = pvw / np.where(pvv > 0, pvv, np.inf)
    return FrequencyResponse(
        freq_hz=f[keep],
        current_per_voltage=None if hi is None else hi[keep],
        speed_per_voltage=hw[keep],
        coherence_current=None if hc is None else hc[keep],
        coherence_speed=cw[keep],
        dt_s=seg.dt_s,
        label=seg.label,
    )


def model_frequency_response(
    params: MotorParams, freq_hz: FloatArray, dt_s: float | None = None
) -> dict[str, ComplexArray]:
    """I/V and w/V of the linear model: sampled (ZOH) when ``dt_s`` is given, else continuous."""
    f = np.asarray(freq_hz, dtype=float)
    out_i = np.empty(f.size, dtype=complex)
    out_w = np.empty(f.size, dtype=complex)
    if dt_s is None:
        s = 2j * np.pi * f
        p = params
        den = p.L * p.J * s**2 + (p.R * p.J + p.L * p.B) * s + (p.R * p.B + p.Ke * p.Kt)
        return {
            "current_per_voltage": (p.J * s + p.B) / den,
            "speed_per_voltage": p.Kt / den + 0j,
        }
    phi, gam = discretize_zoh(params, dt_s)
    phi2, g2 = phi[:2, :2], gam[:2, 0]
    for k, fk in enumerate(f):
        z = np.exp(2j * np.pi * fk * dt_s)
        x = np.linalg.solve(z * np.eye(2) - phi2, g2)
        out_i[k], out_w[k] = x[0], x[1]
    return {"current_per_voltage": out_i, "speed_per_voltage": out_w}
