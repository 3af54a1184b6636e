"""Unmodelled effects of the vocabulary (docs/design.md §4), as composable model additions.

Each effect is a frozen dataclass with its physical parameters (units in the field
names), one module per effect, and declares every hook the rest of the package needs
(:mod:`.base`). A :class:`~pmdc_ident.core.model.Model` is the linear motor plus any
tuple of effects; :mod:`pmdc_ident.core.model` simulates them all. Where an effect
enters the equations::

    applied voltage  Va = delay(dead_zone(V_cmd))
    L(i) di/dt = Va - R(t) i - Ke w - brush(Va - Ke w)
    J dw/dt    = Kt i - B w - friction(w) - mu |Kt i| sign(w) - Cq w|w| - T_load
                 - T_cog sin(N th + phi)
    measured current = i + I_offset

with ``friction(w) = (Tc + Ts exp(-(|w|/ws)^d)) sign(w)`` (``d`` = 2 the Gaussian,
1 the exponential Stribeck curve) while turning and a rotor
held at rest while ``|drive torque| <= Tc + Ts`` (stiction), ``R(t) = R (1 + k q)``
with ``dq/dt = i^2 - q/tau`` (first-order winding heating: ``q`` is the
dissipated ``int i^2 dt`` that has not yet flowed away; ``tau`` -> infinity is the
plain integral), ``Ke(t) = Ke (1 - r k q)`` and ``Kt`` likewise with the same heat
(magnets losing flux as they warm; ``r`` = 0, none, unless fitted) and
``L(i) = L / (1 + (i/I_sat)^2)``; ``mu |Kt i|`` (a torque-dependent friction) also adds
to what static friction can hold.

:data:`EFFECT_TYPES` is the registry (name -> class, in vocabulary order): adding an
effect is one module here, one line below, its kernel lines in
:mod:`pmdc_ident.core.model` and its tests (docs/adding-an-effect.md).
"""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from pmdc_ident.core.effects import layout
from pmdc_ident.core.effects.base import (
    CandidateContext,
    DataScales,
    DetectionProbe,
    Effect,
    Ladder,
    MujocoContext,
    MujocoTerms,
    ParamSpec,
    RecordScales,
    SimPath,
)
from pmdc_ident.core.effects.brush_drop import BrushDrop
from pmdc_ident.core.effects.cogging import Cogging
from pmdc_ident.core.effects.coulomb_friction import CoulombFriction
from pmdc_ident.core.effects.current_offset import CurrentOffset
from pmdc_ident.core.effects.dead_zone import DeadZone
from pmdc_ident.core.effects.delay import Delay
from pmdc_ident.core.effects.inductance_saturation import InductanceSaturation
from pmdc_ident.core.effects.load_torque import LoadTorque
from pmdc_ident.core.effects.quadratic_drag import QuadraticDrag
from pmdc_ident.core.effects.resistance_drift import NO_COOLING_S, ResistanceDrift
from pmdc_ident.core.effects.stribeck_friction import StribeckFriction
from pmdc_ident.core.effects.torque_dependent_friction import TorqueDependentFriction
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.params import PARAMETER_UNITS

__all__ = [
    "DEFAULT_CANDIDATES",
    "EFFECT_NAMES",
    "EFFECT_TYPES",
    "NO_COOLING_S",
    "BrushDrop",
    "CandidateContext",
    "Cogging",
    "CoulombFriction",
    "CurrentOffset",
    "DataScales",
    "DeadZone",
    "Delay",
    "DetectionProbe",
    "Effect",
    "InductanceSaturation",
    "Ladder",
    "LoadTorque",
    "MujocoContext",
    "MujocoTerms",
    "ParamSpec",
    "QuadraticDrag",
    "RecordScales",
    "ResistanceDrift",
    "SimPath",
    "StribeckFriction",
    "TorqueDependentFriction",
    "effect_from_mapping",
    "effects_from_mapping",
    "effects_to_mapping",
    "layout",
    "parameter_unit",
]

#: the registry, in vocabulary order (the order candidates are tried and listed in)
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
        TorqueDependentFriction,
    )
}
EFFECT_NAMES: tuple[str, ...] = tuple(EFFECT_TYPES)
#: what the diagnosis tries unless given a list (the others are opt-in)
DEFAULT_CANDIDATES: tuple[str, ...] = tuple(
    n for n, cls in EFFECT_TYPES.items() if cls.DEFAULT_CANDIDATE
)


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
