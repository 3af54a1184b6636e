"""ROS-free numerics: motor model, effects, data containers (and, later, estimators).

The names below are imported on first use (PEP 562), so that importing a light
submodule such as :mod:`pmdc_ident.core.errors` (the command line does, to build
its help) does not pull in numpy, scipy or numba.
"""

from __future__ import annotations

from pmdc_ident._lazy import lazy_exports

# public name -> submodule of pmdc_ident.core that defines it
_SOURCES: dict[str, str] = {
    "Run": "data",
    "Segment": "data",
    "TestKind": "data",
    "EFFECT_NAMES": "effects",
    "EFFECT_TYPES": "effects",
    "Effect": "effects",
    "DataError": "errors",
    "ParameterError": "errors",
    "PmdcError": "errors",
    "Model": "model",
    "Plant": "model",
    "SimResult": "model",
    "simulate": "model",
    "simulate_linear": "model",
    "MotorSpec": "motors",
    "load_motor": "motors",
    "PARAMETER_NAMES": "params",
    "PARAMETER_UNITS": "params",
    "MotorParams": "params",
}

__all__ = sorted(_SOURCES)
__getattr__, __dir__ = lazy_exports(__name__, _SOURCES)
