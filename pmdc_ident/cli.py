"""The ``pmdc-ident`` command: a thin layer over the ROS-free core.

Each sub-command lives in ``pmdc_ident/commands/<module>.py`` and defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. A user
error (:class:`~pmdc_ident.core.errors.PmdcError`, a missing file) becomes one
line on stderr and a non-zero exit status, never a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Sequence

from pmdc_ident import __version__
from pmdc_ident.core.errors import PmdcError

__all__ = ["EXIT_INTERRUPTED", "EXIT_USER_ERROR", "main"]

EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130

# command name -> module under pmdc_ident.commands
COMMANDS: dict[str, str] = {
    "identify": "identify",
    "diagnose": "diagnose",
    "export": "export",
    "virtual-board": "virtual_board",
    "benchmark": "benchmark",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pmdc-ident",
        description="Identify brushed PMDC motor parameters and diagnose the sim-to-real gap.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module_name in COMMANDS.items():
        try:
            module = importlib.import_module(f"pmdc_ident.commands.{module_name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"pmdc_ident.commands.{module_name}":
                continue  # command not part of this build
            raise
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except PmdcError as exc:
        print(f"pmdc-ident {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_USER_ERROR
    except (FileNotFoundError, IsADirectoryError, PermissionError) as exc:
        print(f"pmdc-ident {args.command}: error: {exc.strerror}: {exc.filename}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt:
        print(f"pmdc-ident {args.command}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
