"""The ``pmdc-ident`` command: a thin layer over the ROS-free core.

Each sub-command lives in ``pmdc_ident/commands/<module>.py`` and defines
``HELP`` (one line), ``add_arguments(parser)`` and ``run(args) -> int``. A user
error (:class:`~pmdc_ident.core.errors.PmdcError`, a file that cannot be read
or written) is one line on stderr and exit status 2; Ctrl-C at any moment is one
line and 130; SIGTERM and SIGHUP (the terminal closed) end the command the same
way (one line, 128 + the signal's number), so every output in progress is removed
and every worker stopped; a bug of ours is one line and 1 (``PMDC_IDENT_DEBUG=1``
shows its traceback). Never a traceback by default.
"""

from __future__ import annotations

import signal
import sys

# First: a Ctrl-C that arrives while the program is still importing this module is
# held here (main raises it inside its try) instead of becoming a traceback. Only in
# the program itself: a process importing the module (a test runner) keeps its own.
_EARLY: list[int] = []


def _hold(signum: int, _frame: object) -> None:
    _EARLY.append(signum)


if sys.argv and sys.argv[0].rsplit("/", 1)[-1] in ("pmdc-ident", "-c"):
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, _hold)
    for _sig in (signal.SIGTERM, signal.SIGHUP):
        if signal.getsignal(_sig) == signal.SIG_DFL:
            signal.signal(_sig, _hold)

import argparse  # noqa: E402
import gc  # noqa: E402
import importlib  # noqa: E402
import os  # noqa: E402
from collections.abc import Iterator, Mapping, Sequence  # noqa: E402
from contextlib import contextmanager  # noqa: E402

from pmdc_ident import __version__  # noqa: E402
from pmdc_ident._blas import limit_blas_threads  # noqa: E402
from pmdc_ident.core.enums import ExitCode  # noqa: E402

__all__ = ["EXIT_INTERNAL_ERROR", "EXIT_INTERRUPTED", "EXIT_USER_ERROR", "main"]

EXIT_INTERNAL_ERROR = ExitCode.FAILED
EXIT_USER_ERROR = ExitCode.USER_ERROR
EXIT_INTERRUPTED = ExitCode.INTERRUPTED

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


class Terminated(KeyboardInterrupt):
    """SIGTERM or SIGHUP: the command ends as on Ctrl-C (outputs in progress removed,
    workers stopped), with exit status 128 + the signal's number."""

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


# the signals raised while the command runs: where one lands in a library that turns
# it into its own exception, the chain no longer names it (numpy's C extension import
# raised a bare ImportError for a SIGTERM under load)
_RAISED: list[int] = []


def _terminate(signum: int, _frame: object) -> None:
    _RAISED.append(signum)
    raise Terminated(signum)


def _interrupt(_signum: int, _frame: object) -> None:
    _RAISED.append(int(signal.SIGINT))
    raise KeyboardInterrupt


def _unraisable(hook: object) -> object:
    """A ``sys.unraisablehook`` that re-sends a signal whose exception landed where
    Python cannot raise it (a weakref callback, ``__del__``: it would print "Exception
    ignored in ..." with a traceback and go on): the handler then raises it at the next
    ordinary statement. Re-sent from a thread a moment later: sent from here, the handler
    ran at once, inside this hook, and its exception was printed as one more "ignored"
    traceback (the families rerun: Ctrl-C 0.3 s into ``export --bag``)."""
    import threading

    def later(signum: int) -> None:
        t = threading.Timer(0.01, os.kill, (os.getpid(), signum))
        t.daemon = True
        t.start()

    def resend(unraisable: object) -> None:
        exc = getattr(unraisable, "exc_value", None)
        if isinstance(exc, Terminated):
            later(exc.signum)
            return
        if isinstance(exc, KeyboardInterrupt):
            later(signal.SIGINT)
            return
        hook(unraisable)  # type: ignore[operator]

    return resend


@contextmanager
def _signals(program: bool = False) -> Iterator[None]:
    """Ctrl-C, SIGTERM and SIGHUP as exceptions while the command runs (main thread).

    ``program``: this process is ``pmdc-ident`` itself and ends with the command, so a
    signal that comes once the command is over stays held (the work is done and its
    outputs are in place): restored to the default, it would raise in whatever runs
    between here and the exit (a late import, the heap freeze) as a traceback."""
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old_hook = sys.unraisablehook
    sys.unraisablehook = _unraisable(old_hook)  # type: ignore[assignment]
    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    signal.signal(signal.SIGTERM, _terminate)
    signal.signal(signal.SIGHUP, _terminate)
    if old[signal.SIGINT] in (_hold, signal.default_int_handler):
        signal.signal(signal.SIGINT, _interrupt)
    early, _EARLY[:] = list(_EARLY), []
    _RAISED[:] = early[:1]
    try:
        if early:  # a signal held while this module was imported
            raise KeyboardInterrupt if early[0] == signal.SIGINT else Terminated(early[0])
        yield
    finally:
        for s, h in old.items():
            if h is _hold and not program:
                h = signal.default_int_handler if s == signal.SIGINT else signal.SIG_DFL
            if h is not None:
                signal.signal(s, h)
        sys.unraisablehook = old_hook


def _signal_of(exc: BaseException) -> int | None:
    """The signal that ended the command (``exc`` or its cause), None for none: the first
    one sent when a second landed while the first was being handled (Ctrl-C, then SIGTERM
    during the clean-up: the command stopped because of the Ctrl-C)."""
    seen: set[int] = set()
    e: BaseException | None = exc
    found: int | None = None
    while e is not None and id(e) not in seen:
        if isinstance(e, Terminated):
            found = e.signum
        elif isinstance(e, KeyboardInterrupt):
            found = int(signal.SIGINT)
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return found


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


def _end_at_once(status: int) -> None:
    """End ``pmdc-ident`` stopped by a signal, its one line said: the output streams
    flushed and the ``atexit`` handlers run, then the process ends without freeing what
    the signal left half-built or finalising the interpreter. Freeing such native
    objects (llvmlite's, while numba compiled a kernel) crashed the process with SIGSEGV
    after "plan: interrupted" once (a fresh clone's suite; not reproduced in 75 tries);
    the files the command wrote are closed, or removed, by then."""
    import atexit

    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    atexit._run_exitfuncs()
    os._exit(status)


def _run(argv: Sequence[str] | None) -> int:
    command = ""
    user_errors: tuple[type[Exception], ...] = ()
    names: Mapping[str, str] | None = None
    try:
        words = list(sys.argv[1:] if argv is None else argv)
        command = next((w for w in words if w in COMMANDS), "")
        # Everything below, the imports of the command modules included, is
        # inside the try: a Ctrl-C at any moment is one line and exit 130.
        with _signals(program=argv is None):
            limit_blas_threads()  # before numpy is imported (batch workers inherit it)
            from pmdc_ident.app.options import CLI_NAMES
            from pmdc_ident.core.errors import PmdcError, wording
            from pmdc_ident.core.safe_write import reading_scope

            user_errors, names = (PmdcError,), CLI_NAMES
            # the command word first (options aside): only its parser is built; anything
            # else (a typo, --help) gets the full parser and its own message
            first = next((w for w in words if not w.startswith("-")), "")
            parser = build_parser(first if first in COMMANDS else None)
            args = parser.parse_args(argv)
            command = args.command
            # what the command reads, it never writes; the core names options as flags
            with reading_scope(), wording(CLI_NAMES):
                return int(args._run(args) or 0)
    except BaseException as exc:  # noqa: BLE001 - sorted below; SystemExit passes
        if isinstance(exc, SystemExit):
            raise
        status = _exit_status(command, exc, user_errors, names)
        if _RAISED:
            if argv is None:  # pmdc-ident itself: ends here, nothing the signal cut freed
                _end_at_once(status)
            _free_what_the_signal_cut(exc)
        return status


def _release(_unraisable: object) -> None:
    """A ``sys.unraisablehook`` that reports nothing."""


def _free_what_the_signal_cut(exc: BaseException) -> None:
    """Free, without a report, the objects a stop signal left half-built.

    A signal raises where it lands: in an ``__init__`` (llvmlite's, while numba compiled
    a kernel into an empty cache) the object is left without the fields its ``__del__``
    reads, and freeing it printed "Exception ignored in ... Traceback" after the one
    line (SIGTERM 0.5 s into ``identify``: llvmlite's ``PassBuilder`` had no
    ``_as_parameter_``; 1 of 30 random signal times on a cold cache). The frames of the
    exception chain hold them: cleared here, and collected, with such reports dropped.
    For in-process callers; ``pmdc-ident`` itself frees none of it (:func:`_end_at_once`)."""
    import traceback

    old = sys.unraisablehook
    sys.unraisablehook = _release  # type: ignore[assignment]
    try:
        seen: set[int] = set()
        e: BaseException | None = exc
        while e is not None and id(e) not in seen:
            seen.add(id(e))
            if e.__traceback__ is not None:
                traceback.clear_frames(e.__traceback__)
            e = e.__cause__ or e.__context__
        gc.collect()
    finally:
        sys.unraisablehook = old


def _exit_status(
    command: str,
    exc: BaseException,
    user_errors: tuple[type[Exception], ...],
    names: Mapping[str, str] | None = None,
) -> int:
    """One line on stderr for ``exc`` and the exit status; never a traceback."""
    prog = f"pmdc-ident {command}".rstrip()
    signum = _signal_of(exc)
    if signum is None and _RAISED:
        signum = _RAISED[0]  # it landed where a library replaced it with its own error
    if signum is not None:
        if signum == signal.SIGINT:
            _say(f"{prog}: interrupted")
            return EXIT_INTERRUPTED
        _say(f"{prog}: stopped by {signal.Signals(signum).name}")
        return 128 + signum
    if isinstance(exc, user_errors):
        render = getattr(exc, "render", None)  # an OptionError: the option as a flag
        return _fail(prog, render(names) if render is not None else str(exc))
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


def _say(line: str) -> None:
    """One line on stderr; nothing when stderr is gone (the terminal closed: SIGHUP)."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


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
