"""The command line's side of reading DATA: the shared column/unit and gate options, the
timed progress lines, and the parsed options the application service takes
(:func:`input_options`; the reading and the gate are :mod:`pmdc_ident.app.inputs`).

Light at import time (the fast ``--help`` rule): numpy and the core load inside
the functions.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, TypeVar

from pmdc_ident.app.inputs import LONG_SAMPLES
from pmdc_ident.app.options import InputOptions

__all__ = [
    "add_gate_arguments",
    "add_unit_arguments",
    "data_megabytes",
    "input_options",
    "make_progress",
]

_Options = TypeVar("_Options", bound=InputOptions)

# the fields of InputOptions read from the namespace of the same name (fixed aside)
_FIELDS = (
    "time_unit",
    "speed_unit",
    "position_unit",
    "current_unit",
    "voltage_unit",
    "supply_v",
    "counts_per_rev",
    "speed_averaged",
    "gear_ratio",
    "no_auto_segments",
    "all_samples",
    "drop_outliers",
)


def input_options(
    cls: type[_Options], args: argparse.Namespace, fixed: Mapping[str, float], **more: Any
) -> _Options:
    """The service's options of ``cls`` from a parsed command line (``more``: the
    command's own)."""
    common = {k: getattr(args, k) for k in _FIELDS if hasattr(args, k)}
    return cls(
        data=tuple(args.data),
        fixed=fixed,
        column=tuple(getattr(args, "column", None) or ()),
        ignore=tuple(getattr(args, "ignore", None) or ()),
        **common,
        **more,
    )


def spec_of_args(args: argparse.Namespace) -> Any:
    """The :class:`~pmdc_ident.dataio.units.InputSpec` of the unit options on the command
    line (:func:`add_unit_arguments`)."""
    from pmdc_ident.dataio.units import UNIT_OPTIONS, spec_from_options

    units = {k: getattr(args, k, None) for k in UNIT_OPTIONS}
    return spec_from_options(column=tuple(getattr(args, "column", None) or ()), **units)


_UNITS = {
    "--time-unit": ("s|ms|us|ns", "time"),
    "--speed-unit": ("rad/s|rpm|deg/s|rev/s|counts/s", "speed"),
    "--position-unit": ("rad|deg|rev|counts", "position"),
    "--current-unit": ("A|mA", "current"),
    "--voltage-unit": ("V|mV|duty|duty%", "voltage"),
}


def add_unit_arguments(parser: argparse.ArgumentParser) -> None:
    """The column/unit options shared by identify, diagnose, check and export."""
    g = parser.add_argument_group(
        "columns and units (data from other tools; also in a sidecar DATA.yaml)"
    )
    g.add_argument(
        "--column",
        action="append",
        default=[],
        metavar="NAME=HEADER",
        help="read the column headed HEADER as NAME (t, voltage, current, position, speed, "
        "terminal_voltage, segment); -HEADER flips its sign, HEADER 'none' ignores the "
        "file's NAME column; repeatable",
    )
    for flag, (choices, what) in _UNITS.items():
        g.add_argument(
            flag,
            metavar="UNIT",
            default=None,
            help=f"unit of the {what} column: {choices}".replace("%", "%%"),
        )
    g.add_argument("--supply-v", default=None, metavar="V", help="supply voltage for duty units")
    g.add_argument(
        "--counts-per-rev",
        default=None,
        metavar="N",
        help="encoder counts per shaft turn, for counts and counts/s",
    )
    g.add_argument(
        "--speed-averaged",
        action="store_true",
        default=None,
        help="the speed column is the counts since the last sample (their mean over the "
        "interval, as most encoder interfaces report): its running sum is used as the "
        "position",
    )
    g.add_argument(
        "--gear-ratio",
        default=None,
        metavar="N",
        help="motor turns per load turn: speed and position were measured on the load side; "
        "parameters are reported on the motor side",
    )


def add_gate_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--no-auto-segments",
        action="store_true",
        help="keep a log without a segment column as one segment (default: its steps, "
        "plateaus, coasts, sweeps and PRBS stretches are found and labelled)",
    )
    parser.add_argument(
        "--all-samples",
        action="store_true",
        help=f"fit and check every sample of a long record (default: above {LONG_SAMPLES} "
        "samples the physics checks and the fit use a representative subset of its "
        "segments, every kind spread over the record; timing, units, clipping and outliers "
        "are checked on every sample)",
    )
    parser.add_argument(
        "--drop-outliers",
        action="store_true",
        help="leave out the isolated outliers the gate finds (one- or two-sample glitches "
        "far outside a signal's range; listed with their lines): the fit steps over them "
        "as over gaps (default: they are an error)",
    )
    parser.add_argument(
        "--ignore",
        action="append",
        default=[],
        metavar="CODE",
        help="turn the data-quality error CODE (e.g. time-unit, current-unit) into a warning "
        "and go on; repeatable",
    )


def data_megabytes(args: argparse.Namespace) -> float:
    """The size of the DATA files (a bag folder's files included), MB."""
    total = 0
    for p in map(Path, args.data):
        try:
            files = [p] if p.is_file() else [f for f in p.rglob("*") if f.is_file()]
            total += sum(f.stat().st_size for f in files)
        except OSError:
            continue
    return total / 1e6


def make_progress(args: argparse.Namespace, *, quiet: bool = False) -> Callable[[str], None]:
    """Timed progress lines on stderr (``[  1.2 s] ...``), nothing with ``--quiet``."""
    t0 = time.perf_counter()
    silent = quiet or getattr(args, "quiet", False)

    def progress(msg: str) -> None:
        if not silent:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    return progress
