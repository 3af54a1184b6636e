"""The fit's parameter vocabulary: motor parameters and ``"<effect>.<field>"`` names,
their bounds and scaling, and models built from a name -> value mapping."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

from pmdc_ident.core.effects import EFFECT_TYPES, Effect
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

__all__ = [
    "FitParameter",
    "at_limit",
    "build_model",
    "is_fitted_field",
    "model_values",
    "parameter_info",
]


@dataclass(frozen=True)
class FitParameter:
    """A fitted parameter's bounds; ``log``: fitted as log(value) (positive parameters)."""

    name: str
    lower: float
    upper: float
    log: bool


def model_values(model: Model) -> dict[str, float]:
    """Every parameter of ``model`` by name: ``R..B``, then ``"<effect>.<field>"``."""
    vals = dict(model.params.as_dict())
    for e in model.effects:
        for fname, v in e.as_dict().items():
            vals[f"{e.NAME}.{fname}"] = float(v)
    return vals


def parameter_info(name: str) -> FitParameter:
    """Bounds and scaling of a parameter name (motor parameters: positive, log scale)."""
    if name in PARAMETER_NAMES:
        return FitParameter(name, 0.0, math.inf, True)
    eff, _, fld = name.partition(".")
    spec = EFFECT_TYPES[eff].SPECS[fld]
    # a positive scale, or one whose limit is its lower bound (freed only when above it)
    log = spec.lower > 0.0 or spec.limit == spec.lower
    return FitParameter(name, spec.lower, spec.upper, log)


def build_model(base: Model, values: Mapping[str, float]) -> Model:
    """``base``'s structure (same effects) with the parameter ``values`` by name."""
    params = MotorParams(**{n: values[n] for n in PARAMETER_NAMES})
    effects: list[Effect] = []
    for e in base.effects:
        data = {f: values[f"{e.NAME}.{f}"] for f in e.as_dict()}
        effects.append(type(e)(**data))
    return Model(params, tuple(effects))


def is_fitted_field(name: str) -> bool:
    """An ``"<effect>.<field>"`` the fit estimates (not a setting like a period count)."""
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    return cls is not None and cls.SPECS[fld].fitted


def at_limit(name: str, value: float) -> bool:
    """An ``"<effect>.<field>"`` at its effect's one-parameter limit (held by default)."""
    eff, _, fld = name.partition(".")
    cls = EFFECT_TYPES.get(eff)
    return cls is not None and cls.SPECS[fld].limit == value
