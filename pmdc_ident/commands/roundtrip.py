"""``pmdc-ident roundtrip DATA... [--mujoco-dir DIR] [--json PATH]``: the diagnosis, in MuJoCo.

Diagnoses the recorded run (as ``diagnose``), exports the plain model and the model
with the diagnosis to MuJoCo's ``<dcmotor>`` (as ``export-model --mujoco --diagnosis``),
replays the recorded voltage of every held-out segment in MuJoCo and prints the
held-out gap of both, beside the same two models in the project's own simulator:
how far the gap shrinks in the simulator users train in (docs/mujoco.md).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from pmdc_ident.commands._inputs import (
    add_gate_arguments,
    add_unit_arguments,
    make_progress,
)
from pmdc_ident.commands.outputs import (
    STDOUT,
    check_distinct,
    check_file_output,
    check_folder_output,
    check_inputs_distinct,
)
from pmdc_ident.core.effects import DEFAULT_CANDIDATES
from pmdc_ident.core.errors import ParameterError, PmdcError
from pmdc_ident.core.safe_write import write_text

HELP = (
    "diagnose a recorded run, export it to MuJoCo with the diagnosis, replay the recorded "
    "voltage there and print the held-out gap of the plain and the diagnosed export"
)
MJCF_FILES = ("plain.mjcf.xml", "diagnosed.mjcf.xml")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "data", nargs="+", metavar="DATA", help="CSV file, .mcap file or rosbag2 directory"
    )
    parser.add_argument(
        "--holdout", nargs="+", default=[], metavar="LABEL", help="as for diagnose"
    )
    parser.add_argument(
        "--effects",
        default=",".join(DEFAULT_CANDIDATES),
        metavar="NAME,...",
        help="effects the diagnosis tries (default: as diagnose)",
    )
    parser.add_argument(
        "--fix", action="append", default=[], metavar="NAME=VALUE", help="as for diagnose"
    )
    parser.add_argument(
        "--substeps",
        type=int,
        default=50,
        metavar="N",
        help="MuJoCo steps per sample of the replay (default 50)",
    )
    parser.add_argument(
        "--mujoco-dir",
        metavar="DIR",
        help=f"write the two MJCF models here ({', '.join(MJCF_FILES)}; created, its parent "
        "must exist)",
    )
    parser.add_argument("--json", metavar="PATH", help="the round trip as JSON (.json; - stdout)")
    parser.add_argument("--quiet", action="store_true", help="no progress messages on stderr")
    add_gate_arguments(parser)
    add_unit_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from pmdc_ident.app.service import diagnose_inputs
    from pmdc_ident.commands.diagnose import diagnose_options
    from pmdc_ident.core.fixed import parse_fix
    from pmdc_ident.core.params import PARAMETER_NAMES

    options = diagnose_options(args)
    if not 1 <= args.substeps <= 2000:
        msg = f"--substeps must lie in [1, 2000] MuJoCo steps per sample, got {args.substeps}"
        raise ParameterError(msg)
    targets = {
        "--json": check_file_output("--json", args.json, args.data, suffixes=(".json",)),
        "--mujoco-dir": check_folder_output("--mujoco-dir", args.mujoco_dir, args.data),
    }
    check_distinct(targets)
    check_inputs_distinct(args.data)
    try:
        import mujoco  # noqa: F401 - the replay's simulator (a benchmark/export dependency)
    except ImportError:
        msg = (
            "roundtrip replays in MuJoCo: install the mujoco package (>= 4, a benchmark "
            'and export dependency): pip install "mujoco==4.0.0" (make venv installs it)'
        )
        raise PmdcError(msg) from None
    json_to, mjcf_to = targets["--json"], targets["--mujoco-dir"]
    text_out = sys.stderr if json_to == STDOUT else sys.stdout
    progress = make_progress(args)
    options = replace(options, fixed=parse_fix(args.fix, known=PARAMETER_NAMES))
    docs = diagnose_inputs(
        options, show=lambda line: print(line, file=text_out), progress=progress
    )
    result = docs.result
    progress("round trip: the held-out segments replayed in MuJoCo")
    from pmdc_ident.exports.roundtrip import round_trip

    trip = round_trip(result, substeps=args.substeps)
    print("\n".join(trip.lines()), file=text_out)
    if mjcf_to is not None:
        folder = Path(mjcf_to)
        folder.mkdir(exist_ok=True)
        for name, text in zip(MJCF_FILES, (trip.xml_plain, trip.xml_diagnosed), strict=True):
            write_text(folder / name, text)
            print(f"wrote {folder / name}", file=text_out)
    if json_to is not None:
        document = json.dumps(trip.to_json(), indent=2) + "\n"
        if json_to == STDOUT:
            print(document, end="")
        else:
            write_text(json_to, document)
            print(f"wrote {json_to}", file=text_out)
    return 0
