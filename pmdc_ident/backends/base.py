"""The interface every motor backend offers the driver node.

A backend owns the motor: it applies commanded voltages (clamped to its
limits), opens the armature on request, and produces telemetry samples stamped
with *its own* sample time (the plant's grid, or the board's clock), never the
host's arrival time. ``poll()`` returns every sample produced since the last
call, so a late host timer loses no data and never changes the physics.
``make_safe()`` must be idempotent and callable from any state, including after
an error: the driver calls it on every way out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from pmdc_ident.core.enums import Fault
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import Limits

__all__ = ["Backend", "BackendError", "Telemetry"]


class BackendError(PmdcError):
    """The backend cannot reach or drive the motor (one plain line)."""


@dataclass(frozen=True)
class Telemetry:
    """One sample of the driver. Units in the names; NaN command = armature open."""

    sample_index: int
    time_s: float  # the backend's own sample time
    current_a: float
    position_rad: float
    speed_rad_s: float
    voltage_cmd_v: float  # the command being applied over this sample (NaN = open)
    terminal_voltage_v: float = math.nan  # measured at the motor when the hardware has it
    supply_voltage_v: float = math.nan
    faults: Fault = Fault.NONE

    @property
    def armature_open(self) -> bool:
        return math.isnan(self.voltage_cmd_v)


@runtime_checkable
class Backend(Protocol):
    """What the driver node needs from a motor backend."""

    @property
    def dt_s(self) -> float: ...

    @property
    def limits(self) -> Limits: ...

    def start(self) -> None:
        """Connect / begin producing samples, with the armature open."""

    def command_voltage(self, voltage_v: float) -> float:
        """Apply a voltage (clamped to the limit); returns the value actually applied.

        Raises :class:`BackendError` for NaN or inf (the caller keeps the motor safe).
        """

    def open_armature(self) -> None:
        """Disconnect the winding (coast-down); 0 V would brake instead."""

    def make_safe(self) -> None:
        """Put the motor in the configured safe state; idempotent, never raises."""

    def poll(self) -> list[Telemetry]:
        """All samples produced since the last call, oldest first."""

    def close(self) -> None:
        """make_safe() then release resources."""
