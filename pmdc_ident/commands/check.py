"""``pmdc-ident check DATA... [units options] [--json PATH]``: the data-quality gate alone.

Prints one line per finding (the number measured and the fix); exit status 2
when an error would stop ``identify``/``diagnose``, else 0.
"""

from __future__ import annotations

import argparse
import sys

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    data_megabytes,
    input_options,
    make_progress,
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
    from pmdc_ident.app import CheckOptions
    from pmdc_ident.app.inputs import check_ignore
    from pmdc_ident.app.service import check_inputs
    from pmdc_ident.core.fixed import parse_fix

    check_ignore(args.ignore)
    options = input_options(CheckOptions, args, parse_fix(args.fix))
    # progress lines for large inputs only (a small file is checked in a second)
    progress = make_progress(args, quiet=data_megabytes(args) < PROGRESS_MB)
    docs = check_inputs(options, show=lambda line: print(line, file=text_out), progress=progress)
    if json_to == STDOUT:
        print(docs.json_text, end="")
    elif json_to is not None:
        from pmdc_ident.core.safe_write import write_text

        write_text(json_to, docs.json_text)
        print(f"wrote {json_to}", file=text_out)
    print(docs.stop_on_errors(), file=text_out)
    return 0
