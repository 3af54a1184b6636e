"""Motor parameters of the seeds' model, with units.

The model (both seeds)::

    L di/dt = V - R i - Ke w
    J dw/dt = Kt i - B w - T_load

Parameter table (the single place where units are defined; names are the JSON
keys of docs/design.md §4):

====  =========  ==========================================
name  unit       meaning
====  =========  ==========================================
R     ohm        armature resistance
L     H          armature inductance
Ke    V*s/rad    back-EMF constant
Kt    N*m/A      torque constant
J     kg*m^2     rotor inertia
B     N*m*s/rad  viscous friction coefficient
====  =========  ==========================================
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

from pmdc_ident.core.errors import ParameterError

__all__ = [
    "NEEDED_PARAMETERS",
    "PARAMETER_NAMES",
    "PARAMETER_RANGES",
    "PARAMETER_UNITS",
    "MotorParams",
    "check_physical_range",
    "physical_range_problem",
]

PARAMETER_NAMES: tuple[str, ...] = ("R", "L", "Ke", "Kt", "J", "B")
# What a motor model cannot do without: identify refuses a result where one is a guess
# (L, B and friction may stay flagged: a model runs with them).
NEEDED_PARAMETERS: tuple[str, ...] = ("R", "Ke", "J")
PARAMETER_UNITS: dict[str, str] = {
    "R": "ohm",
    "L": "H",
    "Ke": "V*s/rad",
    "Kt": "N*m/A",
    "J": "kg*m^2",
    "B": "N*m*s/rad",
}
PARAMETER_DESCRIPTIONS: dict[str, str] = {
    "R": "armature resistance",
    "L": "armature inductance",
    "Ke": "back-EMF constant",
    "Kt": "torque constant",
    "J": "rotor inertia",
    "B": "viscous friction coefficient",
}

# The physical range of each parameter: generous bounds (a watch motor to a
# traction motor) that a value given by a user (``--fix``, a motor file) must
# lie in. A value outside is a typo or a unit mistake, never a motor.
PARAMETER_RANGES: dict[str, tuple[float, float]] = {
    "R": (1e-4, 1e4),
    "L": (1e-9, 10.0),
    "Ke": (1e-6, 100.0),
    "Kt": (1e-6, 100.0),
    "J": (1e-12, 1e3),
    "B": (0.0, 100.0),
}


def check_physical_range(name: str, value: float, source: str = "motor parameter") -> float:
    """``value`` if it lies in :data:`PARAMETER_RANGES` for ``name``, else a ParameterError."""
    problem = physical_range_problem(name, value)
    if problem:
        msg = f"{source} {name}={value:g}: {problem}"
        raise ParameterError(msg)
    return value


def physical_range_problem(name: str, value: float) -> str:
    """Why ``value`` is not a possible ``name`` ('' when it lies in its range)."""
    lo, hi = PARAMETER_RANGES[name]
    if math.isfinite(value) and lo <= value <= hi:
        return ""
    return (
        f"outside the physical range of the {PARAMETER_DESCRIPTIONS[name]}, "
        f"[{lo:g}, {hi:g}] {PARAMETER_UNITS[name]} (a unit mistake?)"
    )


@dataclass(frozen=True)
class MotorParams:
    """The six parameters of the linear PMDC model (units: see module table)."""

    R: float
    L: float
    Ke: float
    Kt: float
    J: float
    B: float

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            try:
                value = float(value)
            except (TypeError, ValueError):
                msg = f"motor parameter {f.name} must be a number, got {value!r}"
                raise ParameterError(msg) from None
            if not math.isfinite(value):
                msg = f"motor parameter {f.name} must be finite, got {value}"
                raise ParameterError(msg)
            lower_ok = value >= 0.0 if f.name == "B" else value > 0.0
            if not lower_ok:
                bound = ">= 0" if f.name == "B" else "> 0"
                msg = (
                    f"motor parameter {f.name} ({PARAMETER_DESCRIPTIONS[f.name]}) must be "
                    f"{bound} {PARAMETER_UNITS[f.name]}, got {value}"
                )
                raise ParameterError(msg)
            object.__setattr__(self, f.name, value)

    # -- conversions -------------------------------------------------------------
    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def from_mapping(cls, data: Any) -> MotorParams:
        """Build from a mapping with keys R, L, Ke, Kt, J, B (extra keys refused)."""
        if not isinstance(data, dict):
            msg = f"motor parameters must be a mapping of {', '.join(PARAMETER_NAMES)}"
            raise ParameterError(msg)
        missing = [n for n in PARAMETER_NAMES if n not in data]
        if missing:
            msg = f"motor parameters lack {', '.join(missing)}"
            raise ParameterError(msg)
        extra = sorted(set(data) - set(PARAMETER_NAMES))
        if extra:
            msg = f"unknown motor parameter(s) {', '.join(extra)}; known: {PARAMETER_NAMES}"
            raise ParameterError(msg)
        return cls(**{n: data[n] for n in PARAMETER_NAMES})

    def replace(self, **changes: float) -> MotorParams:
        return replace(self, **changes)

    # -- closed forms ------------------------------------------------------------
    @property
    def electrical_time_constant_s(self) -> float:
        """L/R."""
        return self.L / self.R

    @property
    def mechanical_time_constant_s(self) -> float:
        """J R / (R B + Ke Kt): the time constant of speed when L -> 0."""
        return self.J * self.R / (self.R * self.B + self.Ke * self.Kt)

    def steady_state(self, voltage_v: float, load_torque_nm: float = 0.0) -> tuple[float, float]:
        """Steady current (A) and speed (rad/s) under a constant voltage and load torque."""
        den = self.R * self.B + self.Ke * self.Kt
        current = (self.B * voltage_v + self.Ke * load_torque_nm) / den
        speed = (self.Kt * voltage_v - self.R * load_torque_nm) / den
        return current, speed

    def transfer_functions(self) -> dict[str, tuple[list[float], list[float]]]:
        """I/V and w/V as (numerator, denominator) in seed 001's eq. 4-5 form.

        Normalised by J so the denominator reads ``L s^2 + (R + L B/J) s + (R B + Ke Kt)/J``
        (seed 001 prints 0.1042 s^2 + 3.123 s + 60.83 for its first trial).
        """
        den = [
            self.L,
            self.R + self.L * self.B / self.J,
            (self.R * self.B + self.Ke * self.Kt) / self.J,
        ]
        return {
            "current_per_voltage": ([1.0, self.B / self.J], den),
            "speed_per_voltage": ([self.Kt / self.J], den),
        }
