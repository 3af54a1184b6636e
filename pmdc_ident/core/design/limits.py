"""The limits a designed plan keeps under the prior model, checked sample by sample.

Voltage (never above the driver's limit), current and speed (a share of the session's
abort thresholds, so a motor a little off its prior does not trip them), winding
heating as ``int i^2 dt`` over the plan, motor time, and optionally the travel of a
joint: the position stays inside the range minus a margin at every instant, and so
does a stop commanded at any instant (the session's safe state: 0 V brakes, an open
armature coasts) and arriving up to ``command_delay_s`` late, the command in force
held meanwhile; a motor that runs faster and farther than the prior
(:meth:`Prior.pessimistic`) stays inside the range itself.

Why the delay: a session's commands follow the driver's samples through the host, and
a host held up for a tenth of a second (a busy machine, a scheduler's throttling) leaves
the driver holding the last command that long. Planned for no delay, a joint's
pre-test square wave left a +/-2 rad range after one switch came 0.15 s late (a busy
CI machine); planned for a delay, the same delay keeps it inside (the default:
:data:`pmdc_ident.core.safety.COMMAND_DELAY_S`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Model
from pmdc_ident.core.safety import COMMAND_DELAY_S

__all__ = [
    "COMMAND_DELAY_S",
    "LIMIT_NAMES",
    "PlanLimits",
    "Violation",
    "late_stop",
    "stop_distance",
]

FloatArray = NDArray[np.float64]
LIMIT_NAMES = ("voltage", "current", "speed", "heat", "travel", "time")


@dataclass(frozen=True)
class Violation:
    limit: str  # one of LIMIT_NAMES
    detail: str


@dataclass(frozen=True)
class PlanLimits:
    """Units in the names. ``use_fraction``: the share of the current and speed limits
    the plan may reach under the prior; ``travel_rad`` ``(min, max)`` in the encoder's
    frame, the plan starting at rest at ``start_rad``; ``budget_s`` the most motor time."""

    voltage_max_v: float
    current_max_a: float
    speed_max_rad_s: float
    heat_a2s: float = math.inf
    travel_rad: tuple[float, float] | None = None
    start_rad: float = 0.0
    travel_margin_rad: float | None = None  # None: 10 % of the range on each side
    use_fraction: float = 0.8
    budget_s: float = 60.0
    safe_mode: SafeMode = SafeMode.ZERO
    command_delay_s: float = COMMAND_DELAY_S  # travel: a stop this late still ends inside

    def __post_init__(self) -> None:
        for name in ("voltage_max_v", "current_max_a", "speed_max_rad_s", "heat_a2s", "budget_s"):
            v = float(getattr(self, name))
            if not v > 0:
                msg = f"limit {name} must be > 0, got {v}"
                raise ParameterError(msg)
        if not 0 < self.use_fraction <= 1:
            msg = f"use_fraction must lie in (0, 1], got {self.use_fraction}"
            raise ParameterError(msg)
        if self.travel_rad is not None:
            lo, hi = (float(x) for x in self.travel_rad)
            if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
                msg = f"travel range must be MIN < MAX (rad), got {lo:g} {hi:g}"
                raise ParameterError(msg)
            if not lo < self.start_rad < hi:
                msg = (
                    f"the start position {self.start_rad:g} rad is not inside the travel range "
                    f"[{lo:g}, {hi:g}] rad"
                )
                raise ParameterError(msg)
            object.__setattr__(self, "travel_rad", (lo, hi))
        if not (math.isfinite(self.command_delay_s) and self.command_delay_s >= 0):
            msg = f"command delay must be >= 0 s, got {self.command_delay_s}"
            raise ParameterError(msg)
        object.__setattr__(self, "safe_mode", SafeMode(self.safe_mode))

    @property
    def margin_rad(self) -> float:
        if self.travel_rad is None:
            return 0.0
        if self.travel_margin_rad is not None:
            return float(self.travel_margin_rad)
        return default_margin_rad(self.travel_rad)

    @property
    def current_use_a(self) -> float:
        return self.use_fraction * self.current_max_a

    @property
    def speed_use_rad_s(self) -> float:
        return self.use_fraction * self.speed_max_rad_s

    def describe(self) -> str:
        parts = [
            f"voltage {self.voltage_max_v:.4g} V",
            f"current {self.current_max_a:.4g} A",
            f"speed {self.speed_max_rad_s:.4g} rad/s (plan within {self.use_fraction:.0%})",
        ]
        if math.isfinite(self.heat_a2s):
            parts.append(f"heat {self.heat_a2s:.4g} A^2*s")
        if self.travel_rad is not None:
            lo, hi = self.travel_rad
            parts.append(
                f"travel [{lo:.4g}, {hi:.4g}] rad (margin {self.margin_rad:.3g} rad, "
                f"commands up to {self.command_delay_s:.3g} s late)"
            )
        parts.append(f"motor time <= {self.budget_s:.4g} s")
        return ", ".join(parts)

    def check(
        self,
        voltage: FloatArray,
        current: FloatArray,
        speed: FloatArray,
        position: FloatArray,
        heat_a2s: float,
        stop: FloatArray | None = None,
        from_rad: float | None = None,
    ) -> Violation | None:
        """The first limit the predicted samples break (``heat_a2s``: the plan's heat up
        to and with them; ``stop``: where the rotor would come to rest were the safe
        state commanded at each sample; ``from_rad``: where the segment starts - a joint
        already inside the margin, a real one a little off its prior, may not go farther
        out, but may come back)."""
        v = voltage[np.isfinite(voltage)]
        if v.size and float(np.max(np.abs(v))) > self.voltage_max_v * (1 + 1e-9):
            return Violation("voltage", f"{float(np.max(np.abs(v))):.3g} V")
        i_peak = float(np.max(np.abs(current))) if current.size else 0.0
        if i_peak > self.current_use_a:
            return Violation("current", f"{i_peak:.3g} A")
        w_peak = float(np.max(np.abs(speed))) if speed.size else 0.0
        if w_peak > self.speed_use_rad_s:
            return Violation("speed", f"{w_peak:.3g} rad/s")
        if heat_a2s > self.heat_a2s:
            return Violation("heat", f"{heat_a2s:.3g} A^2*s")
        if self.travel_rad is not None:
            lo, hi = self.travel_rad
            m = self.margin_rad
            a, b = lo + m, hi - m
            if from_rad is not None:
                a, b = min(a, from_rad), max(b, from_rad)
            if float(position.min()) < a or float(position.max()) > b:
                return Violation("travel", f"{position.min():.3g}..{position.max():.3g} rad")
            # a stop at any instant ends inside the range with its margin too: from
            # every state the plan reaches, braking is itself a feasible next segment
            if stop is not None and (float(stop.min()) < a or float(stop.max()) > b):
                return Violation("travel", f"stopping {stop.min():.3g}..{stop.max():.3g} rad")
        return None


def default_margin_rad(travel_rad: tuple[float, float]) -> float:
    """The travel margin a plan keeps on each side unless told: 10 % of the range."""
    return 0.1 * (float(travel_rad[1]) - float(travel_rad[0]))


def stop_distance(
    model: Model, speed: FloatArray, current: FloatArray, safe: SafeMode
) -> FloatArray:
    """How far the rotor turns, from each sample, once the safe state is commanded:
    0 V shorts the winding (the back-EMF brakes it, time constant ``J R / (Ke Kt + R B)``,
    plus the current still flowing over L/R), an open armature lets it coast on its
    friction alone."""
    p = model.params
    e = model.effect("coulomb_friction")
    tc = float(getattr(e, "torque_nm", 0.0)) if e is not None else 0.0
    if safe is SafeMode.ZERO:
        tau = p.J * p.R / (p.Ke * p.Kt + p.R * p.B)
        # the current decays over L/R, still pushing: at most i Kt (L/R)^2 / J more
        extra = current * p.Kt * (p.L / p.R) ** 2 / p.J
        return speed * tau + extra
    a = p.B / p.J
    w = np.abs(speed)
    if tc > 0 and a > 0:
        d = (w - (tc / p.B) * np.log1p(p.B * w / tc)) / a
    elif tc > 0:
        d = p.J * w * w / (2.0 * tc)
    elif a > 0:
        d = w / a
    else:
        d = np.full_like(w, math.inf)
    return np.sign(speed) * d


def late_stop(
    model: Model,
    voltage: FloatArray,
    speed: FloatArray,
    current: FloatArray,
    safe: SafeMode,
    delay_s: float,
) -> FloatArray:
    """How far the rotor turns, from each sample, when the command in force there
    (``voltage``, NaN: armature open) is held ``delay_s`` longer and the safe state
    then commanded (:func:`stop_distance` from the state it has reached by then).

    Held, the speed relaxes towards the command's steady state with the mechanical
    rate ``(B + Ke Kt / R) / J`` (L neglected: the current follows within L/R); the
    friction slows it (a Coulomb torque beyond the drive's holds it); an open armature
    coasts, bounded by its speed held."""
    if delay_s <= 0:
        return stop_distance(model, speed, current, safe)
    p = model.params
    e = model.effect("coulomb_friction")
    tc = float(getattr(e, "torque_nm", 0.0)) if e is not None else 0.0
    damp = p.B + p.Ke * p.Kt / p.R
    rate = damp / p.J
    driven = np.isfinite(voltage)
    u = p.Kt * np.where(driven, voltage, 0.0) / p.R
    w_ss = np.sign(u) * np.maximum(np.abs(u) - tc, 0.0) / damp
    decay = math.exp(-rate * delay_s)
    w_late = np.where(driven, w_ss + (speed - w_ss) * decay, speed)
    moved = np.where(
        driven, w_ss * delay_s + (speed - w_ss) * (1.0 - decay) / rate, speed * delay_s
    )
    i_late = np.where(driven, (np.where(driven, voltage, 0.0) - p.Ke * w_late) / p.R, 0.0)
    # the current at the sample, where it is the larger push (a step's first samples)
    i_late = np.where(np.abs(current) > np.abs(i_late), current, i_late)
    return moved + stop_distance(model, w_late, i_late, safe)
