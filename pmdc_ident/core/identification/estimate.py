"""One estimated parameter and its JSON form, shared by ``identify`` and ``diagnose``.

JSON (docs/design.md, results): ``{value, ci95: [lo, hi] | null, unit, identifiable,
stderr, reason, method}``; non-finite numbers are written as ``null``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pmdc_ident.core.effects import parameter_unit
from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.errors import option_name as opt
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.params import NEEDED_PARAMETERS

__all__ = ["ParameterEstimate", "estimate_from_fit", "finite_or_none", "unidentified_needed"]


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or ``None`` when it is NaN or infinite (JSON has neither)."""
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class ParameterEstimate:
    """A parameter's value with its 95 % interval, unit and identifiability.

    ``reason`` says why it is not identifiable (or that it was fixed or assumed);
    ``method`` names the estimator that gave ``value``. An assumed value (Kt under the
    closure Kt = Ke, whose reason starts with ``assumed``) is written with
    ``identifiable: false``: the data did not give it.
    """

    name: str
    value: float
    ci95: tuple[float, float] | None
    unit: str
    identifiable: bool
    stderr: float | None = None
    reason: str = ""
    method: str = ""
    # what the reason says, by code (the reason's leading clause and an added gate note)
    notes: frozenset[ParameterNote] = frozenset()

    @property
    def assumed(self) -> bool:
        """Set by an assumption (the Kt = Ke closure), not measured."""
        return ParameterNote.ASSUMED in self.notes

    def to_json(self) -> dict[str, Any]:
        return {
            "value": finite_or_none(self.value),
            "ci95": None
            if self.ci95 is None
            else [finite_or_none(self.ci95[0]), finite_or_none(self.ci95[1])],
            "unit": self.unit,
            "identifiable": bool(self.identifiable) and not self.assumed,
            "stderr": None if self.stderr is None else finite_or_none(self.stderr),
            "reason": self.reason,
            "method": self.method,
        }


def estimate_from_fit(fit: FitResult, name: str, method: str) -> ParameterEstimate:
    """The estimate of ``name`` in an output-error fit (every model parameter has one)."""
    return ParameterEstimate(
        name=name,
        value=fit.values[name],
        ci95=fit.ci95.get(name),
        unit=parameter_unit(name),
        identifiable=fit.identifiable.get(name, True),
        stderr=fit.stderr.get(name),
        reason=fit.reasons.get(name, ""),
        method=method,
        notes=fit.notes.get(name, frozenset()),
    )


def unidentified_needed(
    params: Mapping[str, ParameterEstimate], free: Sequence[str]
) -> str | None:
    """The refusal when a free R, Ke or J is not identifiable (its value a guess), else None.

    One line: which, what would pin each (its flag's own advice) and that ``--fix``
    holds a known value. L, B and friction may stay flagged: a model runs with them.
    """
    bad = [
        n for n in NEEDED_PARAMETERS if n in free and n in params and not params[n].identifiable
    ]
    if not bad:
        return None
    tips = []
    for n in bad:
        why, _, tip = params[n].reason.partition("; ")
        tips.append(f"{n}: {tip or why or 'not identifiable'}")
    verb = "is" if len(bad) == 1 else "are"
    names = " and ".join([", ".join(bad[:-1]), bad[-1]] if len(bad) > 1 else bad)
    return (
        f"{names} {verb} not identifiable from these data (relative standard "
        f"error above 50 % or no information), so a motor model would hold a guess; "
        f"{'; '.join(tips)}; {opt('fix')} {bad[0]}=... holds a value you know; nothing was "
        "written"
    )
