"""``pmdc-ident check DATA... [units options] [--json PATH]``: the data-quality gate alone.

Prints one line per finding (the number measured and the fix); exit status 2
when an error would stop ``identify``/``diagnose``, else 0.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    check_ignore,
    load_inputs,
    quality,
    segment_inputs,
    show_quality,
    stop_on_errors,
)
from pmdc_ident.commands.outputs import STDOUT, check_file_output

HELP = "check recordings before a fit: timing, units, signs, clipping, encoder, delay, duplicates"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data", nargs="+", metavar="DATA", help="CSV file, .mcap file or rosbag2 directory"
    )
    parser.add_argument(
        "--json", metavar="PATH", help="write the findings as JSON (.json; - for stdout)"
    )
    parser.add_argument(
        "--fix",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter the fit will hold (SI units): left out of the expected uncertainties",
    )
    add_gate_arguments(parser)
    add_unit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    json_to = check_file_output("--json", args.json, args.data, suffixes=(".json",))
    text_out = sys.stderr if json_to == STDOUT else sys.stdout
    from pmdc_ident.core.fixed import parse_fix

    check_ignore(args)
    fixed = parse_fix(args.fix)
    inputs = load_inputs(args)
    report = quality(args, inputs, fixed)
    show_quality(report, info=True, show=lambda line: print(line, file=text_out))
    inputs = segment_inputs(args, inputs, show=lambda line: print(line, file=text_out))
    if json_to is not None:
        from pmdc_ident.core.assumptions import register_json
        from pmdc_ident.core.data import unique_labels

        segments = unique_labels(s for x in inputs for s in x.run.segments)
        body = {
            "sources": [x.path for x in inputs],
            "quality": report.to_json(),
            "assumptions_checked": register_json(report.findings, segments),
        }
        document = json.dumps(body, indent=2, allow_nan=False) + "\n"
        if json_to == STDOUT:
            print(document, end="")
        else:
            Path(json_to).write_text(document)
            print(f"wrote {json_to}", file=text_out)
    stop_on_errors(report)
    print(f"ok: no errors, {len(report.warnings)} warning(s)", file=text_out)
    return 0
