"""A diagnosis' model as a motor to export: the named effects with their fitted values.

``pmdc-ident diagnose --json DIAG.json`` writes the diagnosis document (docs/design.md
§4): ``verdict.effects`` names the effects, ``parameters`` holds the augmented model's
values (``R``, ``L``, ``Ke``, ``Kt``, ``J``, ``B`` and ``"<effect>.<field>"``), fitted
together on the fit segments and judged on the held-out ones. :func:`motor_with_diagnosis`
turns that into a :class:`~pmdc_ident.core.motors.MotorSpec`: the diagnosis' model with
the motor file's name, sensors and limits. A diagnosis that names no effect leaves the
motor file as it is.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from pmdc_ident.core.effects import EFFECT_TYPES, effects_from_mapping
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.core.params import PARAMETER_NAMES, MotorParams

__all__ = ["DiagnosedMotor", "load_diagnosis", "motor_with_diagnosis"]

# the motor file and the diagnosis must describe one motor: its back-EMF constant and
# its resistance agree within this factor (a wrong pair is an error, not an export)
SAME_MOTOR_FACTOR = 1.5


@dataclass(frozen=True)
class DiagnosedMotor:
    """The motor to export and what the diagnosis contributed."""

    spec: MotorSpec
    status: str  # the diagnosis' verdict
    effects: tuple[str, ...]  # named effects now in the model
    lines: tuple[str, ...]  # what was done, one line each (printed by export-model)


def load_diagnosis(path: str | Path) -> dict[str, Any]:
    """The document ``pmdc-ident diagnose --json`` writes, checked for what the export
    needs (one clear line when it is not one)."""
    p = Path(path)
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        msg = f"--diagnosis {p}: no such file"
        raise ParameterError(msg) from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        msg = f"--diagnosis {p}: not a JSON document ({exc})"
        raise ParameterError(msg) from None
    _check_document(doc, str(p))
    return doc  # type: ignore[no-any-return]


def _check_document(doc: object, source: str) -> None:
    if not isinstance(doc, dict) or not isinstance(doc.get("verdict"), dict):
        msg = (
            f"{source}: not a diagnosis (no 'verdict'); write one with pmdc-ident diagnose --json"
        )
        raise ParameterError(msg)
    v = doc["verdict"]
    if not isinstance(v.get("effects"), list) or not isinstance(v.get("status"), str):
        msg = f"{source}: the diagnosis' verdict has no 'status' and 'effects'"
        raise ParameterError(msg)
    if v["effects"] and not isinstance(doc.get("parameters"), dict):
        msg = f"{source}: the diagnosis names {', '.join(v['effects'])} but has no 'parameters'"
        raise ParameterError(msg)


def _value(params: Mapping[str, Any], key: str, source: str) -> float:
    entry = params.get(key)
    raw = entry.get("value") if isinstance(entry, dict) else entry
    try:
        x = float(raw)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        msg = f"{source}: parameter {key!r} has no numeric value"
        raise ParameterError(msg) from None
    if not math.isfinite(x):
        msg = f"{source}: parameter {key!r} is {x}"
        raise ParameterError(msg)
    return x


def motor_with_diagnosis(
    spec: MotorSpec,
    diagnosis: Mapping[str, Any],
    source: str = "diagnosis",
    *,
    same_motor: bool = True,
) -> DiagnosedMotor:
    """``spec`` with the diagnosis' model: its parameters and named effects (the motor
    file's name, sensors and limits kept). ``diagnosis`` is the JSON document (or
    ``DiagnosisResult.to_json()``). ``same_motor``: refuse a diagnosis whose Ke or R is
    not the motor file's (a wrong pair of files)."""
    _check_document(diagnosis, source)
    verdict = diagnosis["verdict"]
    status = str(verdict["status"])
    names = tuple(str(n) for n in verdict["effects"])
    unknown = [n for n in names if n not in EFFECT_TYPES]
    if unknown:
        msg = f"{source}: unknown effect(s) {', '.join(unknown)}"
        raise ParameterError(msg)
    if not names:
        line = f"the diagnosis names no effect ({status}): the motor file is exported as it is"
        return DiagnosedMotor(spec, status, (), (line,))
    params = diagnosis["parameters"]
    base = MotorParams(**{k: _value(params, k, source) for k in PARAMETER_NAMES})
    if same_motor:
        _check_same_motor(spec.model.params, base, source)
    mapping = {
        n: {
            f: _value(params, f"{n}.{f}", source)
            for f in EFFECT_TYPES[n].SPECS
            if f"{n}.{f}" in params
        }  # fmt: skip
        for n in names
    }
    effects = effects_from_mapping(mapping)
    lines = [
        f"the diagnosis ({status}: {', '.join(names)}) replaces the motor file's model: its "
        "parameters and effects, fitted together on the diagnosis' fit segments",
    ]
    dropped = [e.NAME for e in spec.model.effects if e.NAME not in names]
    if dropped:
        lines.append(f"the motor file's {', '.join(dropped)} is left out (the diagnosis' model "
                     "does not have it)")  # fmt: skip
    out = replace(spec, model=Model(base, effects))
    return DiagnosedMotor(out, status, names, tuple(lines))


def _check_same_motor(a: MotorParams, b: MotorParams, source: str) -> None:
    for name in ("Ke", "R"):
        x, y = getattr(a, name), getattr(b, name)
        if not (x > 0 and y > 0) or max(x / y, y / x) > SAME_MOTOR_FACTOR:
            msg = (
                f"{source}: the diagnosis' {name} = {y:.4g} and the motor file's {x:.4g} are "
                "not one motor; give the motor file identified from the same data"
            )
            raise ParameterError(msg)
