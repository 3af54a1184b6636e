"""Held-out residuals, noise floors and the gap measure shared by every stage.

The gap of a model on a set of segments is its *excess* simulation error in
units of the measurement noise: for each measured signal (current, speed), the
mean squared free-run simulation error minus the noise variance, divided by the
noise variance, averaged over the signals (a signal's excess below zero, noise
estimated a little high, counts as zero). 0 means "as good as the noise allows";
1 means the error energy is twice the noise. Each signal counts by what it can
show: a clean current is not drowned by a speed differentiated from a coarse
encoder (the output-error fit weighs its residuals the same way). The noise
variance is estimated from the data alone (:func:`estimate_noise`), so the
measure needs no ground truth.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment
from pmdc_ident.core.quality.noise import signal_noise
from pmdc_ident.core.quantisation import quantum

__all__ = ["SIGNALS", "NoiseModel", "Residuals", "estimate_noise", "residuals", "simulated"]

FloatArray = NDArray[np.float64]
SIGNALS: tuple[str, ...] = ("current", "speed")
# Floor on the noise estimate relative to the signal RMS: quantised or noise-free
# data would otherwise make any tiny mismatch look infinitely significant.
NOISE_FLOOR_REL = 1e-4


def _measured(seg: Segment, signal: str) -> FloatArray | None:
    if signal == "current":
        return seg.current
    return seg.speed_or_derivative()


@dataclass(frozen=True)
class NoiseModel:
    """Per-signal noise standard deviation and RMS scale, from the data."""

    sigma: dict[str, float]
    scale: dict[str, float]

    @property
    def signals(self) -> tuple[str, ...]:
        return tuple(self.sigma)


def estimate_noise(segments: Sequence[Segment]) -> NoiseModel:
    """Noise level per signal, the data-quality gate's estimator
    (:func:`~pmdc_ident.core.quality.noise.signal_noise`: the smaller of the
    second-difference spread and a one-step ARX prediction residual, per segment),
    floored at ``NOISE_FLOOR_REL`` of the signal's RMS."""
    sigma: dict[str, float] = {}
    scale: dict[str, float] = {}
    for sig in SIGNALS:
        arrays = [a for s in segments if (a := _measured(s, sig)) is not None]
        if not arrays:
            continue  # a signal is compared where segments carry it
        allv = np.concatenate(arrays)
        rms = float(np.sqrt(np.mean(allv**2)))
        sd = signal_noise(segments, lambda s, sig=sig: _measured(s, sig))
        if rms <= 0.0 or sd is None:
            continue
        if sig == "speed":
            sd = max(sd, _differentiated_counts_sd(segments))
        sigma[sig] = max(sd, NOISE_FLOOR_REL * rms)
        scale[sig] = rms
    return NoiseModel(sigma, scale)


def _differentiated_counts_sd(segments: Sequence[Segment]) -> float:
    """The noise of a speed made by central differences of an encoder's counts:
    (e[k+1] - e[k-1]) / (2 dt) with rounding errors e of sd q/sqrt(12) has sd
    q / (dt sqrt(24)), sqrt(2) more than the rounding of its own q/(2 dt) levels that
    the generic floor sees (a 13-line encoder's speed: held-out error 1.5x the
    estimate on a clean motor, read as a gap). Median over such segments; 0 if none."""
    sds = []
    for s in segments:
        if s.speed is not None or s.position is None or s.n < 3:
            continue
        q = quantum(s.position)
        if q is not None:
            sds.append(q.step / (s.dt_s * math.sqrt(24.0)))
    return float(np.median(sds)) if sds else 0.0


_REL_ERROR_CAP = 1e100


@dataclass(frozen=True)
class Residuals:
    """Per-sample simulation errors over a set of segments, concatenated."""

    error: dict[str, FloatArray]  # simulated - measured, physical units
    seg_index: NDArray[np.int64]
    noise: NoiseModel

    def _excess(self, sig: str) -> FloatArray:
        """Per-sample excess squared error of one signal in noise variances (NaN where
        the segment lacks the signal); a diverged simulation (errors of 1e200) is just
        very wrong: ratios are capped where their square stays finite."""
        err = self.error[sig]
        ratio = np.minimum(np.abs(err) / self.noise.sigma[sig], _REL_ERROR_CAP)
        return np.where(np.isfinite(err), ratio**2 - 1.0, np.nan)

    def excess_per_sample(self) -> FloatArray:
        """Excess squared error per sample in noise variances, averaged over the
        signals the sample has."""
        acc = np.zeros(self.seg_index.size)
        cnt = np.zeros(self.seg_index.size)
        for sig in self.error:
            x = self._excess(sig)
            ok = np.isfinite(x)
            acc[ok] += x[ok]
            cnt += ok
        return acc / np.maximum(cnt, 1)

    def gap(self, mask: NDArray[np.bool_] | None = None) -> float:
        """The gap (see module notes) over all samples or a mask: each signal's mean
        excess (floored at zero), averaged over the signals present."""
        parts = []
        for sig in self.error:
            x = self._excess(sig)
            if mask is not None:
                x = x[mask]
            x = x[np.isfinite(x)]
            if x.size:
                parts.append(max(float(np.mean(x)), 0.0))
        return float(np.mean(parts)) if parts else 0.0

    def gap_by_signal(self) -> dict[str, float]:
        """Each signal's excess error over all samples, in noise variances."""
        out = {}
        for sig in self.error:
            x = self._excess(sig)
            if np.isfinite(x).any():
                out[sig] = float(np.nanmean(x))
        return out

    def rms_by_signal(self) -> dict[str, float]:
        return {
            sig: float(np.sqrt(np.nanmean(err**2)))
            for sig, err in self.error.items()
            if np.isfinite(err).any()
        }


def simulated(seg: Segment, pred: object, signal: str) -> FloatArray:
    """The prediction of a measured signal, made the way the measurement was: a speed
    the log lacks is the central difference of the encoder's position, which damps
    fast motion (to 64 % at a quarter of the sample rate), so the simulated position
    is differentiated the same way rather than compared as the model's true speed."""
    if signal == "speed" and seg.speed is None:
        pos = getattr(pred, "position", None)
        if pos is not None and np.size(pos) == seg.n and seg.n > 1:
            return np.gradient(np.asarray(pos, dtype=float), seg.t)
    return np.asarray(getattr(pred, signal), dtype=float)


def residuals(
    segments: Sequence[Segment], predictions: Sequence[object], noise: NoiseModel
) -> Residuals:
    """Residuals of predictions (objects with ``current`` and ``speed``) against data."""
    err: dict[str, list[FloatArray]] = {sig: [] for sig in noise.signals}
    idx: list[NDArray[np.int64]] = []
    for k, (seg, pred) in enumerate(zip(segments, predictions, strict=True)):
        for sig in noise.signals:
            meas = _measured(seg, sig)
            if meas is None:
                err[sig].append(np.full(seg.n, np.nan))
                continue
            e = simulated(seg, pred, sig) - meas
            err[sig].append(np.where(np.isfinite(e), e, 1e6 * noise.scale[sig]))
        idx.append(np.full(seg.n, k, dtype=np.int64))
    return Residuals(
        {sig: np.concatenate(v) for sig, v in err.items()}, np.concatenate(idx), noise
    )
