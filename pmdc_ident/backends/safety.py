"""Driver-side safety: over-current / over-speed trips and the command watchdog (ROS-free).

The driver node feeds every telemetry sample and every received command to a
:class:`SafetyMonitor` and makes the backend safe when it says so; keeping the
rules here keeps the node thin and lets them be tested without ROS.

* A trip (``|current| > current_limit_a`` or ``|speed| > speed_limit_rad_s``)
  latches: further commands are refused until :meth:`SafetyMonitor.reset`.
* The watchdog fires once when the armature is driven and no command came
  within ``watchdog_s``; the next valid command clears it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from pmdc_ident.backends.base import Fault, Telemetry
from pmdc_ident.core.errors import ParameterError

__all__ = ["SafetyMonitor"]


@dataclass
class SafetyMonitor:
    """Trip limits and watchdog of one driver. Limits <= 0 or inf disable a check."""

    current_limit_a: float
    speed_limit_rad_s: float
    watchdog_s: float
    latched: Fault = Fault.NONE  # OVER_CURRENT / OVER_SPEED, kept until reset()
    watchdog_tripped: bool = False
    trip_message: str = ""
    _last_command_s: float | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        for name in ("current_limit_a", "speed_limit_rad_s", "watchdog_s"):
            value = float(getattr(self, name))
            if math.isnan(value) or value < 0.0:
                msg = f"{name} must be >= 0 (0 disables it), got {value}"
                raise ParameterError(msg)
            setattr(self, name, value)

    @property
    def faults(self) -> Fault:
        return self.latched | (Fault.WATCHDOG if self.watchdog_tripped else Fault.NONE)

    @property
    def tripped(self) -> bool:
        return bool(self.latched)

    def check_sample(self, sample: Telemetry) -> Fault:
        """Fault bits newly tripped by this sample (``Fault.NONE`` if none)."""
        new = Fault.NONE
        ilim, wlim = self.current_limit_a, self.speed_limit_rad_s
        if ilim > 0.0 and abs(sample.current_a) > ilim and not self.latched & Fault.OVER_CURRENT:
            new |= Fault.OVER_CURRENT
            self.trip_message = (
                f"over-current trip: |{sample.current_a:.3f}| A > {ilim:g} A "
                f"at t = {sample.time_s:.4f} s"
            )
        over_speed = wlim > 0.0 and abs(sample.speed_rad_s) > wlim
        if over_speed and not self.latched & Fault.OVER_SPEED:
            new |= Fault.OVER_SPEED
            self.trip_message = (
                f"over-speed trip: |{sample.speed_rad_s:.2f}| rad/s > {wlim:g} rad/s "
                f"at t = {sample.time_s:.4f} s"
            )
        self.latched |= new
        return new

    def command_received(self, now_s: float) -> None:
        """A valid command arrived: feed the watchdog and clear its fault."""
        self._last_command_s = now_s
        self.watchdog_tripped = False

    def watchdog_expired(self, now_s: float, driving: bool) -> bool:
        """True exactly once when a driven armature has gone ``watchdog_s`` without command."""
        if self.watchdog_s <= 0.0 or not driving or self.watchdog_tripped:
            return False
        if self._last_command_s is None:
            self._last_command_s = now_s
            return False
        if now_s - self._last_command_s > self.watchdog_s:
            self.watchdog_tripped = True
            return True
        return False

    def reset(self) -> None:
        """Clear latched trips (the operator has looked at the motor)."""
        self.latched = Fault.NONE
        self.trip_message = ""
