"""Child processes that end with their parent, on every way out.

A batch or a benchmark runs its inputs in worker processes. Whatever happens to the
parent - Ctrl-C, SIGTERM, SIGHUP (the terminal closed), ``kill -9`` - no worker may
keep running, and nothing may be left behind (no forkserver, no resource tracker, no
leaked semaphores). So the pool here is plain: each worker is ``python -m
pmdc_ident.core.workers`` started with :mod:`subprocess`, talking over two pipes of
its own (pickled calls in, pickled results out), with

* ``PR_SET_PDEATHSIG`` (Linux ``prctl``, via ctypes) set between fork and exec: the
  kernel kills the worker when the parent dies, even by ``kill -9``;
* SIGINT ignored in the worker (Ctrl-C reaches the whole process group; the parent
  decides), SIGTERM and SIGHUP raising :class:`SystemExit` so a write in progress
  removes its temporary file (``core.safe_write``);
* the parent stopping every worker when it stops (SIGTERM, then SIGKILL after a grace
  period, each reaped) - :meth:`WorkerPool.close` runs on every exit of the ``with``
  block, a ``KeyboardInterrupt`` included.

No multiprocessing machinery (forkserver, resource tracker, queues with semaphores)
is used: only :class:`multiprocessing.connection.Connection` over the pipes.
"""

from __future__ import annotations

import contextlib
import ctypes
import importlib
import os
import pickle
import signal
import subprocess
import sys
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from typing import Any

__all__ = [
    "WorkerError",
    "WorkerPool",
    "die_with_parent",
    "pdeathsig_preexec",
]

PR_SET_PDEATHSIG = 1
_libc_prctl: Any = None


def _prctl() -> Any:
    """libc's ``prctl`` (looked up once, in the parent: a forked child only calls it)."""
    global _libc_prctl
    if _libc_prctl is None and sys.platform.startswith("linux"):
        try:
            _libc_prctl = ctypes.CDLL(None, use_errno=True).prctl
        except (OSError, AttributeError):
            _libc_prctl = False
    return _libc_prctl or None


def die_with_parent(sig: int = signal.SIGKILL, parent_pid: int | None = None) -> bool:
    """Have the kernel send ``sig`` to this process when its parent dies (Linux).

    Exits at once (status 128 + ``sig``) when the parent ``parent_pid`` is already
    gone (it died before the request was made). False where the platform has no
    ``prctl`` (then the caller's own watch is the only guard).
    """
    prctl = _prctl()
    if prctl is None:
        return False
    prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
    if parent_pid is not None and os.getppid() != parent_pid:
        os._exit(128 + int(sig))
    return True


def pdeathsig_preexec(
    sig: int = signal.SIGTERM, then: Callable[[], None] | None = None
) -> Callable[[], None]:
    """A ``preexec_fn`` for :class:`subprocess.Popen`: the child gets ``sig`` when this
    process dies (the setting survives ``exec``), then runs ``then`` (if given)."""
    parent = os.getpid()
    _prctl()  # resolved before the fork

    def preexec() -> None:
        die_with_parent(sig, parent)
        if then is not None:
            then()

    return preexec


class WorkerError(Exception):
    """A task failed in its worker: the message names the exception, or the worker died."""


@dataclass
class _Worker:
    proc: subprocess.Popen[bytes]
    conn: Any  # multiprocessing.connection.Connection (results)
    send: Any  # Connection (tasks)
    task: Any = None  # key of the task it runs, None when idle


class WorkerPool:
    """``jobs`` worker processes that die with this one; a context manager.

    :meth:`run` hands tasks ``(key, "module:function", args)`` to the workers and
    yields ``(key, result)`` as they finish (:class:`WorkerError` as the result when
    the call raised or the worker died; a dead worker is replaced while tasks remain).
    """

    def __init__(self, jobs: int, *, quiet: bool = True) -> None:
        self.jobs = max(1, int(jobs))
        self.quiet = quiet and not os.environ.get("PMDC_IDENT_DEBUG")
        self._workers: list[_Worker] = []

    def __enter__(self) -> WorkerPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def pids(self) -> list[int]:
        return [w.proc.pid for w in self._workers]

    def _start(self) -> _Worker:
        from multiprocessing.connection import Connection

        task_r, task_w = os.pipe()
        res_r, res_w = os.pipe()
        out = subprocess.DEVNULL if self.quiet else None
        try:
            proc = subprocess.Popen(
                [sys.executable, "-m", "pmdc_ident.core.workers", str(task_r), str(res_w)],
                pass_fds=(task_r, res_w),
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=out,
                preexec_fn=pdeathsig_preexec(signal.SIGKILL),  # noqa: PLW1509
                env={**os.environ, "PMDC_WORKER_PARENT": str(os.getpid())},
            )
        finally:
            os.close(task_r)
            os.close(res_w)
        w = _Worker(proc, Connection(res_r, writable=False), Connection(task_w, readable=False))
        self._workers.append(w)
        return w

    def run(self, tasks: Iterable[tuple[Any, str, tuple[Any, ...]]]) -> Iterator[tuple[Any, Any]]:
        from multiprocessing.connection import wait

        todo = deque(tasks)
        while todo or any(w.task is not None for w in self._workers):
            while todo and len(self._workers) < self.jobs:
                self._start()
            for w in self._workers:
                if w.task is None and todo:
                    key, target, args = todo.popleft()
                    w.task = key
                    try:
                        w.send.send((target, args))
                    except (OSError, ValueError):
                        pass  # it died: its EOF is read below
            busy = {w.conn: w for w in self._workers if w.task is not None}
            for conn in wait(list(busy)):
                w = busy[conn]
                key, w.task = w.task, None
                try:
                    ok, value = conn.recv()
                except (EOFError, OSError):
                    code = w.proc.wait()
                    self._drop(w)
                    how = f"signal {-code}" if code < 0 else f"exit status {code}"
                    yield key, WorkerError(f"its worker process ended ({how})")
                    continue
                yield key, value if ok else WorkerError(value)

    def _drop(self, w: _Worker) -> None:
        for c in (w.conn, w.send):
            with contextlib.suppress(OSError):
                c.close()
        if w in self._workers:
            self._workers.remove(w)

    def close(self, grace_s: float = 2.0) -> None:
        """Stop every worker (SIGTERM, SIGKILL after ``grace_s``) and reap it."""
        workers, self._workers = list(self._workers), []
        for w in workers:
            with contextlib.suppress(OSError):
                w.send.close()  # an idle worker ends at EOF
            if w.task is not None and w.proc.poll() is None:
                with contextlib.suppress(OSError):
                    w.proc.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + grace_s
        for w in workers:
            try:
                w.proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                with contextlib.suppress(OSError):
                    w.proc.kill()
                w.proc.wait()
            with contextlib.suppress(OSError):
                w.conn.close()


def _exit_on(signum: int, _frame: Any) -> None:
    raise SystemExit(128 + signum)


def _serve(task_fd: int, result_fd: int) -> int:
    from multiprocessing.connection import Connection

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides on Ctrl-C
    signal.signal(signal.SIGTERM, _exit_on)
    signal.signal(signal.SIGHUP, _exit_on)
    parent = os.environ.get("PMDC_WORKER_PARENT")
    die_with_parent(signal.SIGKILL, int(parent) if parent else None)
    tasks = Connection(task_fd, writable=False)
    results = Connection(result_fd, readable=False)
    while True:
        try:
            target, args = tasks.recv()
        except (EOFError, OSError):
            return 0
        module, _, name = target.partition(":")
        try:
            value = getattr(importlib.import_module(module), name)(*args)
            try:
                results.send((True, value))
                continue
            except (pickle.PicklingError, TypeError, AttributeError) as exc:
                text = f"its result could not be sent back ({type(exc).__name__}: {exc})"
        except Exception as exc:  # noqa: BLE001 - reported to the parent as one line
            text = f"{type(exc).__name__}: {exc}"
        try:
            results.send((False, text))
        except OSError:
            return 1


if __name__ == "__main__":
    sys.exit(_serve(int(sys.argv[1]), int(sys.argv[2])))
