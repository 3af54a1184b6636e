"""The ``pmdc-ident`` command: a thin layer over the ROS-free core.

Each sub-command lives in ``pmdc_ident/commands/<module>.py`` and defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. A user
error (:class:`~pmdc_ident.core.errors.PmdcError`, a file that cannot be read
or written) is one line on stderr and exit status 2; Ctrl-C at any moment is one
line and 130; a bug of ours is one line and 1 (``PMDC_IDENT_DEBUG=1`` shows its
traceback). Never a traceback by default.
"""

from __future__ import annotations

import argparse
import gc
import importlib
import os
import sys
from collections.abc import Sequence

from pmdc_ident import __version__
from pmdc_ident._blas import limit_blas_threads

__all__ = ["EXIT_INTERNAL_ERROR", "EXIT_INTERRUPTED", "EXIT_USER_ERROR", "main"]

EXIT_INTERNAL_ERROR = 1
EXIT_USER_ERROR = 2
EXIT_INTERRUPTED = 130

# command name -> module under pmdc_ident.commands
COMMANDS: dict[str, str] = {
    "identify": "identify",
    "diagnose": "diagnose",
    "check": "check",
    "export": "export",
    "export-model": "export_model",
    "monitor": "monitor",
    "virtual-board": "virtual_board",
    "benchmark": "benchmark",
    "roundtrip": "roundtrip",
    "plan": "plan",
}


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser of every command, or of command ``only`` alone (its module is then the
    only one imported: a command's own start-up does not pay for the others)."""
    parser = argparse.ArgumentParser(
        prog="pmdc-ident",
        description="Identify brushed PMDC motor parameters and diagnose the sim-to-real gap.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module_name in COMMANDS.items():
        if only is not None and name != only:
            continue
        module = importlib.import_module(f"pmdc_ident.commands.{module_name}")
        p = sub.add_parser(name, help=module.HELP, description=module.HELP)
        module.add_arguments(p)
        p.set_defaults(_run=module.run)
    return parser


def _interrupted(exc: BaseException) -> bool:
    """``exc`` is, or was caused by, a Ctrl-C.

    A Ctrl-C that lands while compiled (numba) code calls back into Python
    surfaces as a ``SystemError`` "returned a result with an exception set"
    whose cause is the ``KeyboardInterrupt``.
    """
    seen: set[int] = set()
    e: BaseException | None = exc
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command in ``argv`` (default ``sys.argv[1:]``); its exit status.

    Called without ``argv`` (the ``pmdc-ident`` program itself), the heap is frozen
    before returning: the interpreter's finalisation would otherwise walk every object
    the command left (numba's, the data's) for its last garbage collections, about
    0.2 s of CPU after ``identify`` has printed its result, for memory the operating
    system takes back anyway. Open files are closed by then (the commands close what
    they write), and ``atexit`` handlers still run. In-process callers (tests, batch
    workers) pass ``argv`` and keep a collectable heap.
    """
    status = _run(argv)
    if argv is None:
        gc.freeze()
    return status


def _run(argv: Sequence[str] | None) -> int:
    command = ""
    user_errors: tuple[type[Exception], ...] = ()
    try:
        words = list(sys.argv[1:] if argv is None else argv)
        command = next((w for w in words if w in COMMANDS), "")
        # Everything below, the imports of the command modules included, is
        # inside the try: a Ctrl-C at any moment is one line and exit 130.
        limit_blas_threads()  # before numpy is imported (batch workers inherit it)
        from pmdc_ident.core.errors import PmdcError

        user_errors = (PmdcError,)
        # the command word first (options aside): only its parser is built; anything
        # else (a typo, --help) gets the full parser and its own message
        first = next((w for w in words if not w.startswith("-")), "")
        parser = build_parser(first if first in COMMANDS else None)
        args = parser.parse_args(argv)
        command = args.command
        return int(args._run(args) or 0)
    except BaseException as exc:  # noqa: BLE001 - sorted below; SystemExit passes
        if isinstance(exc, SystemExit):
            raise
        return _exit_status(command, exc, user_errors)


def _exit_status(
    command: str, exc: BaseException, user_errors: tuple[type[Exception], ...]
) -> int:
    """One line on stderr for ``exc`` and the exit status; never a traceback."""
    prog = f"pmdc-ident {command}".rstrip()
    if _interrupted(exc):
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    if isinstance(exc, user_errors):
        return _fail(prog, str(exc))
    if isinstance(exc, BrokenPipeError):
        # the reader of stdout went away (`| head`): not an error of ours
        _silence_stdout()
        return 0
    if isinstance(exc, OSError):
        where = f": {exc.filename}" if exc.filename else ""
        return _fail(prog, f"{exc.strerror or exc}{where}")
    if isinstance(exc, MemoryError):
        return _fail(prog, "out of memory (the data are too large for this machine)")
    if os.environ.get("PMDC_IDENT_DEBUG"):
        raise exc
    first = (str(exc).splitlines() or [""])[0]
    print(
        f"{prog}: internal error: {type(exc).__name__}: {first} "
        "(a bug: please report it; PMDC_IDENT_DEBUG=1 shows the traceback)",
        file=sys.stderr,
    )
    return EXIT_INTERNAL_ERROR


def _fail(prog: str, message: str) -> int:
    # one line, whatever a library put in the message
    print(f"{prog}: error: {' '.join(message.split())}", file=sys.stderr)
    return EXIT_USER_ERROR


def _silence_stdout() -> None:
    # Python flushes stdout at exit; with the reader gone that flush would
    # print a BrokenPipeError of its own.
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
