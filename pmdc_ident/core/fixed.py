"""Parameter values the user fixes (option ``fix``: ``--fix NAME=VALUE`` on the command
line, the identification node's ``fix`` parameter).

:class:`FixedValues` is the one type of held values: the command line's and the node's
``NAME=VALUE`` items (:func:`parse_fix`), ``identify(fixed=...)`` and
``DiagnosisConfig(fixed=...)`` all check theirs through it, by one rule: a name the
caller can hold, a finite value in the parameter's physical range (a motor
parameter's :data:`~pmdc_ident.core.params.PARAMETER_RANGES`, an effect field's
:class:`~pmdc_ident.core.effects.ParamSpec`), never two different values for one name.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator, Mapping

from pmdc_ident.core.effects import EFFECT_TYPES
from pmdc_ident.core.errors import OptionError
from pmdc_ident.core.params import PARAMETER_NAMES, physical_range_problem

__all__ = ["IDENTIFY_FIXABLE", "FixedValues", "parse_fix"]

#: what identify can hold: the motor parameters, the Coulomb friction and a load torque
IDENTIFY_FIXABLE: tuple[str, ...] = (
    *PARAMETER_NAMES,
    "coulomb_friction.torque_nm",
    "load_torque.torque_nm",
)


class FixedValues(Mapping[str, float]):
    """Held parameter values by name (``"R"``, ``"coulomb_friction.torque_nm"``), each
    checked; an immutable mapping.

    ``known``: the names the caller can hold (default :data:`IDENTIFY_FIXABLE`);
    ``option``: the key of the option the values came from (an error names it in the
    caller's words, :class:`~pmdc_ident.core.errors.OptionError`).
    """

    __slots__ = ("_values",)

    def __init__(
        self,
        values: Mapping[str, float] | Iterable[tuple[str, float]] = (),
        *,
        known: Iterable[str] | None = None,
        option: str = "fix",
    ) -> None:
        names = tuple(IDENTIFY_FIXABLE if known is None else known)
        pairs = values.items() if isinstance(values, Mapping) else values
        out: dict[str, float] = {}
        for name, raw in pairs:
            name = str(name)
            try:
                v = float(raw)
            except (TypeError, ValueError):
                raise OptionError(option, raw, f"{name}: {raw!r} is not a number") from None
            if not math.isfinite(v):
                raise OptionError(option, raw, f"{name}: value must be finite, got {raw!r}")
            if name not in names:
                why = f"{name}: unknown parameter (can be fixed: {', '.join(names)})"
                raise OptionError(option, name, why)
            _check_range(name, v, option)
            if name in out and out[name] != v:
                why = f"{name} given twice with different values ({out[name]:g} and {v:g})"
                raise OptionError(option, raw, why)
            out[name] = v
        self._values = out

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __repr__(self) -> str:
        return f"FixedValues({self._values!r})"

    def __eq__(self, other: object) -> bool:
        return dict(self._values) == dict(other) if isinstance(other, Mapping) else False

    def __hash__(self) -> int:
        return hash(tuple(sorted(self._values.items())))

    def __reduce__(self) -> tuple[object, ...]:
        # to a child process (the node's worker) as what it is, checked again there
        return (_rebuild, (tuple(self._values.items()),))


def _rebuild(items: tuple[tuple[str, float], ...]) -> FixedValues:
    return FixedValues(items, known=[n for n, _ in items])


def parse_fix(items: Iterable[str], known: tuple[str, ...] | None = None) -> FixedValues:
    """``NAME=VALUE`` items of option ``fix`` (the CLI's ``--fix``, the identification
    node's ``fix`` parameter) as :class:`FixedValues`.

    ``known``: the names that may be fixed (default :data:`IDENTIFY_FIXABLE`).
    """
    pairs: list[tuple[str, str]] = []
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep or not name:
            raise OptionError("fix", item, f"expects NAME=VALUE (e.g. L=3e-4), got {item!r}")
        pairs.append((name, value))
    return FixedValues(pairs, known=known)


def _check_range(name: str, value: float, option: str) -> None:
    if name in PARAMETER_NAMES:
        problem = physical_range_problem(name, value)
        if problem:
            raise OptionError(option, value, f"{name}={value:g}: {problem}")
        return
    effect, _, field_name = name.partition(".")
    cls = EFFECT_TYPES.get(effect)
    spec = cls.SPECS.get(field_name) if cls is not None else None
    if spec is None:
        raise OptionError(option, name, f"{name}: unknown parameter")
    if not spec.lower <= value <= spec.upper:
        why = (
            f"{name}={value:g}: outside the range of the {spec.description}, "
            f"[{spec.lower:g}, {spec.upper:g}] {spec.unit}"
        )
        raise OptionError(option, value, why)
