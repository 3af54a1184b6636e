"""The options of the application service, already parsed, and the caller's words for them.

The command line builds these from its ``argparse`` namespace, the identification
node from its ROS parameters and session. The field names are neutral (they happen
to be the command line's ``dest`` names); an error or a hint that names an option
says it in the caller's wording, looked up in :attr:`InputOptions.names`
(:data:`CLI_NAMES` by default: ``--fix``, ``--ignore``, ...).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from pmdc_ident.core.errors import option_name

__all__ = [
    "CLI_NAMES",
    "CheckOptions",
    "DiagnoseOptions",
    "IdentifyOptions",
    "InputOptions",
]

# neutral option name -> how the command line spells it (the core's errors and hints name
# an option by its key, pmdc_ident.core.errors.option_name; cli.py states these words)
CLI_NAMES: Mapping[str, str] = {
    "data": "DATA",
    "fix": "--fix",
    "ignore": "--ignore",
    "column": "--column",
    "no_auto_segments": "--no-auto-segments",
    "all_samples": "--all-samples",
    "drop_outliers": "--drop-outliers",
    "added_inertia": "--added-inertia",
    "closure": "--closure",
    "bootstrap": "--bootstrap",
    "holdout": "--holdout",
    "effects": "--effects",
    "max_effects": "--max-effects",
    "time_unit": "--time-unit",
    "speed_unit": "--speed-unit",
    "position_unit": "--position-unit",
    "current_unit": "--current-unit",
    "voltage_unit": "--voltage-unit",
    "supply_v": "--supply-v",
    "counts_per_rev": "--counts-per-rev",
    "speed_averaged": "--speed-averaged",
    "gear_ratio": "--gear-ratio",
}


@dataclass(frozen=True)
class InputOptions:
    """What to read and how: the DATA paths, their columns and units (as the units
    layer reads them, :func:`pmdc_ident.dataio.units.spec_from_options`), the gate's
    options and the fixed values."""

    data: tuple[str, ...]
    fixed: Mapping[str, float] = field(default_factory=dict)
    column: tuple[str, ...] = ()
    time_unit: str | None = None
    speed_unit: str | None = None
    position_unit: str | None = None
    current_unit: str | None = None
    voltage_unit: str | None = None
    supply_v: str | None = None
    counts_per_rev: str | None = None
    speed_averaged: bool | None = None
    gear_ratio: str | None = None
    no_auto_segments: bool = False
    all_samples: bool = False
    drop_outliers: bool = False
    ignore: tuple[str, ...] = ()
    names: Mapping[str, str] = field(default_factory=lambda: CLI_NAMES)

    def name(self, key: str) -> str:
        """Option ``key`` in the caller's words: :func:`pmdc_ident.core.errors.option_name`
        with :attr:`names` (a key they lack is named as the command line spells it)."""
        return option_name(key, self.names)


@dataclass(frozen=True)
class IdentifyOptions(InputOptions):
    """``identify``: the model, the closure, the bootstrap, the hold-out check, the
    inertia added per DATA path and the name of the motor written."""

    model: str = "auto"
    closure: str = "Kt=Ke"  # or "none"
    bootstrap: int = 0
    holdout_check: bool = True
    added_inertia: tuple[str, ...] = ()  # DATA=KG_M2 items
    motor_name: str = "identified"


@dataclass(frozen=True)
class DiagnoseOptions(InputOptions):
    """``diagnose``: the held-out labels, the effects tried and the largest combination."""

    holdout: tuple[str, ...] = ()
    effects: tuple[str, ...] = ()
    max_effects: int = 3


@dataclass(frozen=True)
class CheckOptions(InputOptions):
    """``check``: the gate alone (no options of its own)."""
