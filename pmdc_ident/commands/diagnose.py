"""``pmdc-ident diagnose DATA... [--holdout LABEL...] [--json PATH] [--report DIR]``.

Fits the linear model on part of the segments, measures its free-run error on
the held-out rest, localizes the gap, tries every effect of the vocabulary (and
combinations), and prints the verdict: ``no_gap``, ``explained`` by named
effects, or ``unexplained``. ``--json`` writes the DESIGN.md keys, ``--report``
an HTML page with plots.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from pmdc_ident.core.diagnosis import DiagnosisConfig, diagnose
from pmdc_ident.core.effects import EFFECT_NAMES
from pmdc_ident.core.errors import ParameterError
from pmdc_ident.dataio import load_data

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
        default=",".join(EFFECT_NAMES),
        metavar="NAME,...",
        help="effects of the vocabulary to try (default: all)",
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
    parser.add_argument("--json", metavar="PATH", help="write the results as JSON")
    parser.add_argument("--report", metavar="DIR", help="write an HTML page with plots here")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")


def run(args: argparse.Namespace) -> int:
    from pmdc_ident.commands.identify import parse_fix

    effects = tuple(e.strip() for e in args.effects.split(",") if e.strip())
    if not effects:
        msg = "--effects lists no effect"
        raise ParameterError(msg)
    config = DiagnosisConfig(
        holdout=tuple(args.holdout),
        effects=effects,
        fixed=parse_fix(args.fix),
        max_effects=args.max_effects,
    )
    t0 = time.perf_counter()

    def progress(msg: str) -> None:
        if not args.quiet:
            print(f"[{time.perf_counter() - t0:6.1f} s] {msg}", file=sys.stderr, flush=True)

    runs = [load_data(p) for p in args.data]
    result = diagnose(runs, config=config, progress=progress)
    print("\n".join(result.summary_lines()))
    print("split: " + "; ".join(result.split.description))
    written: list[Path] = []
    if args.json:
        path = Path(args.json)
        if path.parent and not path.parent.exists():
            path.parent.mkdir(parents=True)
        path.write_text(json.dumps(result.to_json(), indent=2) + "\n")
        written.append(path)
    if args.report:
        from pmdc_ident.report.diagnosis_html import write_report

        written.append(write_report(result, Path(args.report)))
    for p in written:
        print(f"wrote {p}")
    return 0
