"""Held-out residuals, noise floors and the gap measure shared by every stage.

The gap of a model on a set of segments is its *excess* simulation error: for
each measured signal (current, speed), the mean squared free-run simulation
error minus the measurement noise variance, relative to the signal's mean
square, averaged over the signals. 0 means "as good as the noise allows"; 0.1
means a tenth of the signal's energy is unexplained. The noise variance is
estimated from the data alone (robust spread of sample-to-sample differences),
so the measure needs no ground truth.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.data import Segment

__all__ = ["SIGNALS", "NoiseModel", "Residuals", "estimate_noise", "residuals"]

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

    def noise_rel(self, signal: str) -> float:
        """Noise variance relative to the signal's mean square."""
        return (self.sigma[signal] / self.scale[signal]) ** 2


def estimate_noise(segments: Sequence[Segment]) -> NoiseModel:
    """Robust noise level per signal: 1.4826 MAD of second differences / sqrt(6)."""
    sigma: dict[str, float] = {}
    scale: dict[str, float] = {}
    for sig in SIGNALS:
        arrays = [a for s in segments if (a := _measured(s, sig)) is not None]
        if not arrays:
            continue  # a signal is compared where segments carry it
        allv = np.concatenate(arrays)
        rms = float(np.sqrt(np.mean(allv**2)))
        if rms <= 0.0:
            continue
        diffs = np.concatenate([np.diff(a, 2) for a in arrays if a.size > 3] or [np.zeros(1)])
        mad = float(np.median(np.abs(diffs - np.median(diffs))))
        sd = 1.4826 * mad / np.sqrt(6.0)
        uniq = np.unique(allv)
        step = float(np.min(np.diff(uniq))) if 1 < uniq.size < allv.size // 2 else 0.0
        sigma[sig] = max(sd, step / np.sqrt(12.0), NOISE_FLOOR_REL * rms)
        scale[sig] = rms
    return NoiseModel(sigma, scale)


_REL_ERROR_CAP = 1e100


@dataclass(frozen=True)
class Residuals:
    """Per-sample simulation errors over a set of segments, concatenated."""

    error: dict[str, FloatArray]  # simulated - measured, physical units
    seg_index: NDArray[np.int64]
    noise: NoiseModel

    def excess_per_sample(self) -> FloatArray:
        """Relative excess squared error per sample, averaged over the signals it has."""
        acc = np.zeros(self.seg_index.size)
        cnt = np.zeros(self.seg_index.size)
        for sig, err in self.error.items():
            ok = np.isfinite(err)
            scale = self.noise.scale[sig]
            # a diverged simulation (errors of 1e200) is just very wrong: relative errors
            # are capped where their square stays finite
            rel = np.minimum(np.abs(err[ok]) / scale, _REL_ERROR_CAP)
            acc[ok] += rel**2 - (self.noise.sigma[sig] / scale) ** 2
            cnt += ok
        return acc / np.maximum(cnt, 1)

    def gap(self, mask: NDArray[np.bool_] | None = None) -> float:
        """The gap (see module notes) over all samples or a mask."""
        e = self.excess_per_sample()
        if mask is not None:
            e = e[mask]
        return float(np.mean(e)) if e.size else 0.0

    def gap_by_signal(self) -> dict[str, float]:
        return {
            sig: float(
                (np.nanmean(err**2) - self.noise.sigma[sig] ** 2) / self.noise.scale[sig] ** 2
            )
            for sig, err in self.error.items()
            if np.isfinite(err).any()
        }

    def rms_by_signal(self) -> dict[str, float]:
        return {
            sig: float(np.sqrt(np.nanmean(err**2)))
            for sig, err in self.error.items()
            if np.isfinite(err).any()
        }


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
            sim = np.asarray(getattr(pred, sig), dtype=float)
            e = sim - meas
            err[sig].append(np.where(np.isfinite(e), e, 1e6 * noise.scale[sig]))
        idx.append(np.full(seg.n, k, dtype=np.int64))
    return Residuals(
        {sig: np.concatenate(v) for sig, v in err.items()}, np.concatenate(idx), noise
    )
