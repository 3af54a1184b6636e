"""What the diagnosis tries and how it decides (:class:`DiagnosisConfig`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pmdc_ident.core.diagnosis.verdict import Thresholds
from pmdc_ident.core.effects import DEFAULT_CANDIDATES, EFFECT_NAMES
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.fixed import FixedValues
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

__all__ = ["DiagnosisConfig"]


@dataclass(frozen=True)
class DiagnosisConfig:
    """What the diagnosis tries and how it decides.

    ``holdout``: segment labels to hold out (default: the split of
    :mod:`~pmdc_ident.core.diagnosis.holdout`). ``effects``: the vocabulary to
    try (default: every registered effect but the opt-in ones). ``fixed``:
    parameters held at known values (e.g. ``{"L": 3e-4}`` from an LCR meter).
    ``initial``: starting parameters (e.g. from ``identify``). ``swap``: when the
    default split finds no gap, look again with its sides swapped
    (:func:`~pmdc_ident.core.diagnosis.pipeline.diagnose`).
    """

    holdout: tuple[str, ...] = ()
    effects: tuple[str, ...] = DEFAULT_CANDIDATES
    max_effects: int = 3
    fixed: Mapping[str, float] = field(default_factory=dict)
    initial: MotorParams | None = None
    max_nfev: int = 30
    workers: int = 2
    thresholds: Thresholds = field(default_factory=Thresholds)
    swap: bool = True
    detection_limits: bool = True  # per effect, the smallest size the record could show

    def __post_init__(self) -> None:
        unknown = [e for e in self.effects if e not in EFFECT_NAMES]
        if unknown:
            msg = f"unknown effect(s) {', '.join(unknown)}; known: {', '.join(EFFECT_NAMES)}"
            raise ParameterError(msg)
        # the motor parameters only (the candidates' effect fields are what it fits)
        object.__setattr__(self, "fixed", FixedValues(self.fixed, known=PARAMETER_NAMES))
        if self.max_effects < 1 or self.workers < 1 or self.max_nfev < 1:
            msg = "max_effects, workers and max_nfev must be >= 1"
            raise ParameterError(msg)
        object.__setattr__(self, "holdout", tuple(self.holdout))
        object.__setattr__(self, "effects", tuple(self.effects))
