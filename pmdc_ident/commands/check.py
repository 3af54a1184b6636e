"""``pmdc-ident check DATA... [units options] [--json PATH]``: the data-quality gate alone.

Prints one line per finding (the number measured and the fix); exit status 2
when an error would stop ``identify``/``diagnose``, else 0.
"""

from __future__ import annotations

import argparse
import json
import sys

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    check_ignore,
    data_megabytes,
    input_json,
    is_long,
    load_inputs,
    long_subset,
    make_progress,
    quality,
    segment_inputs,
    show_incomplete,
    show_quality,
    stop_on_errors,
)
from pmdc_ident.commands.outputs import STDOUT, check_file_output

PROGRESS_MB = 10.0

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
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    add_gate_arguments(parser)
    add_unit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    json_to = check_file_output("--json", args.json, args.data, suffixes=(".json",))
    text_out = sys.stderr if json_to == STDOUT else sys.stdout
    from pmdc_ident.core.fixed import parse_fix

    check_ignore(args)
    fixed = parse_fix(args.fix)
    # progress lines for large inputs only (a small file is checked in a second)
    progress = make_progress(args, quiet=data_megabytes(args) < PROGRESS_MB)

    def show(line: str) -> None:
        print(line, file=text_out)

    inputs = load_inputs(args, progress)
    show_incomplete(inputs, show)
    if is_long(args, inputs):  # the physics checks on a representative subset
        progress("finding the segments of the long record")
        segmented = segment_inputs(args, inputs, show=show)
        chosen = long_subset(args, segmented, show, progress)
        progress("checking")
        report = quality(args, chosen, fixed, whole=inputs)
        show_quality(report, info=True, show=show)
    else:
        progress("checking")
        report = quality(args, inputs, fixed)
        show_quality(report, info=True, show=show)
        segmented = segment_inputs(args, inputs, show=show)
    if json_to is not None:
        from pmdc_ident.core.assumptions import register_json
        from pmdc_ident.core.data import unique_labels

        segments = unique_labels(s for x in segmented for s in x.run.segments)
        body = {
            "sources": [x.path for x in inputs],
            **input_json(segmented, report),
            "assumptions_checked": register_json(report.findings, segments),
        }
        document = json.dumps(body, indent=2, allow_nan=False) + "\n"
        if json_to == STDOUT:
            print(document, end="")
        else:
            from pmdc_ident.core.safe_write import write_text

            write_text(json_to, document)
            print(f"wrote {json_to}", file=text_out)
    stop_on_errors(report)
    print(f"ok: no errors, {len(report.warnings)} warning(s)", file=text_out)
    return 0
