"""What the steps of :func:`~pmdc_ident.core.identification.identify.identify` share:
the checked inputs (:class:`_Setup`, with the output-error fit they imply) and what
the steps add to the result as they go (:class:`_Report`, warnings by code)."""

from __future__ import annotations

import enum
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from pmdc_ident.core.data import Segment
from pmdc_ident.core.estimators.output_error import FitResult, fit_output_error
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import PARAMETER_NAMES

__all__ = ["ModelChoice", "WarningCode"]


class ModelChoice(enum.StrEnum):
    """Which model the output-error fit reports (auto: Coulomb when significant)."""

    AUTO = "auto"
    LINEAR = "linear"
    COULOMB = "coulomb"


@dataclass(frozen=True)
class _Setup:
    """The checked inputs of one identification."""

    segments: list[Segment]
    dynamic: list[Segment]  # long, regularly sampled: for the dynamic methods
    fixed: dict[str, float]
    closure: str | None  # the closure actually used
    added: dict[str, float]  # known added inertia by segment label, kg*m^2
    current_mode: bool  # no voltage column: mechanical side only

    def fit(self, segs: Sequence[Segment], model: Model, **kwargs: Any) -> FitResult:
        """The output-error fit of ``model`` on ``segs`` with this setup's fixed values,
        closure and added inertia."""
        return fit_output_error(
            segs,
            model,
            fixed=_fixed_for(self.fixed, model),
            closure=self.closure,
            added_inertia=_added_for(self.added, segs),
            **kwargs,
        )


class WarningCode(enum.Enum):
    """Warnings a later step of :func:`identify` looks for (by code, not by its text)."""

    OUTPUT_ERROR_FAILED = "output-error-failed"  # a model's output-error fit failed
    SEGMENTS_WITH_GAPS = "segments-with-gaps"  # segments left out for gaps in time


@dataclass
class _Report:
    """What the steps add to the result as they go."""

    assumptions: list[str]
    warnings: list[str] = field(default_factory=list)
    methods: dict[str, dict[str, Any]] = field(default_factory=dict)
    validation: dict[str, Any] = field(default_factory=dict)
    said: dict[str, str] = field(default_factory=dict)  # register entry -> what was done
    coded: dict[WarningCode, list[str]] = field(default_factory=dict)

    def warn(self, code: WarningCode, text: str) -> None:
        """A warning of the result that a later step may look for by ``code``."""
        self.warnings.append(text)
        self.coded.setdefault(code, []).append(text)


def _added_for(added: Mapping[str, float], segs: Sequence[Segment]) -> dict[str, float]:
    labels = {s.label for s in segs}
    return {k: v for k, v in added.items() if k in labels}


def _fixed_for(fixed: Mapping[str, float], m: Model) -> dict[str, float]:
    names = set(PARAMETER_NAMES) | {f"{e.NAME}.{f}" for e in m.effects for f in e.as_dict()}
    return {k: v for k, v in fixed.items() if k in names}
