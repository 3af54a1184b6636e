"""``pmdc-ident identify DATA... [--fix NAME=VALUE]... [--json PATH] [--report DIR]``.

Prints the parameter table with 95 % intervals, the assumptions, the transfer
functions and the method comparison; writes the JSON of docs/design.md §4, a motor
YAML that ``load_motor`` (and the simulated driver) reads, and with
``--report`` plots of measured against simulated response per segment.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    input_options,
    make_progress,
)
from pmdc_ident.commands.batch import add_batch_arguments, format_table
from pmdc_ident.commands.outputs import (
    STDOUT,
    check_distinct,
    check_file_output,
    check_folder_output,
    check_inputs_distinct,
)

HELP = "identify R, L, Ke, Kt, J, B and friction from recorded runs (CSV or bag)"

# The values of core.identification.identify.ModelChoice (a test checks they agree): the
# numerical core is imported by run(), not to build the help (see pmdc_ident.cli).
MODEL_CHOICES: tuple[str, ...] = ("auto", "linear", "coulomb")
MAX_BOOTSTRAP = 500  # parametric-bootstrap refits at most


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data", nargs="+", metavar="DATA", help="CSV file, .mcap file or rosbag2 directory"
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a parameter at a known value in SI units (e.g. L=3e-4 from an LCR meter, "
        "R=1.375 from a multimeter, Kt=0.067 to replace the Kt = Ke closure); repeatable",
    )
    parser.add_argument(
        "--added-inertia",
        action="append",
        default=[],
        metavar="DATA=KG_M2",
        help="this DATA file was recorded with a known inertia added to the shaft: with "
        "runs with and without it, Kt is estimated instead of assumed equal to Ke",
    )
    parser.add_argument(
        "--json", metavar="PATH", help="write the results as JSON (.json; - for stdout)"
    )
    parser.add_argument(
        "--yaml",
        metavar="PATH",
        help="write a motor file that load_motor()/the sim driver reads (.yaml; - for stdout)",
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help="write plots (measured vs simulated, residuals) into this folder (created; its "
        "parent must exist)",
    )
    parser.add_argument(
        "--model",
        choices=MODEL_CHOICES,
        default=MODEL_CHOICES[0],
        help="model to report: linear, linear + Coulomb friction, or auto (Coulomb when "
        "significant; default)",
    )
    parser.add_argument(
        "--closure",
        choices=["Kt=Ke", "none"],
        default="Kt=Ke",
        help="closure of the (Kt, J, B) scale ambiguity (default Kt=Ke)",
    )
    parser.add_argument(
        "--bootstrap",
        type=int,
        default=None,
        metavar="N",
        help="check the intervals with N parametric-bootstrap refits (default 0, 10 with "
        "--report)",
    )
    parser.add_argument(
        "--no-holdout", action="store_true", help="skip the held-out segment validation"
    )
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    add_gate_arguments(parser)
    add_unit_arguments(parser)
    add_batch_arguments(parser)


def _outputs(args: argparse.Namespace) -> dict[str, Path | str | None]:
    """The checked --json/--yaml/--report targets (before any work is done)."""
    inputs = list(args.data)
    targets: dict[str, Path | str | None] = {
        "--json": check_file_output("--json", args.json, inputs, suffixes=(".json",)),
        "--yaml": check_file_output("--yaml", args.yaml, inputs, suffixes=(".yaml", ".yml")),
        "--report": check_folder_output(
            "--report", args.report, inputs, writes=("identify.json", "identified_motor.yaml")
        ),
    }
    check_distinct(targets)
    check_inputs_distinct(args.data)
    return targets


def _write(path: Path | str, text: str) -> Path:
    from pmdc_ident.core.safe_write import write_text

    return write_text(path, text)


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.app import IdentifyOptions
    from pmdc_ident.app.inputs import check_ignore
    from pmdc_ident.app.service import check_identify_options, identify_inputs
    from pmdc_ident.core.fixed import parse_fix

    check_ignore(args.ignore)
    fixed = parse_fix(args.fix)
    from pmdc_ident.commands._bounds import Bound

    Bound("--bootstrap", 0, MAX_BOOTSTRAP, "each refit costs a whole fit", integer=True).check(
        args.bootstrap
    )
    options = input_options(
        IdentifyOptions,
        args,
        fixed,
        model=args.model,
        closure=args.closure,
        bootstrap=args.bootstrap if args.bootstrap is not None else (10 if args.report else 0),
        holdout_check=not args.no_holdout,
        added_inertia=tuple(args.added_inertia),
    )
    check_identify_options(options)
    if args.batch is not None:
        from pmdc_ident.commands.batch import run_batch

        return run_batch(args, __name__, batch_table, forbidden=("--json", "--yaml", "--report"))
    targets = _outputs(args)
    to_stdout = STDOUT in targets.values()
    # with a document on standard output, the human-readable report goes to stderr
    text_out = sys.stderr if to_stdout else sys.stdout
    docs = identify_inputs(
        options, show=lambda line: print(line, file=text_out), progress=make_progress(args)
    )
    result = docs.result
    document = docs.json_text
    written: list[Path] = []
    json_to, yaml_to, report_to = targets["--json"], targets["--yaml"], targets["--report"]
    if json_to == STDOUT:
        print(document, end="")
    elif json_to is not None:
        written.append(_write(json_to, document))
    if yaml_to == STDOUT:
        print(docs.yaml_text, end="")
    elif yaml_to is not None:
        written.append(result.write_motor_yaml(yaml_to))
    if report_to is not None:
        from pmdc_ident.report.plots import write_identify_report

        out = Path(report_to)
        written += write_identify_report(result, docs.segments, out)
        if json_to is None:
            written.append(_write(out / "identify.json", document))
        if yaml_to is None:
            written.append(result.write_motor_yaml(out / "identified_motor.yaml"))
    for p in written:
        print(f"wrote {p}", file=text_out)
    return 0


# --batch: what the summary table shows of each input's JSON
_BATCH_COLUMNS = {
    "R": "R ohm",
    "L": "L H",
    "Ke": "Ke V*s/rad",
    "J": "J kg*m^2",
    "B": "B N*m*s/rad",
    "coulomb_friction.torque_nm": "Tc N*m",
}


def batch_summary(json_path: Path) -> dict[str, Any]:
    """The model and the main parameter values of one input's JSON (for the batch table)."""
    body = json.loads(Path(json_path).read_text())
    params = body.get("parameters", {})
    values = {k: params[k]["value"] for k in _BATCH_COLUMNS if k in params}
    return {"model": body.get("model", ""), **values}


def batch_table(outcomes: list[Any]) -> str:
    rows = []
    for o in outcomes:
        s = o.summary
        cells = [f"{s[k]:.5g}" if k in s else "-" for k in _BATCH_COLUMNS]
        status = "ok" if o.ok else "FAILED"
        rows.append([str(o.item.path), status, s.get("model", "-"), *cells, f"{o.elapsed_s:.1f}"])
    return format_table(["input", "status", "model", *_BATCH_COLUMNS.values(), "s"], rows)
