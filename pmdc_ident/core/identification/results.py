"""Identification results: parameter estimates, method comparison, JSON and motor YAML.

JSON (docs/design.md §4, schema in docs/integration.md): ``schema_version``
(:data:`pmdc_ident.core.schema.SCHEMA_VERSION`), ``sources``,
``parameters.{R,L,Ke,Kt,J,B}`` each ``{value, ci95: [lo, hi] |
null, unit, identifiable}`` (plus ``stderr``, ``reason``), effect parameters as
``parameters["<effect>.<name>"]``; then ``assumptions``, ``warnings``,
``methods`` (each method's estimates, for comparison), ``validation``
(held-out free-run error, residual whiteness, bootstrap check of the
intervals), ``transfer_functions`` (seed 001's eq. 4-5 form) and ``fit``.

The YAML is a motor file of :mod:`pmdc_ident.core.motors`, so
``load_motor(path)`` (and the simulated driver) reads it: identify -> simulate.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pmdc_ident.core.enums import ParameterNote
from pmdc_ident.core.estimators.output_error import FitResult
from pmdc_ident.core.identification.estimate import ParameterEstimate, finite_or_none
from pmdc_ident.core.model import Model
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec, motor_to_yaml
from pmdc_ident.core.schema import SCHEMA_VERSION

# the first line of every motor file identify writes (command line and node alike)
MOTOR_YAML_HEADER = "# Motor file written by `pmdc-ident identify`; load_motor(path) reads it.\n"

__all__ = [
    "MOTOR_YAML_HEADER",
    "IdentificationResult",
    "format_polynomial",
    "transfer_function_dict",
]


def format_polynomial(coeffs: list[float], var: str = "s") -> str:
    n = len(coeffs) - 1
    terms = []
    for k, c in enumerate(coeffs):
        p = n - k
        mag = f"{abs(c):.4g}"
        if p == 0:
            t = mag
        elif p == 1:
            t = var if mag == "1" else f"{mag} {var}"
        else:
            t = f"{var}^{p}" if mag == "1" else f"{mag} {var}^{p}"
        sign = "-" if c < 0 else "+"
        terms.append((sign, t))
    out = ("-" if terms[0][0] == "-" else "") + terms[0][1]
    for sign, t in terms[1:]:
        out += f" {sign} {t}"
    return out


# notes shown in the table's note column although the parameter is identifiable
_SHOWN = frozenset(ParameterNote) - {ParameterNote.ASSUMED}


def transfer_function_dict(model: Model) -> dict[str, Any]:
    """I/V and w/V in seed 001's eq. 4-5 form (J-normalised), with readable text."""
    tf = model.params.transfer_functions()
    out: dict[str, Any] = {}
    for key, (num, den) in tf.items():
        lhs = "I(s)/V(s)" if key.startswith("current") else "W(s)/V(s)"
        out[key] = {
            "num": [float(c) for c in num],
            "den": [float(c) for c in den],
            "text": f"{lhs} = ({format_polynomial(num)}) / ({format_polynomial(den)})",
        }
    return out


@dataclass(frozen=True)
class IdentificationResult:
    """Everything ``pmdc-ident identify`` reports."""

    sources: tuple[str, ...]
    model_kind: str  # "linear", "coulomb", "mechanical", "classical"
    model: Model
    parameters: dict[str, ParameterEstimate]
    assumptions: tuple[str, ...]
    warnings: tuple[str, ...]
    methods: dict[str, dict[str, Any]]
    validation: dict[str, Any]
    noise: dict[str, float]
    fit: FitResult | None = field(default=None, repr=False)
    frequency: Any = field(default=None, repr=False)
    fit_info: dict[str, Any] = field(default_factory=dict)
    limits: Limits = field(default_factory=Limits)
    # the assumption register's reading of the data and what it changed (JSON key
    # ``assumptions_checked``, the same function for every command: core/assumptions.py)
    assumptions_checked: dict[str, Any] = field(default_factory=dict)

    # -- text -----------------------------------------------------------------
    def table(self) -> str:
        lines = [f"{'parameter':<28} {'value':>12}  {'95 % interval':<26} {'unit':<11} note"]
        for p in self.parameters.values():
            if p.ci95 is None:
                ci = "-"
            else:
                ci = f"[{p.ci95[0]:.5g}, {p.ci95[1]:.5g}]"
            note = "" if p.identifiable else "NOT IDENTIFIABLE"
            if p.assumed:  # a closure: said as what it is
                note = p.reason
            elif p.reason and (not p.identifiable or p.notes & _SHOWN):
                note = (note + " " + p.reason).strip() if not p.identifiable else p.reason
            lines.append(f"{p.name:<28} {p.value:>12.6g}  {ci:<26} {p.unit:<11} {note}")
        return "\n".join(lines)

    @property
    def mechanical_only(self) -> bool:
        """A fit of the mechanical side alone (current-driven data): no electrical model."""
        return self.model_kind == "mechanical"

    def text_report(self) -> str:
        out = [f"model: {self.model_kind}  (data: {', '.join(self.sources)})", self.table()]
        out.append("assumptions:")
        out += [f"  - {a}" for a in self.assumptions]
        if self.warnings:
            out.append("warnings:")
            out += [f"  - {w}" for w in self.warnings]
        if self.mechanical_only:
            out.append(
                "transfer functions: none (mechanical-only fit: R, L and Ke are not measured "
                "here, so I(s)/V(s) and W(s)/V(s) would be built from placeholders)"
            )
        else:
            tf = transfer_function_dict(self.model)
            out.append("transfer functions (seed 001 eq. 4-5 form):")
            out += [f"  {v['text']}" for v in tf.values()]
        for m, info in self.methods.items():
            notes = info.get("notes") or []
            if notes:
                out.append(f"notes ({m}):")
                out += [f"  - {n}" for n in notes]
        comp = self.method_table()
        if comp:
            out.append("method comparison:")
            out.append(comp)
        ho = self.validation.get("holdout")
        if ho:
            txt = ", ".join(f"{k} {v:.4g}" for k, v in ho["rms"].items())
            out.append(f"validation: free-run rms on held-out {', '.join(ho['labels'])}: {txt}")
        return "\n".join(out)

    def method_table(self) -> str:
        names = ["R", "L", "Ke", "Kt", "J", "B", "coulomb_friction.torque_nm"]
        methods = [m for m in self.methods if self.methods[m].get("values")]
        if not methods:
            return ""
        width = max(12, *(len(m) for m in methods))
        head = f"  {'parameter':<28}" + "".join(f"{m:>{width + 2}}" for m in methods)
        rows = [head]
        for n in names:
            cells = []
            for m in methods:
                v = self.methods[m]["values"].get(n)
                cells.append(f"{v:>{width + 2}.5g}" if v is not None else f"{'-':>{width + 2}}")
            rows.append(f"  {n:<28}" + "".join(cells))
        return "\n".join(rows)

    # -- files ----------------------------------------------------------------
    def to_json_dict(self) -> dict[str, Any]:
        return _jsonable(
            {
                "schema_version": SCHEMA_VERSION,
                "sources": list(self.sources),
                "model": self.model_kind,
                "parameters": {k: p.to_json() for k, p in self.parameters.items()},
                "assumptions": list(self.assumptions),
                "warnings": list(self.warnings),
                "methods": self.methods,
                "validation": self.validation,
                "transfer_functions": {}
                if self.mechanical_only
                else transfer_function_dict(self.model),
                "noise": self.noise,
                "fit": self.fit_info,
                "assumptions_checked": self.assumptions_checked,
            }
        )

    def write_json(self, path: str | Path) -> Path:
        from pmdc_ident.core.safe_write import write_text

        return write_text(path, json.dumps(self.to_json_dict(), indent=2, allow_nan=False) + "\n")

    def motor_spec(self, name: str = "identified") -> MotorSpec:
        """The identified motor as a motor file: a value the fit ran outside the physical
        range (flagged in the result) is carried at the nearest end of the range, so
        ``load_motor`` and ``export-model`` accept what identify writes; the description
        says which."""
        sensors = SensorSpec(
            current_noise_a=float(self.noise.get("current", 0.0)),
            speed_noise_rad_s=float(self.noise.get("speed", 0.0)),
        )
        model, clamped = _in_range(self.model)
        note = f"; {clamped}" if clamped else ""
        return MotorSpec(
            name=name,
            model=model,
            sensors=sensors,
            limits=self.limits,
            description=f"identified by pmdc-ident from {', '.join(self.sources)} "
            f"({self.model_kind} model){note}",
        )

    def motor_yaml(self, name: str = "identified") -> str:
        """The motor file of the identified motor (:data:`MOTOR_YAML_HEADER` first), as
        ``pmdc-ident identify --yaml`` and the identification node write it."""
        return MOTOR_YAML_HEADER + motor_to_yaml(self.motor_spec(name))

    def write_motor_yaml(self, path: str | Path, name: str | None = None) -> Path:
        from pmdc_ident.core.safe_write import write_text

        p = Path(path)
        return write_text(p, self.motor_yaml(name or p.stem))


def _in_range(model: Model) -> tuple[Model, str]:
    """``model`` with each motor parameter clamped into its physical range, and the note
    saying which were (empty when none)."""
    import math
    from dataclasses import replace

    from pmdc_ident.core.params import PARAMETER_RANGES

    values = model.params.as_dict()
    said = []
    for name, (lo, hi) in PARAMETER_RANGES.items():
        v = values.get(name)
        if v is None or (math.isfinite(v) and lo <= v <= hi):
            continue
        end = lo if not v > lo else hi
        said.append(f"{name} {v:.3g} outside [{lo:g}, {hi:g}], written as {end:g} (flagged)")
        values[name] = end
    if not said:
        return model, ""
    return replace(model, params=type(model.params)(**values)), "; ".join(said)


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return [_jsonable(v) for v in obj.tolist()]
    if isinstance(obj, np.bool_ | bool):
        return bool(obj)
    if isinstance(obj, np.integer | int):
        return int(obj)
    if isinstance(obj, np.floating | float):
        return finite_or_none(float(obj))
    return obj
