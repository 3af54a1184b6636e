"""The identification node's link to the driver, ROS-free: how late samples arrive,
when a command is (re)sent, and whether the driver confirmed the safe state.

* :class:`Latency`: receive time minus driver stamp, less the smallest such
  difference seen. A board's clock may be offset from this host's (a serial driver
  stamps on the board's clock) and the transport delay is never negative, so the
  minimum is the baseline.
* :class:`CommandPolicy`: a voltage is published when it changes, when the armature
  was open, and every ``refresh_s`` so the driver's watchdog stays fed.
* :class:`SafeConfirmation`: after an abort or a stop, the driver's own
  ``voltage_applied`` must show 0 V or an open armature (NaN) at or after a stamp;
  until then the safe command is repeated every ``repeat_s``, up to a timeout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["CommandPolicy", "Latency", "SafeConfirmation"]


class Latency:
    """Latency of the driver's samples at this node (ns), against the lowest seen."""

    def __init__(self) -> None:
        self.baseline_ns = 2**62
        self.last_ns = 0

    def update(self, stamp_ns: int, received_ns: int) -> int:
        """The latency of a sample stamped ``stamp_ns`` and received at ``received_ns``
        (host wall clock, ns)."""
        raw = received_ns - stamp_ns
        self.baseline_ns = min(self.baseline_ns, raw)
        self.last_ns = raw - self.baseline_ns
        return self.last_ns


@dataclass
class CommandPolicy:
    """When a voltage command goes out (publish on change, refresh for the watchdog)."""

    refresh_s: float = 0.1
    last_v: float = math.nan
    last_s: float = -math.inf
    armature_open: bool = False

    def should_send(self, voltage_v: float, now_s: float) -> bool:
        return (
            voltage_v != self.last_v or self.armature_open or now_s - self.last_s > self.refresh_s
        )

    def sent(self, voltage_v: float, now_s: float) -> None:
        self.last_v = voltage_v
        self.last_s = now_s


class SafeConfirmation:
    """Waits for the driver to report the safe state on its own telemetry."""

    def __init__(self, timeout_s: float, repeat_s: float = 0.1) -> None:
        self.timeout_s = timeout_s
        self.repeat_s = repeat_s
        self.after_ns: int | None = None
        self.deadline_s = 0.0
        self.sent_s = 0.0
        self.confirmed = False

    @property
    def pending(self) -> bool:
        return self.after_ns is not None

    def start(self, after_ns: int, now_s: float) -> None:
        """Watch ``voltage_applied`` from the stamp ``after_ns`` on."""
        self.after_ns = after_ns
        self.deadline_s = now_s + self.timeout_s
        self.sent_s = now_s

    def cancel(self) -> None:
        """Stop waiting (nothing confirmed)."""
        self.after_ns = None

    def on_voltage(self, stamp_ns: int, voltage_v: float) -> str:
        """The safe state the driver reports ('' if this sample shows none)."""
        if self.after_ns is None or stamp_ns < self.after_ns:
            return ""
        if not (voltage_v == 0.0 or math.isnan(voltage_v)):
            return ""
        self.after_ns = None
        self.confirmed = True
        return "armature open" if math.isnan(voltage_v) else "0 V applied"

    def tick(self, now_s: float) -> str:
        """'timeout' when the deadline passed (then no longer pending), 'repeat' when the
        safe command should be sent again, '' otherwise."""
        if self.after_ns is None:
            return ""
        if now_s > self.deadline_s:
            self.after_ns = None
            return "timeout"
        if now_s - self.sent_s > self.repeat_s:
            self.sent_s = now_s
            return "repeat"
        return ""
