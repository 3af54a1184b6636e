"""Many inputs at once: ``identify --batch DIR`` and ``diagnose --batch DIR``.

Each input (a bag, an ``.mcap`` or a CSV; a folder stands for the bags and CSVs
in it, a quoted glob for its matches) is processed on its own by the command's
own ``run`` - the same gate, options and numbers as one call per input - in
``--jobs`` worker processes. Each input's JSON (and its text report) goes to the
batch folder; a failure is one line in the final list and never stops the
batch. A progress bar is drawn on a terminal; the summary table goes to stdout.

Light at import time (the fast ``--help`` rule): workers import the numerical
core themselves.
"""

from __future__ import annotations

import argparse
import contextlib
import glob
import importlib
import io
import os
import re
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import ParameterError, PmdcError

__all__ = [
    "BatchItem",
    "Outcome",
    "add_batch_arguments",
    "expand_inputs",
    "run_batch",
]

DATA_SUFFIXES = (".csv", ".txt", ".mcap")
MAX_JOBS = 256
_GLOB = re.compile(r"[*?\[]")


def add_batch_arguments(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("batch (many recordings, one result each)")
    g.add_argument(
        "--batch",
        metavar="DIR",
        help="process each DATA on its own (a folder: every bag, .mcap and CSV in it; a "
        "quoted glob: its matches) and write DIR/<input>.json and .txt per input; one "
        "summary table on stdout; a failed input is listed and the batch goes on",
    )
    g.add_argument(
        "--jobs",
        type=int,
        default=None,
        metavar="N",
        help="worker processes for --batch (default: the number of CPUs)",
    )


def _is_bag_dir(p: Path) -> bool:
    return p.is_dir() and (p / "metadata.yaml").is_file()


def _inputs_in(folder: Path) -> list[Path]:
    found = [
        c
        for c in sorted(folder.iterdir())
        if _is_bag_dir(c) or (c.is_file() and c.suffix.lower() in DATA_SUFFIXES)
    ]
    # a sidecar (run.csv + run.yaml) and bag internals are not inputs of their own
    return [c for c in found if not (c.suffix.lower() == ".mcap" and _is_bag_dir(c.parent))]


def expand_inputs(items: Sequence[str]) -> list[Path]:
    """The inputs the DATA arguments name, in order, each once."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if not p.exists() and _GLOB.search(item):
            matches = [Path(m) for m in sorted(glob.glob(item))]
            if not matches:
                msg = f"{item}: no file matches this pattern"
                raise ParameterError(msg)
            for m in matches:
                out += _inputs_in(m) if m.is_dir() and not _is_bag_dir(m) else [m]
        elif p.is_dir() and not _is_bag_dir(p):
            inside = _inputs_in(p)
            if not inside:
                msg = f"{p}: a folder with no bag, .mcap or CSV in it"
                raise ParameterError(msg)
            out += inside
        else:
            out.append(p)  # a missing file is the worker's one-line failure
    seen: set[Path] = set()
    unique = []
    for p in out:
        key = p.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(p)
    return unique


def _names(paths: Sequence[Path]) -> list[str]:
    """One file name per input (its stem; a number added when two stems collide)."""
    stems = [p.stem if p.suffix else p.name for p in paths]
    out = []
    for k, s in enumerate(stems):
        out.append(s if stems.count(s) == 1 else f"{s}_{k + 1:03d}")
    return out


@dataclass(frozen=True)
class BatchItem:
    """One input of a batch and where its results go."""

    path: Path
    json_path: Path
    text_path: Path


@dataclass
class Outcome:
    item: BatchItem
    ok: bool
    error: str = ""
    elapsed_s: float = 0.0
    summary: dict[str, Any] = field(default_factory=dict)
    cpu_s: float = 0.0  # CPU time of the worker process on this input


def _run_one(
    module_name: str, options: dict[str, Any], item: BatchItem, summarize_name: str
) -> Outcome:
    """Worker: the command's own run() on one input, its output into the item's files.

    The files appear complete or not at all (``core.safe_write``); an interrupted
    input writes nothing (the previous run's files stay as they were), and a failed
    one removes the previous run's JSON, so no result of an older run stands for
    this one (its text report says why it failed).
    """
    from pmdc_ident.core.safe_write import reading_scope, write_text

    module = importlib.import_module(module_name)
    args = argparse.Namespace(**options)
    args.data = [str(item.path)]
    args.json = str(item.json_path)
    args.quiet = True
    buf = io.StringIO()
    t0, c0 = time.perf_counter(), time.process_time()
    failure = ""
    with reading_scope():
        try:
            with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
                rc = int(module.run(args) or 0)
            if rc != 0:
                failure = f"exit status {rc}"
        except PmdcError as exc:
            failure = str(exc).strip().splitlines()[0].removeprefix(f"{item.path}: ")
        except OSError as exc:
            failure = f"{exc.strerror or type(exc).__name__}: {exc.filename}"
        except Exception as exc:  # noqa: BLE001 - one input's bug must not stop the batch
            failure = f"internal error: {type(exc).__name__}: {exc}"
    elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
    text = buf.getvalue() + (f"FAILED: {failure}\n" if failure else "")
    try:
        write_text(item.text_path, text)
        if failure:
            item.json_path.unlink(missing_ok=True)  # an older run's result, not this one's
    except OSError as exc:
        failure = failure or f"{exc.strerror or type(exc).__name__}: {exc.filename}"
    if failure:
        return Outcome(item, False, failure, elapsed, cpu_s=cpu)
    summarize: Callable[[Path], dict[str, Any]] = getattr(module, summarize_name)
    return Outcome(item, True, "", elapsed, summarize(item.json_path), cpu)


def _check_items(out: Path, items: Sequence[BatchItem], paths: Sequence[Path]) -> None:
    """No file of the batch replaces an input or its sidecar (``--batch logs logs`` would
    write ``logs/run.txt`` over a recording ``run.txt``): refused before any work."""
    from pmdc_ident.commands.outputs import OutputError, reads_of
    from pmdc_ident.core.safe_write import conflict

    reads = reads_of(paths)
    for item in items:
        for target in (item.json_path, item.text_path):
            why = conflict(target, reads)
            if why is not None:
                msg = (
                    f"--batch {out}: would write {target}, {why}; refusing to write over an "
                    "input: choose a folder for the results that holds no input"
                )
                raise OutputError(msg)


class _Progress:
    """A one-line progress bar on a terminal; one line per input otherwise (unless quiet)."""

    def __init__(self, total: int, stream: TextIO, quiet: bool) -> None:
        self.total, self.stream, self.quiet = total, stream, quiet
        self.tty = stream.isatty()
        self.done = self.failed = 0
        self.t0 = time.perf_counter()

    def update(self, o: Outcome) -> None:
        self.done += 1
        self.failed += not o.ok
        elapsed = time.perf_counter() - self.t0
        if self.tty:
            width = 30
            fill = round(width * self.done / self.total)
            eta = elapsed / self.done * (self.total - self.done)
            self.stream.write(
                f"\r[{'#' * fill}{'.' * (width - fill)}] {self.done}/{self.total} "
                f"({self.failed} failed) {elapsed:5.0f} s, ~{eta:4.0f} s left "
            )
            if self.done == self.total:
                self.stream.write("\n")
        elif not self.quiet:
            state = "ok" if o.ok else f"FAILED: {o.error}"
            self.stream.write(
                f"[{self.done}/{self.total} {elapsed:6.1f} s] {o.item.path}: {state}\n"
            )
        self.stream.flush()


def _outcomes(
    module_name: str, options: dict[str, Any], items: list[BatchItem], jobs: int, summarize: str
) -> Iterator[Outcome]:
    if jobs <= 1 or len(items) == 1:
        for item in items:
            yield _run_one(module_name, options, item, summarize)
        return
    from pmdc_ident.core.workers import WorkerError, WorkerPool

    # fresh interpreters that die with this process (core.workers): on Ctrl-C, SIGTERM,
    # SIGHUP or kill -9 of the batch no worker keeps running
    by_key = dict(enumerate(items))
    target = f"{__name__}:_run_one"
    tasks = [(k, target, (module_name, options, it, summarize)) for k, it in by_key.items()]
    with WorkerPool(jobs) as pool:
        for k, value in pool.run(tasks):
            if isinstance(value, WorkerError):
                yield Outcome(by_key[k], False, f"internal error: {value}")
            else:
                yield value


def run_batch(
    args: argparse.Namespace,
    module_name: str,
    table: Callable[[list[Outcome]], str],
    *,
    summarize: str = "batch_summary",
    forbidden: Sequence[str] = (),
) -> int:
    """Process every input of ``args.data`` on its own; the summary table; the exit status.

    0 when every input succeeded, 2 when any failed (each failure listed).
    """
    for option in forbidden:
        if getattr(args, option.lstrip("-").replace("-", "_"), None):
            msg = f"{option} is per run: not with --batch (each input's JSON goes to the folder)"
            raise ParameterError(msg)
    jobs = args.jobs if args.jobs is not None else (os.cpu_count() or 1)
    from pmdc_ident.commands._bounds import Bound

    Bound("--jobs", 1, MAX_JOBS, "worker processes", integer=True).check(jobs)
    paths = expand_inputs(args.data)
    from pmdc_ident.commands.outputs import check_folder_output

    out = check_folder_output("--batch", args.batch, paths)
    assert out is not None
    out.mkdir(exist_ok=True)  # its parent exists (checked): no tree of new folders
    items = [
        BatchItem(p, out / f"{name}.json", out / f"{name}.txt")
        for p, name in zip(paths, _names(paths), strict=True)
    ]
    _check_items(out, items, paths)
    options = {k: v for k, v in vars(args).items() if not k.startswith("_")}
    options.update(batch=None, jobs=None)
    progress = _Progress(len(items), sys.stderr, bool(getattr(args, "quiet", False)))
    outcomes: list[Outcome] = []
    t0 = time.perf_counter()
    for o in _outcomes(module_name, options, items, min(jobs, len(items)), summarize):
        outcomes.append(o)
        progress.update(o)
    wall = time.perf_counter() - t0
    order = {item.path: k for k, item in enumerate(items)}
    outcomes.sort(key=lambda o: order[o.item.path])
    print(table(outcomes))
    failed = [o for o in outcomes if not o.ok]
    n_ok = len(outcomes) - len(failed)
    rate = 60.0 * len(outcomes) / wall if wall > 0 else float("inf")
    cpu = sum(o.cpu_s for o in outcomes)
    print(
        f"{n_ok} of {len(outcomes)} inputs done in {wall:.1f} s wall ({cpu:.1f} s CPU in the "
        f"workers) with {jobs} job(s): {rate:.1f} per minute; results in {out}"
    )
    for o in failed:
        print(f"FAILED {o.item.path}: {o.error}")
    return ExitCode.USER_ERROR if failed else ExitCode.OK


def format_table(headers: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    """A plain aligned text table (first column left, the rest right)."""
    widths = [
        max(len(h), *(len(r[k]) for r in rows)) if rows else len(h) for k, h in enumerate(headers)
    ]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            c.ljust(w) if k == 0 else c.rjust(w)
            for k, (c, w) in enumerate(zip(cells, widths, strict=True))
        )

    return "\n".join([line(headers), *(line(r) for r in rows)])
