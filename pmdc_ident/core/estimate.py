"""One estimated parameter and its JSON form, shared by ``identify`` and ``diagnose``.

JSON (docs/design.md, results): ``{value, ci95: [lo, hi] | null, unit, identifiable,
stderr, reason, method}``; non-finite numbers are written as ``null``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from pmdc_ident.core.effects import parameter_unit
from pmdc_ident.core.estimators.output_error import FitResult

__all__ = ["ParameterEstimate", "estimate_from_fit", "finite_or_none"]


def finite_or_none(x: float) -> float | None:
    """``x`` as a float, or ``None`` when it is NaN or infinite (JSON has neither)."""
    x = float(x)
    return x if math.isfinite(x) else None


@dataclass(frozen=True)
class ParameterEstimate:
    """A parameter's value with its 95 % interval, unit and identifiability.

    ``reason`` says why it is not identifiable (or that it was fixed or assumed);
    ``method`` names the estimator that gave ``value``.
    """

    name: str
    value: float
    ci95: tuple[float, float] | None
    unit: str
    identifiable: bool
    stderr: float | None = None
    reason: str = ""
    method: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "value": finite_or_none(self.value),
            "ci95": None
            if self.ci95 is None
            else [finite_or_none(self.ci95[0]), finite_or_none(self.ci95[1])],
            "unit": self.unit,
            "identifiable": bool(self.identifiable),
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
    )
