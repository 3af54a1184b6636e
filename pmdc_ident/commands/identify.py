"""``pmdc-ident identify DATA... [--fix NAME=VALUE]... [--json PATH] [--report DIR]``.

Prints the parameter table with 95 % intervals, the assumptions, the transfer
functions and the method comparison; writes the JSON of docs/design.md §4, a motor
YAML that ``load_motor`` (and the simulated driver) reads, and with
``--report`` plots of measured against simulated response per segment.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    check_ignore,
    input_json,
    load_side,
    prepare_inputs,
)
from pmdc_ident.commands.batch import add_batch_arguments, format_table
from pmdc_ident.commands.outputs import (
    STDOUT,
    check_distinct,
    check_file_output,
    check_folder_output,
    check_inputs_distinct,
)
from pmdc_ident.core.errors import ParameterError

# the first line of a motor file identify writes (as IdentificationResult.write_motor_yaml)
MOTOR_YAML_HEADER = "# Motor file written by `pmdc-ident identify`; load_motor(path) reads it.\n"

HELP = "identify R, L, Ke, Kt, J, B and friction from recorded runs (CSV or bag)"

# The values of core.estimators.identify.ModelChoice (a test checks they agree): the
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


def _added_inertia(items: list[str], data: list[str], runs, segments) -> dict[str, float]:
    """``DATA=KG_M2`` items to segment labels (segments keep the order of the files)."""
    per_file: dict[str, float] = {}
    for item in items:
        path, sep, value = item.rpartition("=")
        try:
            per_file[path] = float(value)
        except ValueError:
            per_file[path] = math.nan
        if not sep or not path or not math.isfinite(per_file[path]):
            msg = f"--added-inertia expects DATA=KG_M2 (e.g. run2.csv=0.002), got {item!r}"
            raise ParameterError(msg)
    out: dict[str, float] = {}
    start = 0
    spans = []
    for path, r in zip(data, runs, strict=True):
        spans.append((path, segments[start : start + len(r)]))
        start += len(r)
    for path, value in per_file.items():
        if value < 0:
            msg = f"--added-inertia {path}: must be >= 0 kg*m^2, got {value:g}"
            raise ParameterError(msg)
        match = [
            segs for p, segs in spans if p == path or Path(p).resolve() == Path(path).resolve()
        ]
        if not match:
            msg = f"--added-inertia {path}: not one of the DATA arguments"
            raise ParameterError(msg)
        for s in match[0]:
            out[s.label] = value
    return out


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
    check_ignore(args)
    from pmdc_ident.core.fixed import parse_fix

    fixed = parse_fix(args.fix)
    from pmdc_ident.commands._bounds import Bound

    Bound("--bootstrap", 0, MAX_BOOTSTRAP, "each refit costs a whole fit", integer=True).check(
        args.bootstrap
    )
    if args.closure == "none" and not ({"Kt", "J"} & set(fixed) or args.added_inertia):
        msg = (
            "--closure none leaves the scale of (Kt, J, B) unidentifiable from voltage, "
            "current and speed: give --fix Kt=..., --fix J=... or --added-inertia DATA=KG_M2"
        )
        raise ParameterError(msg)
    if args.batch is not None:
        from pmdc_ident.commands.batch import run_batch

        return run_batch(args, __name__, batch_table, forbidden=("--json", "--yaml", "--report"))
    targets = _outputs(args)
    to_stdout = STDOUT in targets.values()
    # with a document on standard output, the human-readable report goes to stderr
    text_out = sys.stderr if to_stdout else sys.stdout
    from pmdc_ident.core.estimators.identify import identify, merge_runs
    from pmdc_ident.core.estimators.output_error import CLOSURE_KT_KE

    inputs, report, progress = prepare_inputs(args, text_out, fixed)
    runs = [x.run for x in inputs]
    n_boot = args.bootstrap if args.bootstrap is not None else (10 if args.report else 0)
    segments = merge_runs(runs)
    added = _added_inertia(args.added_inertia, args.data, runs, segments)
    result = identify(
        segments,
        sources=tuple(r.source for r in runs),
        fixed=fixed,
        closure=CLOSURE_KT_KE if args.closure == "Kt=Ke" else None,
        model=args.model,
        holdout=not args.no_holdout,
        bootstrap=n_boot,
        progress=progress,
        added_inertia=added,
        findings=report.findings,
        expected_rsd=report.expected_rsd,
    )
    print(result.text_report(), file=text_out)
    body = result.to_json_dict()
    body.update(input_json(inputs, report))
    gear = load_side({k: p.value for k, p in result.parameters.items()}, inputs)
    if gear:
        body["load_side"] = gear
        print("load side: " + gear["note"], file=text_out)
        values = ", ".join(f"{k} = {v:.6g}" for k, v in gear.items() if k != "note")
        print(f"  {values}", file=text_out)
    document = json.dumps(body, indent=2, allow_nan=False) + "\n"
    written: list[Path] = []
    json_to, yaml_to, report_to = targets["--json"], targets["--yaml"], targets["--report"]
    if json_to == STDOUT:
        print(document, end="")
    elif json_to is not None:
        written.append(_write(json_to, document))
    if yaml_to == STDOUT:
        from pmdc_ident.core.motors import motor_to_yaml

        print(MOTOR_YAML_HEADER + motor_to_yaml(result.motor_spec("identified")), end="")
    elif yaml_to is not None:
        written.append(result.write_motor_yaml(yaml_to))
    if report_to is not None:
        from pmdc_ident.report.plots import write_identify_report

        out = Path(report_to)
        written += write_identify_report(result, segments, out)
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
