"""ROS-free numerics: motor model, effects, data containers (and, later, estimators)."""

from __future__ import annotations

from pmdc_ident.core.data import Run, Segment, TestKind
from pmdc_ident.core.effects import EFFECT_NAMES, EFFECT_TYPES, Effect
from pmdc_ident.core.errors import DataError, ParameterError, PmdcError
from pmdc_ident.core.model import Model, Plant, SimResult, simulate, simulate_linear
from pmdc_ident.core.motors import MotorSpec, load_motor
from pmdc_ident.core.params import PARAMETER_NAMES, PARAMETER_UNITS, MotorParams

__all__ = [
    "EFFECT_NAMES",
    "EFFECT_TYPES",
    "PARAMETER_NAMES",
    "PARAMETER_UNITS",
    "DataError",
    "Effect",
    "Model",
    "MotorParams",
    "MotorSpec",
    "ParameterError",
    "Plant",
    "PmdcError",
    "Run",
    "Segment",
    "SimResult",
    "TestKind",
    "load_motor",
    "simulate",
    "simulate_linear",
]
