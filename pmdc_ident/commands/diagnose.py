"""``pmdc-ident diagnose DATA... [--holdout LABEL...] [--json PATH] [--report DIR]``.

Fits the linear model on part of the segments, measures its free-run error on
the held-out rest, localizes the gap, tries every effect of the vocabulary (and
combinations), and prints the verdict: ``no_gap``, ``explained`` by named
effects, or ``unexplained``. ``--json`` writes the keys of docs/design.md §4, ``--report``
an HTML page with plots.
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
from pmdc_ident.core.effects import DEFAULT_CANDIDATES, EFFECT_NAMES

HELP = "diagnose the sim-to-real gap: where it lies, which effect causes it, how far it shrinks"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data", nargs="+", metavar="DATA", help="CSV file, .mcap file or rosbag2 directory"
    )
    parser.add_argument(
        "--holdout",
        nargs="+",
        default=[],
        metavar="LABEL",
        help="segment labels to hold out (default: every test type split between fit and "
        "held-out; the split used is printed)",
    )
    parser.add_argument(
        "--effects",
        default=",".join(DEFAULT_CANDIDATES),
        metavar="NAME,...",
        help="effects of the vocabulary to try (default: all"
        + "".join(f" but {n}" for n in EFFECT_NAMES if n not in DEFAULT_CANDIDATES)
        + ")",
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="hold a motor parameter at a known value in SI units (e.g. L=3e-4); repeatable",
    )
    parser.add_argument(
        "--max-effects", type=int, default=3, help="largest combination of effects (default 3)"
    )
    parser.add_argument(
        "--json", metavar="PATH", help="write the results as JSON (.json; - for stdout)"
    )
    parser.add_argument(
        "--report",
        metavar="DIR",
        help="write an HTML page with plots into this folder (created; its parent must exist)",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    add_gate_arguments(parser)
    add_unit_arguments(parser)
    add_batch_arguments(parser)


def diagnose_options(args: argparse.Namespace, **extra: Any) -> Any:
    """The service's ``DiagnoseOptions`` from the diagnosis arguments (``--holdout``,
    ``--effects``, the unit and gate options; ``extra`` the caller's own), checked.
    ``roundtrip`` diagnoses with the same arguments."""
    from pmdc_ident.app import DiagnoseOptions
    from pmdc_ident.app.service import check_diagnose_options

    options = input_options(
        DiagnoseOptions,
        args,
        {},
        holdout=tuple(args.holdout),
        effects=tuple(e.strip() for e in args.effects.split(",") if e.strip()),
        **extra,
    )
    check_diagnose_options(options)
    return options


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from pmdc_ident.app.service import diagnose_inputs
    from pmdc_ident.core.fixed import parse_fix
    from pmdc_ident.core.params import PARAMETER_NAMES

    options = diagnose_options(args, max_effects=args.max_effects)
    if args.batch is not None:
        from pmdc_ident.commands.batch import run_batch

        return run_batch(args, __name__, batch_table, forbidden=("--json", "--report"))
    targets = {
        "--json": check_file_output("--json", args.json, args.data, suffixes=(".json",)),
        "--report": check_folder_output(
            "--report", args.report, args.data, writes=("index.html", "diagnosis.json")
        ),
    }
    check_distinct(targets)
    check_inputs_distinct(args.data)
    json_to, report_to = targets["--json"], targets["--report"]
    text_out = sys.stderr if json_to == STDOUT else sys.stdout
    options = replace(options, fixed=parse_fix(args.fix, known=PARAMETER_NAMES))
    docs = diagnose_inputs(
        options, show=lambda line: print(line, file=text_out), progress=make_progress(args)
    )
    written: list[Path] = []
    if json_to == STDOUT:
        print(docs.json_text, end="")
    elif json_to is not None:
        from pmdc_ident.core.safe_write import write_text

        written.append(write_text(json_to, docs.json_text))
    if report_to is not None:
        from pmdc_ident.report.diagnosis_html import write_diagnosis_report

        written.append(write_diagnosis_report(docs.result, Path(report_to)))
    for p in written:
        print(f"wrote {p}", file=text_out)
    return 0


def batch_summary(json_path: Path) -> dict[str, Any]:
    """Verdict, effects and held-out shrink of one input's JSON (for the batch table)."""
    body = json.loads(Path(json_path).read_text())
    verdict = body.get("verdict", {})
    return {
        "verdict": verdict.get("status", ""),
        "effects": "+".join(verdict.get("effects", [])),
        "shrink": body.get("holdout", {}).get("shrink"),
    }


def batch_table(outcomes: list[Any]) -> str:
    rows = []
    for o in outcomes:
        s = o.summary
        shrink = s.get("shrink")
        rows.append(
            [
                str(o.item.path),
                "ok" if o.ok else "FAILED",
                s.get("verdict", "-"),
                s.get("effects") or "-",
                "-" if shrink is None else f"{shrink:.0%}",
                f"{o.elapsed_s:.1f}",
            ]
        )
    return format_table(["input", "status", "verdict", "effects", "shrink", "s"], rows)
