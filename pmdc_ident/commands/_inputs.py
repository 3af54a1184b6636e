"""DATA arguments as the commands read them: columns and units applied (``dataio.units``),
then the data-quality gate (``core.quality``) before any fit.

Light at import time (the fast ``--help`` rule): numpy and the core load inside
the functions.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TextIO

if TYPE_CHECKING:
    from pmdc_ident.core.quality import QualityReport
    from pmdc_ident.dataio.units import LoadedInput

__all__ = [
    "add_gate_arguments",
    "add_unit_arguments",
    "check_ignore",
    "gate",
    "input_json",
    "load_inputs",
    "load_side",
    "quality",
    "prepare_inputs",
    "segment_inputs",
    "show_quality",
    "stop_on_errors",
]

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
        "--ignore",
        action="append",
        default=[],
        metavar="CODE",
        help="turn the data-quality error CODE (e.g. time-unit, current-unit) into a warning "
        "and go on; repeatable",
    )


def load_inputs(args: argparse.Namespace) -> list[LoadedInput]:
    """Every DATA argument in SI units (command-line keys over each file's sidecar)."""
    from pmdc_ident.dataio.units import load_input, spec_from_args

    spec = spec_from_args(args)
    return [load_input(p, spec) for p in args.data]


def segment_inputs(
    args: argparse.Namespace, inputs: list[LoadedInput], show: Callable[[str], None] = print
) -> list[LoadedInput]:
    """Unlabeled logs cut into their experiments (printed; usable as --holdout labels)."""
    if getattr(args, "no_auto_segments", False):
        return inputs
    from dataclasses import replace

    from pmdc_ident.core.segmentation import segment_run

    out = []
    for x in inputs:
        try:
            run, lines = segment_run(x.run)
        except (ArithmeticError, ValueError, IndexError) as exc:  # data nobody foresaw
            show(f"segments: {x.path} kept as one segment ({type(exc).__name__}: {exc})")
            run, lines = x.run, []
        if lines:
            show(f"segments found in {x.path} (no segment column; --no-auto-segments keeps one):")
            for line in lines:
                show(f"  {line}")
            x = replace(x, run=run, notes=(*x.notes, f"segments found: {len(lines)}"))
        out.append(x)
    return out


def quality(
    args: argparse.Namespace,
    inputs: list[LoadedInput],
    fixed: dict[str, float] | None = None,
) -> QualityReport:
    """The gate's findings on ``inputs`` (``--ignore CODE`` errors turned into warnings);
    ``fixed`` parameters are left out of the expected uncertainties."""
    from pmdc_ident.core.quality import GateInput, check_inputs

    return check_inputs(
        [GateInput(x.path, x.run, x.spec.declared(), x.notes) for x in inputs],
        fixed=fixed,
        ignore=getattr(args, "ignore", []) or [],
    )


def show_quality(
    report: QualityReport, *, show: Callable[[str], None] = print, info: bool = False
) -> None:
    """Print the findings (errors and warnings; ``info`` adds the measurements)."""
    lines = report.lines(info=info)
    if lines:
        show("data quality:")
        for line in lines:
            show(f"  {line}")


def check_ignore(args: argparse.Namespace) -> None:
    """``--ignore CODE`` names a finding code (checked before any work)."""
    from pmdc_ident.core.errors import ParameterError
    from pmdc_ident.core.quality.findings import CODES

    bad = [c for c in getattr(args, "ignore", []) or [] if c not in CODES]
    if bad:
        msg = f"--ignore {bad[0]}: not a finding code (codes: {', '.join(CODES)})"
        raise ParameterError(msg)


def stop_on_errors(report: QualityReport) -> None:
    """Refuse to go on (:class:`DataError`, exit 2) when an error remains; the line
    carries the first error itself (the others are listed above it)."""
    from pmdc_ident.core.errors import DataError

    if report.errors:
        first = report.errors[0]
        more = len(report.errors) - 1
        fix = f"; fix: {first.fix}" if first.fix else ""
        also = f" (and {more} more above)" if more else ""
        msg = (
            f"data quality: {first.code}: {first.where}: {first.message}{fix}{also}; "
            "nothing was fitted (--ignore CODE goes on anyway)"
        )
        raise DataError(msg)


def gate(
    args: argparse.Namespace,
    inputs: list[LoadedInput],
    *,
    show: Callable[[str], None] = print,
    info: bool = False,
    fixed: dict[str, float] | None = None,
) -> QualityReport:
    """:func:`quality`, :func:`show_quality`, :func:`stop_on_errors`: the gate before a fit."""
    check_ignore(args)
    report = quality(args, inputs, fixed)
    show_quality(report, show=show, info=info)
    stop_on_errors(report)
    return report


def prepare_inputs(
    args: argparse.Namespace, text_out: TextIO, fixed: dict[str, float]
) -> tuple[list[LoadedInput], QualityReport, Callable[[str], None]]:
    """What ``identify`` and ``diagnose`` do first: read the DATA (their notes as
    progress), run the :func:`gate`, cut the automatic segments. Returns the inputs,
    the gate's report and the progress callback (timed lines on stderr unless
    ``--quiet``)."""
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    def show(line: str) -> None:
        print(line, file=text_out)

    inputs = load_inputs(args)
    for x in inputs:
        for note in x.notes:
            progress(f"{x.path}: {note}")
    report = gate(args, inputs, show=show, fixed=fixed)
    return segment_inputs(args, inputs, show=show), report, progress


# load-side value = motor-side value * gear_ratio ** power (N motor turns per load turn)
_REFLECT = {"Ke": 1, "Kt": 1, "J": 2, "B": 2, "coulomb_friction.torque_nm": 1}


def load_side(values: dict[str, float], inputs: list[LoadedInput]) -> dict[str, Any]:
    """The parameters seen from the load side of the gear (``--gear-ratio N``), else {}."""
    gears = {x.spec.gear_ratio for x in inputs}
    if gears == {None}:
        return {}
    if len(gears) != 1:
        return {"note": "inputs have different gear ratios: no load-side values"}
    (n,) = gears
    assert n is not None
    out: dict[str, Any] = {
        name: values[name] * n**power for name, power in _REFLECT.items() if name in values
    }
    out["gear_ratio"] = n
    out["note"] = (
        f"seen from the load side of a {n:g}:1 gear (Ke, Kt, torques x {n:g}; J, B x {n:g}^2; "
        "gear losses not included)"
    )
    return out


def input_json(inputs: list[LoadedInput], report: QualityReport) -> dict[str, Any]:
    """The ``quality`` and ``inputs`` (units applied per file) keys of a command's JSON."""
    return {
        "quality": report.to_json(),
        "inputs": {x.path: {"units": x.spec.to_json(), "notes": list(x.notes)} for x in inputs},
    }
