"""Every file and folder the package writes goes through here: nothing lost, nothing half-written.

Two rules, one module (docs/data-safety.md):

* **Atomic.** An output is written under a temporary name in its target folder
  (``.NAME.<pid>.<random>.partial[.suffix]``), flushed and ``fsync``-ed, and renamed
  to its final name only when complete; the folder is ``fsync``-ed after the rename.
  An interruption (Ctrl-C, SIGTERM, a full disk, a crash, a kill) therefore leaves
  the previous file untouched, or no file, never a partial one under the final name;
  a left-over temporary (only ``kill -9`` or a power cut leave one) belongs to a dead
  process and is removed by the next write into that folder. A folder (an exported
  bag) is built the same way and renamed once closed, so it is complete when its
  final name appears.
* **Inputs are never written.** While a command runs (:func:`reading_scope`, opened
  by ``pmdc-ident`` for each command), what it reads (its DATA files and bag
  folders, their sidecars, motor files) is registered by the readers with
  :func:`protect`; a write whose target is a registered file (under any spelling or link), inside a
  registered folder, or a registered file's sidecar name, is refused with one line
  (:class:`WriteRefusedError`). The commands also check every output they will write
  before any work starts (``pmdc_ident.commands.outputs``), with the same test
  (:func:`conflict`); this registry is the net under that check.

ROS-free and light (standard library only).
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import shutil
import stat
import threading
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import IO, Any

from pmdc_ident.core.errors import PmdcError

__all__ = [
    "PARTIAL",
    "WriteRefusedError",
    "atomic_folder",
    "atomic_open",
    "atomic_path",
    "clear_protection",
    "conflict",
    "protect",
    "protected",
    "reading_scope",
    "refuse_protected",
    "save_figure",
    "sidecar_of",
    "write_bytes",
    "write_text",
]

PARTIAL = ".partial"  # marks a temporary name: never a final one
_PARTIAL_RE = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[0-9a-f]{8}\.partial(\..*)?$")

_lock = threading.Lock()
_protected: dict[str, str] = {}  # resolved path -> what it is ("the input run.csv")
_scopes = [0]  # open reading scopes (registration happens only inside one)


class WriteRefusedError(PmdcError):
    """An output would replace, or write into, something the command reads."""


def sidecar_of(path: str | Path) -> Path:
    """The sidecar name of a recording: ``RUN.csv`` -> ``RUN.csv.yaml`` (a bag ``DIR`` ->
    ``DIR.yaml``), as :func:`pmdc_ident.dataio.units.sidecar_path` reads it."""
    return Path(str(Path(path)) + ".yaml")


def _key(path: str | Path) -> str:
    try:
        return str(Path(path).resolve())
    except (OSError, RuntimeError):
        return os.path.abspath(str(path))


@contextlib.contextmanager
def reading_scope() -> Iterator[None]:
    """While open, what the readers read is registered (:func:`protect`) and never
    written; the registry is cleared when the outermost scope closes. Outside any
    scope (a library caller, a node) nothing is registered."""
    with _lock:
        _scopes[0] += 1
    try:
        yield
    finally:
        with _lock:
            _scopes[0] -= 1
            if _scopes[0] == 0:
                _protected.clear()


def protect(paths: Iterable[str | Path], what: str = "the input") -> None:
    """Register ``paths`` (files or folders this process reads) as never to be written
    (only inside a :func:`reading_scope`)."""
    with _lock:
        if not _scopes[0]:
            return
        for p in paths:
            _protected.setdefault(_key(p), f"{what} {p}")


def clear_protection() -> None:
    """Forget every registered input (a batch worker between two inputs; tests)."""
    with _lock:
        _protected.clear()


def protected() -> dict[str, str]:
    """The registered inputs: resolved path -> description."""
    with _lock:
        return dict(_protected)


def _inside(path: str, folder: str) -> bool:
    return path != folder and path.startswith(folder.rstrip(os.sep) + os.sep)


def _same_file(a: str | Path, b: str | Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def conflict(target: str | Path, reads: Iterable[tuple[str | Path, str]]) -> str | None:
    """Why writing ``target`` would destroy one of ``reads`` ((path, description) pairs),
    or None when it would not.

    It would when ``target`` is one of them (any spelling, symlink or hard link), lies
    inside one that is a folder (a bag), or is the sidecar name of one (the next run
    would read it as that recording's units and columns).
    """
    t = _key(target)
    for path, what in reads:
        r = _key(path)
        if t == r or _same_file(target, path):
            return f"that is {what}"
        if _inside(t, r) and Path(r).is_dir():
            return f"that is inside {what.replace('the input ', 'the input folder ', 1)}"
        if t == _key(sidecar_of(path)) and not str(path).endswith(".yaml"):
            return f"that is the sidecar name of {what} (its units, read on every run)"
    return None


RECORDING_SUFFIXES = (".csv", ".txt", ".mcap")


def sidecar_owner(target: str | Path) -> Path | None:
    """The recording beside ``target`` whose sidecar name ``target`` is (``run.csv`` for
    ``run.csv.yaml``, a bag folder ``DIR`` for ``DIR.yaml``), or None."""
    t = str(target)
    if not t.lower().endswith(".yaml"):
        return None
    owner = Path(t[: -len(".yaml")])
    try:
        if owner.is_dir() and (owner / "metadata.yaml").is_file():
            return owner
        if owner.is_file() and owner.suffix.lower() in RECORDING_SUFFIXES:
            return owner
    except OSError:
        return None
    return None


def refuse_link(link: Path, target: Path, option: str = "") -> None:
    """A link is written through only to a file of its own kind: ``out.yaml`` linked to a
    recording ``run.csv`` would replace the recording with a motor file."""
    regular = target.is_file() or target.is_dir()  # a device or a pipe is written through
    if regular and target.suffix.lower() != link.suffix.lower():
        who = f"{option} " if option else ""
        msg = (
            f"{who}{link}: a link to {target}, which is no {link.suffix or 'such'} file; "
            "refusing to write through it (give the file's own name)"
        )
        raise WriteRefusedError(msg)


def refuse_protected(target: str | Path, option: str = "") -> None:
    """:class:`WriteRefusedError` when ``target`` conflicts with a registered input, or is
    the sidecar name of a recording beside it (whether this command reads it or not:
    the next command on that recording would read the file as its units)."""
    owner = sidecar_owner(target)
    if owner is not None:
        who = f"{option} " if option else ""
        msg = (
            f"{who}{target}: that is the sidecar name of the recording {owner} (its units "
            "and columns, read on every run); refusing to write there (choose another name)"
        )
        raise WriteRefusedError(msg)
    reads = [(k, v) for k, v in protected().items()]
    why = conflict(target, reads)
    if why is not None:
        who = f"{option} " if option else ""
        msg = f"{who}{target}: {why}; refusing to write over an input (choose another name)"
        raise WriteRefusedError(msg)


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def _sweep(folder: Path, name: str) -> None:
    """Remove the temporaries of ``name`` that dead processes left in ``folder``."""
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return
    for e in entries:
        m = _PARTIAL_RE.match(e.name)
        if m is None or m.group("name") != name or _pid_alive(int(m.group("pid"))):
            continue
        with contextlib.suppress(OSError):
            if e.is_dir(follow_symlinks=False):
                shutil.rmtree(e.path)
            else:
                os.unlink(e.path)


def _temp_name(final: Path, keep_suffix: bool) -> Path:
    suffix = final.suffix if keep_suffix else ""
    token = secrets.token_hex(4)
    return final.with_name(f".{final.name}.{os.getpid()}.{token}{PARTIAL}{suffix}")


def _umask_mode() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def _prepare(path: str | Path, option: str) -> tuple[Path, bool]:
    """The file to replace (a symlink's target: the link stays) and whether it is a
    special file (a device, a pipe: written through, there is nothing to replace)."""
    final = Path(path)
    refuse_protected(final, option)
    if final.is_symlink():
        target = final.resolve()
        refuse_link(final, target, option)
        final = target
        refuse_protected(final, option)
    if final.is_dir():
        msg = f"{option + ' ' if option else ''}{final}: is a folder; give a file name"
        raise WriteRefusedError(msg)
    special = final.exists() and not final.is_file()
    if not special:
        _sweep(final.parent, final.name)
    return final, special


def _commit_file(tmp: Path, final: Path) -> None:
    """``tmp`` (complete, closed) under the final name, with the mode ``final`` had."""
    try:
        mode = stat.S_IMODE(final.stat().st_mode)
    except OSError:
        mode = _umask_mode()
    os.chmod(tmp, mode)
    os.replace(tmp, final)
    _fsync_dir(final.parent)


@contextlib.contextmanager
def atomic_open(
    path: str | Path,
    mode: str = "w",
    *,
    encoding: str | None = "utf-8",
    newline: str | None = None,
    option: str = "",
) -> Iterator[IO[Any]]:
    """An open file whose content appears under ``path`` only when the block ends
    without an exception (then flushed, ``fsync``-ed and renamed); else nothing changes."""
    if mode not in ("w", "wb"):
        msg = f"atomic_open: mode {mode!r} (only 'w' and 'wb')"
        raise ValueError(msg)
    final, special = _prepare(path, option)
    if special:  # /dev/null, a named pipe: written through
        with open(final, mode, encoding=encoding, newline=newline) as direct:
            yield direct
        return
    tmp = _temp_name(final, keep_suffix=False)
    binary = mode == "wb"
    fh: IO[Any]
    if binary:
        fh = open(tmp, "xb")  # noqa: SIM115 - closed below on every path
    else:
        fh = open(tmp, "x", encoding=encoding, newline=newline)  # noqa: SIM115
    try:
        yield fh
        fh.flush()
        os.fsync(fh.fileno())
        fh.close()
        _commit_file(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError, ValueError):
            fh.close()
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


@contextlib.contextmanager
def atomic_path(path: str | Path, *, option: str = "") -> Iterator[Path]:
    """A temporary file name (same folder, same suffix) for a library that writes by
    name (matplotlib's ``savefig``, ``numpy.savetxt``); renamed to ``path`` when the block
    ends without an exception, removed otherwise."""
    final, special = _prepare(path, option)
    if special:
        yield final
        return
    tmp = _temp_name(final, keep_suffix=True)
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        _commit_file(tmp, final)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_text(path: str | Path, text: str, *, option: str = "") -> Path:
    """``text`` (UTF-8) into ``path``, atomically (see :func:`atomic_open`)."""
    with atomic_open(path, "w", option=option) as fh:
        fh.write(text)
    return Path(path)


def write_bytes(path: str | Path, data: bytes, *, option: str = "") -> Path:
    """``data`` into ``path``, atomically."""
    with atomic_open(path, "wb", encoding=None, option=option) as fh:
        fh.write(data)
    return Path(path)


def _fsync_tree(folder: Path) -> None:
    for root, _dirs, files in os.walk(folder):
        for name in files:
            fd = os.open(os.path.join(root, name), os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
        _fsync_dir(Path(root))


@contextlib.contextmanager
def atomic_folder(path: str | Path, *, option: str = "") -> Iterator[Path]:
    """A new folder built under a temporary parent and moved to ``path`` once the block
    ends without an exception (its files ``fsync``-ed first).

    Yields ``<temporary folder>/<final name>``, which does not exist yet (the writer
    creates it; a rosbag2 writer names its ``.mcap`` after it, so the bag keeps its
    final names). ``path`` must not exist: a folder is never replaced. On any
    exception the temporary folder and what it holds are removed.
    """
    final = Path(path)
    refuse_protected(final, option)
    if final.exists():
        msg = f"{option + ' ' if option else ''}{final}: exists already and is never overwritten"
        raise WriteRefusedError(msg)
    _sweep(final.parent, final.name)
    holder = _temp_name(final, keep_suffix=False)
    os.mkdir(holder)
    try:
        inner = holder / final.name
        yield inner
        _fsync_tree(inner)
        if final.exists():  # appeared meanwhile: never replaced
            msg = f"{final}: appeared while it was written; the new one is not moved over it"
            raise WriteRefusedError(msg)
        os.rename(inner, final)
        _fsync_dir(final.parent)
    finally:
        with contextlib.suppress(OSError):
            shutil.rmtree(holder)


def save_figure(fig: Any, path: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig`` (matplotlib) into ``path``, atomically (the format from its suffix)."""
    final = Path(path)
    fmt = kwargs.pop("format", None) or final.suffix.lstrip(".") or None
    with atomic_path(final) as tmp:
        fig.savefig(tmp, format=fmt, **kwargs)
    return final
