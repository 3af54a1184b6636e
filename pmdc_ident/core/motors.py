"""Motor description files: parameters, effects, sensors and limits (YAML).

The built-in motors live in ``config/motors/`` (installed to
``share/pmdc_ident/config/motors``). :func:`load_motor` accepts a built-in
name (``seed000_ebike``) or a path to a YAML file of the same form; the
``identify`` command writes such files, so identify -> simulate closes the loop.
"""

from __future__ import annotations

import math
import os
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import yaml

from pmdc_ident.core.effects import effects_from_mapping, effects_to_mapping
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.core.model import Model
from pmdc_ident.core.params import MotorParams, check_physical_range

__all__ = [
    "BUILTIN_MOTORS",
    "Limits",
    "MotorSpec",
    "SensorSpec",
    "builtin_motor_dir",
    "share_candidates",
    "share_file",
    "load_motor",
    "motor_to_yaml",
]

BUILTIN_MOTORS: tuple[str, ...] = ("seed000_ebike", "seed001_110v")


def _check_fields(obj: object, lower_strict: bool = False) -> None:
    for f in fields(obj):  # type: ignore[arg-type]
        raw = getattr(obj, f.name)
        try:
            value = float(raw)
        except (TypeError, ValueError):
            msg = f"{type(obj).__name__}.{f.name} must be a number, got {raw!r}"
            raise ParameterError(msg) from None
        bad = value <= 0 if lower_strict else value < 0
        if not math.isfinite(value) or bad:
            bound = "> 0" if lower_strict else ">= 0"
            msg = f"{type(obj).__name__}.{f.name} must be finite and {bound}, got {value}"
            raise ParameterError(msg)
        object.__setattr__(obj, f.name, value)


@dataclass(frozen=True)
class SensorSpec:
    """Measurement imperfections of a (simulated) driver."""

    current_noise_a: float = 0.0
    speed_noise_rad_s: float = 0.0
    encoder_counts_per_rev: float = 0.0  # 0: exact angle

    def __post_init__(self) -> None:
        _check_fields(self)


@dataclass(frozen=True)
class Limits:
    """Safe operating limits of the motor and driver."""

    voltage_max_v: float = 24.0
    current_max_a: float = 30.0
    speed_max_rad_s: float = 500.0

    def __post_init__(self) -> None:
        _check_fields(self, lower_strict=True)


@dataclass(frozen=True)
class MotorSpec:
    name: str
    model: Model
    sensors: SensorSpec = field(default_factory=SensorSpec)
    limits: Limits = field(default_factory=Limits)
    description: str = ""


def share_candidates(*parts: str) -> list[Path]:
    """Where a file of the package's share folder may be, most specific first.

    The source tree (``config/``, ``launch/`` beside the package), then each
    ``AMENT_PREFIX_PATH`` prefix's and ``sys.prefix``'s ``share/pmdc_ident/``.
    """
    candidates = [Path(__file__).resolve().parents[2].joinpath(*parts)]
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            candidates.append(Path(prefix, "share", "pmdc_ident", *parts))
    candidates.append(Path(sys.prefix, "share", "pmdc_ident", *parts))
    return candidates


def share_file(*parts: str) -> Path | None:
    """The first existing share file (e.g. ``share_file("config", "driver.yaml")``)."""
    return next((c for c in share_candidates(*parts) if c.is_file()), None)


def builtin_motor_dir() -> Path:
    """Folder of the built-in motor files (source tree, or an installed share/)."""
    found = share_file("config", "motors", f"{BUILTIN_MOTORS[0]}.yaml")
    if found is not None:
        return found.parent
    looked = ", ".join(str(c.parent) for c in share_candidates("config", "motors", "x"))
    msg = f"built-in motor files not found (looked in: {looked})"
    raise ParameterError(msg)


def load_motor(name_or_path: str | Path) -> MotorSpec:
    """Load a built-in motor by name, or a motor YAML file by path."""
    text = str(name_or_path)
    path = Path(text)
    if text in BUILTIN_MOTORS:
        path = builtin_motor_dir() / f"{text}.yaml"
    elif not path.is_file():
        msg = f"no motor file {text!r} (built-in motors: {', '.join(BUILTIN_MOTORS)})"
        raise ParameterError(msg)
    else:
        from pmdc_ident.core.safe_write import protect

        protect([path], "the motor file")  # never an output of the command reading it
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        msg = f"{path}: not a motor file (not UTF-8 text)"
        raise ParameterError(msg) from None
    except yaml.YAMLError as exc:
        msg = f"{path}: not valid YAML ({str(exc).splitlines()[0]})"
        raise ParameterError(msg) from None
    return motor_from_mapping(data, source=str(path))


def motor_from_mapping(data: Any, source: str = "motor") -> MotorSpec:
    if not isinstance(data, dict) or "parameters" not in data:
        what = (
            "a recording, not a motor file"
            if str(source).lower().endswith((".csv", ".txt", ".mcap"))
            else "not a motor file"
        )
        msg = (
            f"{source}: {what}: a motor file needs a 'parameters' mapping (R, L, Ke, Kt, J, B), "
            "as `pmdc-ident identify --yaml` writes it; or give a built-in motor "
            f"({', '.join(BUILTIN_MOTORS)})"
        )
        raise ParameterError(msg)
    try:
        params = MotorParams.from_mapping(data["parameters"])
        for name, value in params.as_dict().items():
            check_physical_range(name, value)
        effects = effects_from_mapping(data.get("effects"))
        sensors = SensorSpec(**(data.get("sensors") or {}))
        limits = Limits(**(data.get("limits") or {}))
    except TypeError as exc:
        msg = f"{source}: {exc}"
        raise ParameterError(msg) from None
    except ParameterError as exc:
        msg = f"{source}: {exc}"
        raise ParameterError(msg) from None
    return MotorSpec(
        name=str(data.get("name", Path(source).stem)),
        model=Model(params, effects),
        sensors=sensors,
        limits=limits,
        description=str(data.get("description", "")),
    )


def motor_to_yaml(spec: MotorSpec) -> str:
    """The YAML text :func:`load_motor` reads back."""
    data = {
        "name": spec.name,
        "description": spec.description,
        "parameters": spec.model.params.as_dict(),
        "effects": effects_to_mapping(spec.model.effects),
        "sensors": {f.name: getattr(spec.sensors, f.name) for f in fields(spec.sensors)},
        "limits": {f.name: getattr(spec.limits, f.name) for f in fields(spec.limits)},
    }
    return yaml.safe_dump(data, sort_keys=False)
