"""Unmodelled effects of the vocabulary (docs/design.md §4), as composable model additions.

Each effect is a frozen dataclass with its physical parameters (units in the
field names). A :class:`~pmdc_ident.core.model.Model` is the linear motor plus
any tuple of effects; :mod:`pmdc_ident.core.model` simulates them all. Where an
effect enters the equations::

    applied voltage  Va = delay(dead_zone(V_cmd))
    L(i) di/dt = Va - R(t) i - Ke w - brush(Va - Ke w)
    J dw/dt    = Kt i - B w - friction(w) - Cq w|w| - T_load - T_cog sin(N th + phi)
    measured current = i + I_offset

with ``friction(w) = (Tc + Ts exp(-(|w|/ws)^d)) sign(w)`` (``d`` = 2 the Gaussian,
1 the exponential Stribeck curve) while turning and a rotor
held at rest while ``|drive torque| <= Tc + Ts`` (stiction), ``R(t) = R (1 + k q)``
with ``dq/dt = i^2 - q/tau`` (first-order winding heating: ``q`` is the
dissipated ``int i^2 dt`` that has not yet flowed away; ``tau`` -> infinity is the
plain integral), ``Ke(t) = Ke (1 - r k q)`` and ``Kt`` likewise with the same heat
(magnets losing flux as they warm; ``r`` = 0, none, unless fitted) and
``L(i) = L / (1 + (i/I_sat)^2)``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any, ClassVar

from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.params import PARAMETER_UNITS

__all__ = [
    "EFFECT_NAMES",
    "NO_COOLING_S",
    "EFFECT_TYPES",
    "BrushDrop",
    "Cogging",
    "CoulombFriction",
    "CurrentOffset",
    "DeadZone",
    "Delay",
    "Effect",
    "InductanceSaturation",
    "LoadTorque",
    "QuadraticDrag",
    "ResistanceDrift",
    "StribeckFriction",
    "effect_from_mapping",
    "effects_from_mapping",
    "effects_to_mapping",
    "parameter_unit",
]


NO_COOLING_S = 1e6  # a winding time constant this long is the plain heat integral


@dataclass(frozen=True)
class ParamSpec:
    """Unit, physical range and a typical size of one effect parameter."""

    unit: str
    lower: float
    upper: float
    description: str
    fitted: bool = True
    # the value at which the effect is its one-parameter limit (the heat integral, the
    # hard brush drop): a fit holds the field there unless asked to free it
    limit: float | None = None


@dataclass(frozen=True)
class Effect:
    """Base class. Subclasses set NAME, DESCRIPTION and SPECS (one entry per field)."""

    NAME: ClassVar[str] = ""
    DESCRIPTION: ClassVar[str] = ""
    SPECS: ClassVar[dict[str, ParamSpec]] = {}

    def __post_init__(self) -> None:
        for f in fields(self):
            spec = self.SPECS[f.name]
            raw = getattr(self, f.name)
            try:
                value = float(raw)
            except (TypeError, ValueError):
                msg = f"{self.NAME}.{f.name} must be a number, got {raw!r}"
                raise ParameterError(msg) from None
            if not (math.isfinite(value) and spec.lower <= value <= spec.upper):
                msg = (
                    f"{self.NAME}.{f.name} ({spec.description}) must lie in "
                    f"[{spec.lower:g}, {spec.upper:g}] {spec.unit}, got {value:g}"
                )
                raise ParameterError(msg)
            object.__setattr__(self, f.name, value)

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    @classmethod
    def fitted_names(cls) -> tuple[str, ...]:
        return tuple(n for n, s in cls.SPECS.items() if s.fitted)

    def free_names(self) -> tuple[str, ...]:
        """The fields a fit estimates by default: the fitted ones but those held at
        their one-parameter limit (:attr:`ParamSpec.limit`)."""
        return tuple(
            n
            for n in self.fitted_names()
            if self.SPECS[n].limit is None or getattr(self, n) != self.SPECS[n].limit
        )


@dataclass(frozen=True)
class CoulombFriction(Effect):
    NAME: ClassVar[str] = "coulomb_friction"
    DESCRIPTION: ClassVar[str] = "torque opposing motion, constant in size"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "Coulomb friction torque"),
    }
    torque_nm: float


@dataclass(frozen=True)
class StribeckFriction(Effect):
    NAME: ClassVar[str] = "stribeck_friction"
    DESCRIPTION: ClassVar[str] = "extra breakaway torque at low speed"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "extra breakaway torque at rest"),
        "speed_rad_s": ParamSpec("rad/s", 1e-3, 1e4, "Stribeck speed"),
        # the shape of the fall: 1 Tustin's exponential, 2 the Gaussian (Armstrong);
        # measured curves lie between (a setting the diagnosis scans, not a fitted value)
        "shape_exponent": ParamSpec(
            "1", 0.5, 2.0, "exponent d of the fall exp(-(|w|/ws)^d)", False
        ),
    }
    torque_nm: float
    speed_rad_s: float
    shape_exponent: float = 2.0


@dataclass(frozen=True)
class QuadraticDrag(Effect):
    NAME: ClassVar[str] = "quadratic_drag"
    DESCRIPTION: ClassVar[str] = "torque proportional to w|w| (fan, propeller, air)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "coeff_nm_s2": ParamSpec("N*m*s^2/rad^2", 0.0, 1e3, "quadratic drag coefficient"),
    }
    coeff_nm_s2: float


@dataclass(frozen=True)
class LoadTorque(Effect):
    NAME: ClassVar[str] = "load_torque"
    DESCRIPTION: ClassVar[str] = "constant torque, direction-independent (e.g. a hanging mass)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", -1e4, 1e4, "load torque (positive opposes +w)"),
    }
    torque_nm: float


@dataclass(frozen=True)
class BrushDrop(Effect):
    NAME: ClassVar[str] = "brush_drop"
    DESCRIPTION: ClassVar[str] = (
        "voltage drop across the brushes with the sign of current: Vb tanh(i/i_knee), "
        "the hard sign at i_knee = 0"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "voltage_v": ParamSpec("V", 0.0, 100.0, "total brush voltage drop"),
        # a contact film conducts like a resistor at small current (slope Vb/i_knee)
        # and saturates at Vb above a few i_knee; 0 is the limit of a hard sign
        "knee_current_a": ParamSpec(
            "A", 0.0, 1e4, "current where the drop reaches 76 % of Vb", limit=0.0
        ),
    }
    voltage_v: float
    knee_current_a: float = 0.0  # the hard sign: a dead band on the driving voltage


@dataclass(frozen=True)
class DeadZone(Effect):
    NAME: ClassVar[str] = "dead_zone"
    DESCRIPTION: ClassVar[str] = "driver ignores commands smaller than a threshold"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "voltage_v": ParamSpec("V", 0.0, 1000.0, "dead-zone half width"),
    }
    voltage_v: float


@dataclass(frozen=True)
class Cogging(Effect):
    NAME: ClassVar[str] = "cogging"
    DESCRIPTION: ClassVar[str] = "torque periodic in shaft angle"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "torque_nm": ParamSpec("N*m", 0.0, 1e4, "cogging torque amplitude"),
        "periods_per_rev": ParamSpec("1/rev", 1.0, 1000.0, "cogging periods per turn", False),
        "phase_rad": ParamSpec("rad", -10.0, 10.0, "cogging phase"),
    }
    torque_nm: float
    periods_per_rev: float
    phase_rad: float = 0.0


@dataclass(frozen=True)
class ResistanceDrift(Effect):
    NAME: ClassVar[str] = "resistance_drift"
    DESCRIPTION: ClassVar[str] = (
        "winding heats, R rises: first-order heating by i^2 with a thermal time constant"
        " (the magnets' flux may fall with it)"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        # k = alpha R / C_th: 0.004 1/K x R over the winding's heat capacity; a coreless
        # micro-motor (20-100 ohm, 0.01-0.05 J/K) reaches 10-40, a milliamp one more
        "coeff_per_a2s": ParamSpec("1/(A^2*s)", 0.0, 1e4, "k in R(t) = R (1 + k q)"),
        "time_constant_s": ParamSpec(
            "s",
            0.1,
            NO_COOLING_S,
            "winding thermal time constant (dq/dt = i^2 - q/tau)",
            limit=NO_COOLING_S,
        ),
        # the magnets heat with the winding and lose flux: Ke(t) = Ke (1 - r k q), Kt
        # likewise. r is the relative fall of the flux per relative rise of R: a
        # magnet's coefficient over copper's (+0.39 %/K) times the magnets' temperature
        # rise over the winding's. NdFeB (-0.12 %/K) gives 0.31, ferrite (-0.2 %/K,
        # the steepest common magnet) 0.51, SmCo 0.09, each when the magnets get as hot
        # as the winding; they heat less and later (heated through the air gap, more
        # mass), so a physical r stays below ~0.5. The bound 1 (the flux never falls
        # faster than R rises) leaves room for the one heat state standing in for the
        # magnets' own. 0 is the limit: no weakening.
        "flux_loss_ratio": ParamSpec(
            "1", 0.0, 1.0, "r in Ke(t) = Ke (1 - r k q), Kt likewise", limit=0.0
        ),
    }
    coeff_per_a2s: float
    time_constant_s: float = NO_COOLING_S  # the plain integral within any run
    flux_loss_ratio: float = 0.0  # magnets that keep their flux


@dataclass(frozen=True)
class Delay(Effect):
    NAME: ClassVar[str] = "delay"
    DESCRIPTION: ClassVar[str] = (
        "command reaches the motor late: a transport delay, then a first-order lag"
    )
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "delay_s": ParamSpec("s", 0.0, 1.0, "transport delay"),
        # a drive's output filter or current loop: tau dVa/dt = V - Va; 0 is the limit of
        # a pure transport delay
        "lag_s": ParamSpec("s", 0.0, 1.0, "first-order lag time constant", limit=0.0),
    }
    delay_s: float
    lag_s: float = 0.0


@dataclass(frozen=True)
class CurrentOffset(Effect):
    NAME: ClassVar[str] = "current_offset"
    DESCRIPTION: ClassVar[str] = "current sensor reads non-zero at zero current"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "offset_a": ParamSpec("A", -1e3, 1e3, "current sensor offset"),
    }
    offset_a: float


@dataclass(frozen=True)
class InductanceSaturation(Effect):
    NAME: ClassVar[str] = "inductance_saturation"
    DESCRIPTION: ClassVar[str] = "L falls at high current: L(i) = L / (1 + (i/I_sat)^2)"
    SPECS: ClassVar[dict[str, ParamSpec]] = {
        "saturation_current_a": ParamSpec("A", 1e-3, 1e5, "current where L has halved"),
    }
    saturation_current_a: float


EFFECT_TYPES: dict[str, type[Effect]] = {
    cls.NAME: cls
    for cls in (
        CoulombFriction,
        StribeckFriction,
        QuadraticDrag,
        LoadTorque,
        BrushDrop,
        DeadZone,
        Cogging,
        ResistanceDrift,
        Delay,
        CurrentOffset,
        InductanceSaturation,
    )
}
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECT_TYPES)


def parameter_unit(name: str) -> str:
    """Unit of a motor parameter (``"R"``) or an effect parameter (``"<effect>.<field>"``).

    Raises :class:`ParameterError` for a name that is neither.
    """
    if name in PARAMETER_UNITS:
        return PARAMETER_UNITS[name]
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    if cls is None or fld not in cls.SPECS:
        msg = f"unknown parameter {name!r}"
        raise ParameterError(msg)
    return cls.SPECS[fld].unit


def effect_from_mapping(name: str, data: Any) -> Effect:
    """Build one effect from its vocabulary name and a mapping of its fields."""
    cls = EFFECT_TYPES.get(name)
    if cls is None:
        msg = f"unknown effect {name!r}; known: {', '.join(EFFECT_NAMES)}"
        raise ParameterError(msg)
    if not isinstance(data, dict):
        msg = f"effect {name} needs a mapping of its parameters {list(cls.SPECS)}"
        raise ParameterError(msg)
    unknown = sorted(set(data) - set(cls.SPECS))
    if unknown:
        msg = f"effect {name} has no parameter(s) {', '.join(unknown)}; known: {list(cls.SPECS)}"
        raise ParameterError(msg)
    try:
        return cls(**data)
    except TypeError:
        required = [f.name for f in fields(cls) if f.name not in data]
        msg = f"effect {name} lacks {', '.join(required)}"
        raise ParameterError(msg) from None


def effects_from_mapping(data: Any) -> tuple[Effect, ...]:
    """``{name: {field: value}}`` (as in the motor YAML files) to a tuple of effects."""
    if data is None:
        return ()
    if not isinstance(data, dict):
        msg = "effects must be a mapping of effect name to its parameters"
        raise ParameterError(msg)
    return tuple(effect_from_mapping(name, fields_) for name, fields_ in data.items())


def effects_to_mapping(effects: tuple[Effect, ...]) -> dict[str, dict[str, float]]:
    return {e.NAME: e.as_dict() for e in effects}
