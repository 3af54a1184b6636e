"""The driver's status in words (ROS-free): what its ``/diagnostics`` says."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from pmdc_ident.core.enums import Fault

__all__ = ["DriverStatus", "Level", "armature_text", "fault_names"]


class Level(enum.Enum):
    OK = "ok"
    WARN = "warn"
    ERROR = "error"


def armature_text(command_v: float) -> str:
    return "armature open" if math.isnan(command_v) else f"{command_v:g} V applied"


def fault_names(f: Fault) -> str:
    if not f:
        return "none"
    return ",".join(m.name for m in Fault if m and m in f and m.name)


@dataclass(frozen=True)
class DriverStatus:
    """One diagnostics report: level, message and the key-value table."""

    level: Level
    message: str
    values: dict[str, str]

    @classmethod
    def of(
        cls,
        *,
        faults: Fault,
        trip_message: str,
        rate_set_hz: float,
        rate_delivered_hz: float,
        link_error: str,
        link_state: str | None,
        values: dict[str, str],
    ) -> DriverStatus:
        """Errors first (a latched trip, a serial link down), then warnings (other
        faults, a sample rate below 90 % of the set one), else 'running'."""
        if faults & (Fault.OVER_CURRENT | Fault.OVER_SPEED):
            level, message = Level.ERROR, trip_message
        elif faults or rate_delivered_hz < 0.9 * rate_set_hz:
            level = Level.WARN
            message = f"faults: {fault_names(faults)}" if faults else "sample rate low"
        else:
            level, message = Level.OK, "running"
        if link_state is not None and link_state != "streaming":
            level, message = Level.ERROR, link_error or "serial link down"
        return cls(level, message, values)
