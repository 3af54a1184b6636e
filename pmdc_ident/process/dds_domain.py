"""One DDS domain per session on a shared machine: a cross-process lock per domain id.

Several test suites, benchmarks and ``make demo`` run at once on one machine. Two
of them on the same ``ROS_DOMAIN_ID`` see each other's topics: a recorder would
write the other session's samples, a driver would obey the other session's
commands. Each user of a domain therefore holds an exclusive ``flock`` on
``/tmp/pmdc_dds_domain_<id>.lock`` for as long as its processes run; the kernel
drops the lock when the holder exits, even on ``kill -9``, so a lock is never
stale.

- :func:`lock_domain` locks one given id (``make demo``, ``bringup``) and raises
  :class:`DomainBusyError` (naming the holder) when someone else holds it;
- :func:`allocate_domain` locks the first free id of :data:`POOL` (tests, benchmarks).

A process that already holds a domain may lock it again (nested, counted): a test
holding a domain can call ``run_session(domain_id=...)``, which locks it too. A
holder hands its domain to the processes it starts with :func:`child_env` (the
variable ``PMDC_DDS_DOMAIN_HELD``): a child ``bringup`` on that domain then runs
under its parent's lock instead of finding the domain busy. The session's nodes
also inherit the lock's descriptor (:meth:`DomainLock.fileno`, ``pass_fds``): a
``flock`` lasts until the last descriptor of it closes, so the domain stays held
until the last node of the session is gone - even when the process that took the
lock was killed first. ROS-free: no rclpy import here.
"""

from __future__ import annotations

import fcntl
import os
import random
import sys
import threading
from collections.abc import Iterable
from pathlib import Path

from pmdc_ident.core.errors import PmdcError

__all__ = [
    "POOL",
    "DomainBusyError",
    "DomainLock",
    "allocate_domain",
    "child_env",
    "lock_dir",
    "lock_domain",
]

# Ids handed out automatically. Left out: 0 (the ROS default: other software on the
# machine), 11-20 (passed by hand: `make test ROS_DOMAIN_ID=...`), 42 (the Makefile's
# default, `make demo`), and the ids older checkouts' tests and benchmarks hard-coded
# without a lock (51, 54, 60-76, 79), so a suite here never meets one running there.
# 101 is the highest id whose RTPS ports stay below Linux's ephemeral range
# (7400 + 250 * id + participant offsets < 32768).
_UNLOCKED_LEGACY = frozenset({42, 51, 54, 79, *range(60, 77)})
POOL: tuple[int, ...] = tuple(d for d in range(21, 102) if d not in _UNLOCKED_LEGACY)

HELD_ENV = "PMDC_DDS_DOMAIN_HELD"  # set by a lock holder for its children
_held: dict[int, tuple[int, int]] = {}  # domain id -> (fd, nesting count), this process
_guard = threading.Lock()


class DomainBusyError(PmdcError):
    """The DDS domain is held by another process on this machine."""


def lock_dir() -> Path:
    """Where the lock files live (``PMDC_DDS_LOCK_DIR``, default ``/tmp``: machine-wide)."""
    return Path(os.environ.get("PMDC_DDS_LOCK_DIR", "/tmp"))


def _path(domain_id: int) -> Path:
    return lock_dir() / f"pmdc_dds_domain_{domain_id}.lock"


def _holder(domain_id: int) -> str:
    try:
        text = _path(domain_id).read_text().strip()
    except OSError:
        return "another process"
    return text or "another process"


class DomainLock:
    """A held domain: ``domain_id``; release with :meth:`release` or a ``with`` block."""

    def __init__(self, domain_id: int, *, by_parent: bool = False) -> None:
        self.domain_id = int(domain_id)
        self._released = by_parent  # held by the process that started this one

    def fileno(self) -> int | None:
        """The locked descriptor (for children to inherit: the lock then lasts until the
        last of them exits), or None when the lock is held by a parent process."""
        if self._released:
            return None
        with _guard:
            held = _held.get(self.domain_id)
        return held[0] if held else None

    def release(self) -> None:
        if self._released:
            return
        self._released = True
        with _guard:
            fd, count = _held[self.domain_id]
            if count > 1:
                _held[self.domain_id] = (fd, count - 1)
                return
            del _held[self.domain_id]
        os.close(fd)  # closing the descriptor drops the flock

    def __enter__(self) -> DomainLock:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.release()

    def __repr__(self) -> str:
        return f"DomainLock({self.domain_id})"


def _try_lock(domain_id: int, purpose: str) -> DomainLock | None:
    """Lock ``domain_id`` without waiting; None when another process holds it."""
    with _guard:
        if domain_id in _held:
            fd, count = _held[domain_id]
            _held[domain_id] = (fd, count + 1)
            return DomainLock(domain_id)
        path = _path(domain_id)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except PermissionError:  # created by another user: locking needs only a descriptor
            fd = os.open(path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        try:  # say who holds it, for the busy message of the next one
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()} ({purpose})\n".encode(), 0)
        except OSError:
            pass
        _held[domain_id] = (fd, 1)
        return DomainLock(domain_id)


def _purpose(purpose: str | None) -> str:
    return purpose or " ".join(Path(a).name for a in sys.argv[:3])[:80]


def lock_domain(domain_id: int, *, purpose: str | None = None) -> DomainLock:
    """Lock ``domain_id`` for this process; :class:`DomainBusyError` if another holds it."""
    d = int(domain_id)
    if not 0 <= d <= 232:
        raise DomainBusyError(f"ROS_DOMAIN_ID must be in 0..232, got {d}")
    if os.environ.get(HELD_ENV) == str(d) and d not in _held:
        return DomainLock(d, by_parent=True)
    lock = _try_lock(d, _purpose(purpose))
    if lock is None:
        msg = (
            f"ROS_DOMAIN_ID {d} is in use by {_holder(d)} on this machine: "
            "choose another domain id"
        )
        raise DomainBusyError(msg)
    return lock


def allocate_domain(candidates: Iterable[int] = POOL, *, purpose: str | None = None) -> DomainLock:
    """Lock the first free domain of ``candidates`` (tried in a random order).

    A random order spreads concurrent suites over the pool, so an id is rarely
    reused right after its previous holder's processes stopped.
    """
    ids = list(candidates)
    random.shuffle(ids)
    why = _purpose(purpose)
    for d in ids:
        if d in _held:  # this process's own: a second user here needs its own domain
            continue
        lock = _try_lock(d, why)
        if lock is not None:
            return lock
    msg = f"every DDS domain id of {min(ids)}..{max(ids)} is in use on this machine"
    raise DomainBusyError(msg)


def child_env(domain_id: int) -> dict[str, str]:
    """Environment entries telling a child that its parent holds ``domain_id`` for it.

    Empty unless this process holds (or was handed) the lock on ``domain_id``.
    """
    d = int(domain_id)
    if d in _held or os.environ.get(HELD_ENV) == str(d):
        return {HELD_ENV: str(d)}
    return {}
