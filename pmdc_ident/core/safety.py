"""The one safety monitor (ROS-free): latching limit checks on every sample and a
command watchdog.

Both places that guard the motor use it. The driver node feeds every telemetry
sample and every received command to its monitor and makes the backend safe on a
trip (commands are refused until ``reset_faults``); the identification session feeds
every driver sample to its own and aborts on the first trip. Keeping the rules here
keeps both thin and lets them be tested without ROS.

* over-current ``|current| > current_max_a`` and over-speed ``|speed| >
  speed_max_rad_s`` (an infinite limit disables the check);
* stall: ``|current| > stall_current_a`` while ``|speed| < stall_speed_rad_s`` for
  ``stall_time_s`` (an infinite ``stall_current_a`` disables it);
* a non-finite reading, when ``non_finite_trips`` (the driver's sensors may report
  "not measured"; the session must not run on one);
* travel: the measured position outside ``[position_min_rad, position_max_rad]`` (a
  joint with end stops; infinite bounds disable it, a non-finite position trips it then);
* the watchdog (``watchdog_s > 0``) fires once when the armature is driven and no
  command came within ``watchdog_s``; the next valid command clears it.

A trip latches until :meth:`SafetyMonitor.reset`; :meth:`SafetyMonitor.check` returns
the first trip a sample newly latched, :meth:`SafetyMonitor.report` latches a trip a
backend reports in its fault bits.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

from pmdc_ident.core.enums import AbortReason, Fault
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.motors import Limits

__all__ = ["SafetyConfig", "SafetyMonitor"]

# How late a command may reach the driver with a travel-limited joint still inside its
# range: plans for such a joint hold for a command (a stop, a switch) this late, the
# last one held meanwhile (pmdc_ident.core.design.limits). A session's commands follow
# the driver's samples through the host: a busy host holds them up for tenths of a
# second (a pre-test planned for none left a +/-2 rad range on a busy CI machine).
COMMAND_DELAY_S = 0.15

_FAULT_OF = {
    AbortReason.OVER_CURRENT: Fault.OVER_CURRENT,
    AbortReason.OVER_SPEED: Fault.OVER_SPEED,
}


@dataclass(frozen=True)
class SafetyConfig:
    """Trip thresholds. Units in the names; a stall is current above
    ``stall_current_a`` while ``|speed| < stall_speed_rad_s`` for ``stall_time_s``.
    ``data_timeout_s`` is the session's lost-data abort (0: off)."""

    current_max_a: float
    speed_max_rad_s: float
    stall_current_a: float = math.inf
    stall_speed_rad_s: float = 1.0
    stall_time_s: float = 1.0
    data_timeout_s: float = 3.0
    watchdog_s: float = 0.0
    non_finite_trips: bool = True
    position_min_rad: float = -math.inf
    position_max_rad: float = math.inf

    def __post_init__(self) -> None:
        lo, hi = float(self.position_min_rad), float(self.position_max_rad)
        if math.isnan(lo) or math.isnan(hi) or not lo < hi:
            msg = f"safety travel range must be MIN < MAX (rad), got {lo} {hi}"
            raise ParameterError(msg)
        for f in ("current_max_a", "speed_max_rad_s", "stall_current_a", "stall_time_s"):
            v = float(getattr(self, f))
            if not v > 0:
                msg = f"safety.{f} must be a positive number (inf: no limit), got {v}"
                raise ParameterError(msg)
        for f in ("stall_speed_rad_s", "data_timeout_s", "watchdog_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v >= 0):
                msg = f"safety.{f} must be a number >= 0, got {v}"
                raise ParameterError(msg)

    @classmethod
    def for_limits(
        cls,
        limits: Limits,
        tau_m_s: float,
        *,
        stall_current_fraction: float = 0.5,
        stall_speed_rad_s: float = 1.0,
        data_timeout_s: float = 3.0,  # the identification node's default (busy hosts)
    ) -> SafetyConfig:
        """Defaults from motor limits: stall after 3 tau_m (a free rotor is at 95 %)."""
        return cls(
            current_max_a=limits.current_max_a,
            speed_max_rad_s=limits.speed_max_rad_s,
            stall_current_a=stall_current_fraction * limits.current_max_a,
            stall_speed_rad_s=stall_speed_rad_s,
            stall_time_s=max(3.0 * tau_m_s, 0.05),
            data_timeout_s=data_timeout_s,
        )


class SafetyMonitor:
    """Checks each sample against a :class:`SafetyConfig`; trips latch until reset."""

    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self.latched: dict[AbortReason, str] = {}  # trip -> message, in trip order
        self.reason: AbortReason | None = None  # the first trip since the last reset
        self.detail = ""  # its message
        self.watchdog_tripped = False
        self._stall_since: float | None = None
        self._last_command_s: float | None = None

    # -- state ------------------------------------------------------------------------
    @property
    def tripped(self) -> bool:
        return bool(self.latched)

    @property
    def faults(self) -> Fault:
        """The latched trips and the watchdog as telemetry fault bits."""
        out = Fault.NONE
        for reason in self.latched:
            out |= _FAULT_OF.get(reason, Fault.NONE)
        return out | (Fault.WATCHDOG if self.watchdog_tripped else Fault.NONE)

    def update(self, **changes: float) -> None:
        """Change thresholds at run time (checked as at construction)."""
        self.config = replace(self.config, **changes)

    def reset(self) -> None:
        """Clear latched trips (the operator has looked at the motor)."""
        self.latched.clear()
        self.reason = None
        self.detail = ""
        self._stall_since = None

    # -- checks -----------------------------------------------------------------------
    def check(
        self,
        t_s: float,
        current_a: float,
        speed_rad_s: float,
        position_rad: float | None = None,
    ) -> AbortReason | None:
        """The first limit this sample newly trips (``None`` if none)."""
        trips = self._violations(t_s, current_a, speed_rad_s)
        travel = self._travel(t_s, position_rad)
        return self._latch([*trips, travel] if travel else trips)

    def _travel(self, t_s: float, position_rad: float | None) -> tuple[AbortReason, str] | None:
        c = self.config
        if position_rad is None or (
            c.position_min_rad == -math.inf and c.position_max_rad == math.inf
        ):
            return None
        if (
            not math.isfinite(position_rad)
            or not c.position_min_rad <= position_rad <= c.position_max_rad
        ):
            return (
                AbortReason.OUT_OF_TRAVEL,
                f"out of travel: position {position_rad:.4g} rad outside "
                f"[{c.position_min_rad:.4g}, {c.position_max_rad:.4g}] rad at t={t_s:.3f} s",
            )
        return None

    def report(self, faults: Fault, t_s: float) -> AbortReason | None:
        """Trips a backend reports in its own fault bits (it trips at the sample itself,
        like board firmware): latched like the monitor's own; the first new one."""
        trips = []
        for reason, bit in _FAULT_OF.items():
            if faults & bit:
                words = reason.value.replace("_", "-")
                trips.append((reason, f"{words}: tripped by the backend at t={t_s:.3f} s"))
        return self._latch(trips)

    def _latch(self, trips: list[tuple[AbortReason, str]]) -> AbortReason | None:
        """Latch the trips not latched yet; the first of them (``None`` if none)."""
        new: AbortReason | None = None
        for reason, message in trips:
            if reason in self.latched:
                continue
            self.latched[reason] = message
            if new is None:
                new = reason
            if self.reason is None:
                self.reason, self.detail = reason, message
        return new

    def message(self) -> str:
        """The latched trips in words ('' when none)."""
        return "; ".join(self.latched.values())

    def _violations(
        self, t_s: float, current_a: float, speed_rad_s: float
    ) -> list[tuple[AbortReason, str]]:
        c = self.config
        if not (math.isfinite(current_a) and math.isfinite(speed_rad_s)):
            if c.non_finite_trips:
                return [(AbortReason.DRIVER_FAULT, "driver sent a non-finite reading")]
            return []
        out: list[tuple[AbortReason, str]] = []
        if abs(current_a) > c.current_max_a:
            out.append(
                (
                    AbortReason.OVER_CURRENT,
                    f"over-current: |current| {abs(current_a):.3g} A > {c.current_max_a:.3g} A "
                    f"at t={t_s:.3f} s",
                )
            )
        if abs(speed_rad_s) > c.speed_max_rad_s:
            out.append(
                (
                    AbortReason.OVER_SPEED,
                    f"over-speed: |speed| {abs(speed_rad_s):.4g} rad/s > "
                    f"{c.speed_max_rad_s:.4g} rad/s at t={t_s:.3f} s",
                )
            )
        stall = self._stall(t_s, current_a, speed_rad_s)
        if stall:
            out.append((AbortReason.STALL, stall))
        return out

    def _stall(self, t_s: float, current_a: float, speed_rad_s: float) -> str:
        c = self.config
        if not (abs(current_a) > c.stall_current_a and abs(speed_rad_s) < c.stall_speed_rad_s):
            self._stall_since = None
            return ""
        if self._stall_since is None:
            self._stall_since = t_s
            return ""
        if t_s - self._stall_since < c.stall_time_s:
            return ""
        return (
            f"stall: |current| > {c.stall_current_a:.3g} A with |speed| < "
            f"{c.stall_speed_rad_s:.3g} rad/s for {t_s - self._stall_since:.2f} s"
        )

    # -- watchdog ---------------------------------------------------------------------
    def command_received(self, now_s: float) -> None:
        """A valid command arrived: feed the watchdog and clear its fault."""
        self._last_command_s = now_s
        self.watchdog_tripped = False

    def watchdog_expired(self, now_s: float, driving: bool) -> bool:
        """True exactly once when a driven armature has gone ``watchdog_s`` without command."""
        timeout = self.config.watchdog_s
        if timeout <= 0.0 or not driving or self.watchdog_tripped:
            return False
        if self._last_command_s is None:
            self._last_command_s = now_s
            return False
        if now_s - self._last_command_s > timeout:
            self.watchdog_tripped = True
            return True
        return False
