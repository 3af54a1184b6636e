"""``pmdc-ident export``: a bag to CSV (``--csv OUT.csv``) or a CSV to a bag (``--bag OUTDIR``)."""

from __future__ import annotations

import argparse
from pathlib import Path

from pmdc_ident.core.errors import DataError

HELP = "convert a recorded run: bag -> CSV (--csv OUT.csv) or CSV -> rosbag2/MCAP (--bag DIR)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("data", metavar="DATA", help="a bag directory, an .mcap file or a CSV")
    out = parser.add_mutually_exclusive_group(required=True)
    out.add_argument("--csv", metavar="OUT.csv", type=Path, help="write the run as CSV")
    out.add_argument(
        "--bag", metavar="OUTDIR", type=Path, help="write the run as a rosbag2/MCAP directory"
    )
    parser.add_argument(
        "--session", default=None, help="only this session of a bag (default: every session)"
    )


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.dataio import load_data

    src = Path(args.data)
    is_bag = src.is_dir() or src.suffix.lower() == ".mcap"
    if args.session is not None and not is_bag:
        msg = "--session applies to bags only"
        raise DataError(msg)
    if is_bag:
        from pmdc_ident.dataio.bagio import read_bag

        data = read_bag(src, session=args.session)
    else:
        data = load_data(src)
    if args.csv is not None:
        from pmdc_ident.dataio.csvio import write_csv

        write_csv(data, args.csv)
        out = args.csv
    else:
        from pmdc_ident.dataio.bagio import write_bag

        out = write_bag(data, args.bag, session=src.stem or "export")
    n = sum(s.n for s in data.segments)
    print(f"{out}: {len(data.segments)} segment(s), {n} samples")
    return 0
