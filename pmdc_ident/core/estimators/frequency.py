"""Non-parametric frequency response from the sweep, with coherence.

Band-smoothed empirical transfer function estimates of I/V and w/V over the
sweep segment, with the coherence that says where they can be trusted. The
parametric model's response (exact ZOH, so it is comparable up to Nyquist) is
evaluated on the same frequencies as a cross-check.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

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


def estimate_frequency_response(
    seg: Segment,
    bands: int = 60,
    *,
    free_response: tuple[FloatArray, FloatArray] | None = None,
) -> FrequencyResponse:
    """Smoothed empirical transfer function estimate of I/V and w/V on one sweep.

    The whole segment is Fourier transformed (a chirp is not stationary, so
    Welch's short windows would each see a different frequency); cross and auto
    spectra are summed over log-spaced frequency bands (at least 4 bins each).
    Per band, ``H = sum(Y U*) / sum(|U|^2)`` and the coherence is
    ``|sum(Y U*)|^2 / (sum(|U|^2) sum(|Y|^2))``: near 1 where the output is
    explained linearly by the input, lower where noise or transients dominate.
    Only bands where the sweep put energy (per-bin input power >= 1 % of the
    strongest band's) are kept.

    ``free_response`` = (current, speed) of the motor's zero-input response from
    the segment's initial state: subtracted first, so that a sweep starting from
    a moving rotor does not leak its transient into the low frequencies (this
    borrows only the initial-state decay from a fitted model).
    """
    if seg.voltage is None or np.isnan(seg.voltage).any():
        msg = f"segment {seg.label!r}: the frequency response needs a closed-armature voltage"
        raise DataError(msg)
    if seg.n < 64:
        msg = f"segment {seg.label!r}: too short for a frequency response ({seg.n} samples)"
        raise DataError(msg)
    dt = seg.dt_s
    # Both signals are first-differenced (pre-whitened): the ratio Y/U is unchanged,
    # but the large low-frequency response no longer leaks into the higher bins of
    # a segment that does not start and end in the same state.
    v = np.diff(seg.voltage)
    f = np.fft.rfftfreq(v.size, dt)
    U = np.fft.rfft(v)
    outs = {"speed": seg.speed_or_derivative()}
    if seg.current is not None:
        outs["current"] = seg.current
    if free_response is not None:
        outs["speed"] = outs["speed"] - free_response[1]
        if "current" in outs:
            outs["current"] = outs["current"] - free_response[0]
    Y = {k: np.fft.rfft(np.diff(y)) for k, y in outs.items()}
    f_lo = 2.0 / seg.duration_s
    f_hi = 0.4 / dt
    ratio = (f_hi / f_lo) ** (1.0 / bands)
    idx = [int(np.searchsorted(f, f_lo))]
    while idx[-1] < f.size - 1 and f[idx[-1]] < f_hi:
        idx.append(max(idx[-1] + 4, int(np.searchsorted(f, f[idx[-1]] * ratio))))
    idx = np.minimum(np.array(idx), f.size)
    centers, hs, cohs = [], {k: [] for k in Y}, {k: [] for k in Y}
    dens_max = 0.0
    rows = []
    for a, b in zip(idx[:-1], idx[1:], strict=True):
        if b - a < 4:
            continue
        suu = float(np.sum(np.abs(U[a:b]) ** 2))
        rows.append((a, b, suu))
        dens_max = max(dens_max, suu / (b - a))
    for a, b, suu in rows:
        if suu <= 0.0 or suu / (b - a) < 1e-2 * dens_max:
            continue  # the sweep put (almost) no energy here (none at all: a flat record)
        centers.append(float(np.exp(np.mean(np.log(f[a:b])))))
        for k, Yk in Y.items():
            syu = complex(np.sum(Yk[a:b] * np.conj(U[a:b])))
            syy = float(np.sum(np.abs(Yk[a:b]) ** 2))
            hs[k].append(syu / suu)
            cohs[k].append(abs(syu) ** 2 / (suu * syy) if syy > 0 else 0.0)
    if len(centers) < 3:
        msg = f"segment {seg.label!r}: too little input energy for a frequency response"
        raise DataError(msg)
    has_i = "current" in Y
    return FrequencyResponse(
        freq_hz=np.array(centers),
        current_per_voltage=np.array(hs["current"]) if has_i else None,
        speed_per_voltage=np.array(hs["speed"]),
        coherence_current=np.array(cohs["current"]) if has_i else None,
        coherence_speed=np.array(cohs["speed"]),
        dt_s=dt,
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
