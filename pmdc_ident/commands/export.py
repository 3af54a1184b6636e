"""``pmdc-ident export``: a bag to CSV (``--csv OUT.csv``) or a CSV to a bag (``--bag OUTDIR``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from pmdc_ident.commands.outputs import STDOUT, check_file_output, check_folder_output
from pmdc_ident.core.errors import DataError

HELP = "convert a recorded run: bag -> CSV (--csv OUT.csv) or CSV -> rosbag2/MCAP (--bag DIR)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", metavar="DATA", help="a bag directory, an .mcap file or a CSV")
    out = parser.add_mutually_exclusive_group(required=True)
    out.add_argument(
        "--csv", metavar="OUT.csv", help="write the run as CSV (a .csv name; - for stdout)"
    )
    out.add_argument(
        "--bag", metavar="OUTDIR", help="write the run as a new rosbag2/MCAP directory"
    )
    parser.add_argument(
        "--session", default=None, help="only this session of a bag (default: every session)"
    )
    from pmdc_ident.commands._inputs import add_unit_arguments

    add_unit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.commands._inputs import spec_of_args
    from pmdc_ident.dataio.units import convert_run, load_input, read_sidecar

    spec = spec_of_args(args)
    src = Path(args.data)
    is_bag = src.is_dir() or src.suffix.lower() == ".mcap"
    if args.session is not None and not is_bag:
        msg = "--session applies to bags only"
        raise DataError(msg)
    csv_to = check_file_output("--csv", args.csv, [src], suffixes=(".csv",))
    bag_to = check_folder_output("--bag", args.bag, [src], must_be_new=True)
    if is_bag:
        from pmdc_ident.dataio.bagio import read_bag

        full = spec.merged_over(read_sidecar(src))
        if full.columns:
            msg = f"{src}: --column applies to CSV files only (a bag has fixed topics)"
            raise DataError(msg)
        data, notes = convert_run(read_bag(src, session=args.session), full)
    else:
        loaded = load_input(src, spec)
        data, notes = loaded.run, loaded.notes
    from pmdc_ident.app.inputs import recording_of

    state = recording_of(str(src))
    if state is not None and not state.complete:
        more = state.lines(truncation=False)  # the reader logged the truncation itself
        notes = (*notes, *(line.removeprefix(f"{src}: ") for line in more))
    for note in notes:
        print(f"{src}: {note}", file=sys.stderr)
    summary = f"{len(data.segments)} segment(s), {sum(s.n for s in data.segments)} samples"
    if csv_to == STDOUT:
        from pmdc_ident.dataio.csvio import write_csv

        write_csv(data, sys.stdout)
        print(f"standard output: {summary}", file=sys.stderr)
        return 0
    if csv_to is not None:
        from pmdc_ident.dataio.csvio import write_csv

        out = write_csv(data, csv_to)
    else:
        from pmdc_ident.dataio.bagio import write_bag

        assert bag_to is not None  # argparse: exactly one of --csv, --bag
        out = write_bag(data, bag_to, session=src.stem or "export")
    print(f"{out}: {summary}")
    return 0
