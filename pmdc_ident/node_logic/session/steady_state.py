"""When a staircase level has settled: a trailing-window drift test on speed and current."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pmdc_ident.core.errors import ParameterError

__all__ = ["SteadyStateConfig", "SteadyStateDetector"]


@dataclass(frozen=True)
class SteadyStateConfig:
    """When a staircase level counts as settled.

    Over the trailing ``window_s`` the fitted drift (slope x window) of speed and of
    current must both be within ``n_sigma`` times their residual noise, or within
    ``rel_tol`` of their mean. A level is held at least ``min_hold_fraction`` and at
    most ``timeout_factor`` times its nominal (planned) length.
    """

    window_s: float = 0.0  # 0: one mechanical time constant
    n_sigma: float = 3.0
    rel_tol: float = 0.002
    min_hold_fraction: float = 0.5
    timeout_factor: float = 4.0
    check_every_s: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < self.min_hold_fraction <= self.timeout_factor:
            msg = "steady_state: need 0 < min_hold_fraction <= timeout_factor"
            raise ParameterError(msg)
        for f in ("window_s", "n_sigma", "rel_tol", "check_every_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v >= 0):
                msg = f"steady_state.{f} must be a number >= 0, got {v}"
                raise ParameterError(msg)


class SteadyStateDetector:
    """Trailing-window drift test on speed and current (preallocated ring buffer)."""

    def __init__(self, window_samples: int, config: SteadyStateConfig) -> None:
        self.n = max(8, int(window_samples))
        self.config = config
        self._t = np.zeros(self.n)
        self._i = np.zeros(self.n)
        self._w = np.zeros(self.n)
        self._k = 0

    def reset(self) -> None:
        self._k = 0

    def push(self, t_s: float, current_a: float, speed_rad_s: float) -> None:
        j = self._k % self.n
        self._t[j], self._i[j], self._w[j] = t_s, current_a, speed_rad_s
        self._k += 1

    @property
    def full(self) -> bool:
        return self._k >= self.n

    def drift(self) -> tuple[float, float, float, float]:
        """(speed drift, speed tolerance, current drift, current tolerance) over the window."""
        t = self._t - self._t.mean()
        stt = float(t @ t)
        out: list[float] = []
        for y in (self._w, self._i):
            ym = float(y.mean())
            slope = float(t @ (y - ym)) / stt if stt > 0 else 0.0
            resid = y - ym - slope * t
            sigma = float(np.sqrt(resid @ resid / max(self.n - 2, 1)))
            span = float(self._t.max() - self._t.min())
            tol = max(self.config.n_sigma * sigma, self.config.rel_tol * abs(ym))
            out += [abs(slope) * span, tol]
        return out[0], out[1], out[2], out[3]

    def is_steady(self) -> bool:
        if not self.full:
            return False
        dw, tw, di, ti = self.drift()
        return dw <= tw and di <= ti
