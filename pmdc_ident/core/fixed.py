"""Parameter values the user fixes (``--fix NAME=VALUE``; the node's ``fix`` parameter)."""

from __future__ import annotations

import math
from collections.abc import Iterable

from pmdc_ident.core.effects import EFFECT_TYPES
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.params import PARAMETER_NAMES, check_physical_range

__all__ = ["parse_fix"]


def parse_fix(items: Iterable[str], known: tuple[str, ...] | None = None) -> dict[str, float]:
    """``--fix NAME=VALUE`` items (the CLI option and the identification node's ``fix``
    parameter): known names, physical values, no conflicting repeats.

    ``known``: the names that may be fixed (default: what identify can hold, the
    motor parameters, the Coulomb friction and a load torque).
    """
    if known is None:
        known = (*PARAMETER_NAMES, "coulomb_friction.torque_nm", "load_torque.torque_nm")
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            msg = f"--fix expects NAME=VALUE (e.g. L=3e-4), got {item!r}"
            raise ParameterError(msg)
        try:
            v = float(value)
        except ValueError:
            msg = f"--fix {name}: {value!r} is not a number"
            raise ParameterError(msg) from None
        if not math.isfinite(v):
            msg = f"--fix {name}: value must be finite, got {value!r}"
            raise ParameterError(msg)
        if name not in known:
            msg = f"--fix {name}: unknown parameter (known: {', '.join(known)})"
            raise ParameterError(msg)
        _check_fix_range(name, v)
        if name in out and out[name] != v:
            msg = f"--fix {name} given twice with different values ({out[name]:g} and {v:g})"
            raise ParameterError(msg)
        out[name] = v
    return out


def _check_fix_range(name: str, value: float) -> None:
    if name in PARAMETER_NAMES:
        check_physical_range(name, value, source="--fix")
        return
    effect, _, field_name = name.partition(".")
    spec = EFFECT_TYPES[effect].SPECS[field_name]
    if not spec.lower <= value <= spec.upper:
        msg = (
            f"--fix {name}={value:g}: outside the range of the {spec.description}, "
            f"[{spec.lower:g}, {spec.upper:g}] {spec.unit}"
        )
        raise ParameterError(msg)
