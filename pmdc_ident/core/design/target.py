"""What a designed experiment must reach: a relative standard deviation per parameter.

The default is every identifiable parameter of the fitted model to 1 % (R, L, Ke, J,
B) and the Coulomb friction torque to 5 %. Written as ``R=1%,Tc=5%,L=off`` (a bare
number is a fraction: ``J=0.005``); ``off`` drops a parameter from the target (it is
still fitted). ``coulomb_friction.torque_nm`` and ``coulomb`` name ``Tc``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from pmdc_ident.core.errors import ParameterError

__all__ = ["DEFAULT_TARGET", "TARGET_NAMES", "describe_target", "parse_target", "public_name"]

DEFAULT_TARGET: dict[str, float] = {
    "R": 0.01,
    "L": 0.01,
    "Ke": 0.01,
    "J": 0.01,
    "B": 0.01,
    "Tc": 0.05,
}
TARGET_NAMES: tuple[str, ...] = tuple(DEFAULT_TARGET)
_ALIASES = {"coulomb_friction.torque_nm": "Tc", "coulomb": "Tc", "coulomb_friction": "Tc"}
# the name a user reads in identify's output
_PUBLIC = {"Tc": "coulomb_friction.torque_nm"}


def public_name(name: str) -> str:
    return _PUBLIC.get(name, name)


def parse_target(text: str | None, base: Mapping[str, float] | None = None) -> dict[str, float]:
    """``R=1%,J=0.5%,L=off`` over ``base`` (default :data:`DEFAULT_TARGET`)."""
    out = dict(DEFAULT_TARGET if base is None else base)
    if text is None or not text.strip():
        return out
    for item in text.split(","):
        if not item.strip():
            continue
        name, sep, value = item.partition("=")
        name = _ALIASES.get(name.strip(), name.strip())
        if not sep or name not in TARGET_NAMES:
            msg = (
                f"target {item.strip()!r}: expected NAME=VALUE with NAME one of "
                f"{', '.join(TARGET_NAMES)} (e.g. R=1%,Tc=5%,L=off)"
            )
            raise ParameterError(msg)
        value = value.strip().lower()
        if value in ("off", "none", "-"):
            out.pop(name, None)
            continue
        pct = value.endswith("%")
        try:
            v = float(value.rstrip("%")) / (100.0 if pct else 1.0)
        except ValueError:
            msg = f"target {name}: {value!r} is not a number (e.g. {name}=1% or {name}=0.01)"
            raise ParameterError(msg) from None
        if not (math.isfinite(v) and 0.0 < v < 1.0):
            msg = f"target {name}: a relative sd in (0, 100 %), got {value}"
            raise ParameterError(msg)
        out[name] = v
    if not out:
        msg = "the target names no parameter"
        raise ParameterError(msg)
    return out


def describe_target(target: Mapping[str, float]) -> str:
    return ", ".join(f"{public_name(k)} {100 * v:.3g} %" for k, v in target.items())
