"""Optional numba acceleration for the simulation kernels.

numba is used when importable; otherwise the kernels run as plain Python (same
results, slower). Set ``PMDC_IDENT_NO_JIT=1`` to force plain Python.

Every kernel is compiled once and cached on disk (``cache=True``), so only the
first process pays the compilation. numba alone would invalidate a cached kernel
only when *its own* source file changes, not when a kernel it calls from another
module does (``output_error/kernel.py`` inlines ``model.effects_kernel``): after a
``git pull`` that changes only ``model.py`` the old physics would run on, silently.
So unless ``NUMBA_CACHE_DIR`` is set, the cache lives in a folder named by a hash of
every kernel source (:data:`KERNEL_SOURCES`): ``$XDG_CACHE_HOME/pmdc_ident`` (or
``~/.cache/pmdc_ident``), and where that is not writable (a service with no home)
a private directory under the system's temporary directory
(:func:`_private_cache_dir`). If even that is impossible the kernels are compiled
per process, never an import error.
"""

from __future__ import annotations

import hashlib
import importlib.machinery
import importlib.util
import os
import shutil
import stat
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["HAVE_NUMBA", "KERNEL_SOURCES", "njit"]

#: every module with a numba kernel, relative to the package; a test keeps it complete
KERNEL_SOURCES = (
    "core/_jit.py",
    "core/model.py",
    "core/estimators/output_error/kernel.py",
    "core/drift_estimator.py",
    "dataio/mcap_scan.py",
    "benchmark/plant.py",
)
_STALE_AFTER_S = 7 * 24 * 3600.0  # caches of other source versions unused this long go

try:
    if os.environ.get("PMDC_IDENT_NO_JIT"):
        raise ImportError
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    _numba = None
    HAVE_NUMBA = False


def _register_cython_blas() -> None:
    """Load ``scipy.linalg.cython_blas`` without the rest of ``scipy.linalg``.

    numba's first compilation or cache load imports ``numba.np.arraymath``, which tests
    for BLAS with ``import scipy.linalg.cython_blas``: that runs ``scipy.linalg``'s
    ``__init__`` (~0.14 s of CPU in every process; our kernels call no BLAS). The
    extension module alone loads in ~2 ms and is all numba uses of it (its function
    pointers). Registered under its own name, a later ``import scipy.linalg`` runs as
    usual and picks it up. Anything unexpected: nothing is registered, numba imports
    it its own way.
    """
    name = "scipy.linalg.cython_blas"
    scipy = sys.modules.get("scipy")  # numba imports scipy to check its version
    if scipy is None or "scipy.linalg" in sys.modules or name in sys.modules:
        return
    try:
        paths = [os.path.join(p, "linalg") for p in scipy.__path__]
        spec = importlib.machinery.PathFinder.find_spec(name, paths)
        if spec is None or spec.loader is None:
            return
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
    except Exception:  # noqa: BLE001 - any failure: numba imports it itself
        sys.modules.pop(name, None)


if _numba is not None:
    _register_cython_blas()


def kernel_fingerprint(root: Path | None = None) -> str:
    """A short hash of every kernel source under ``root`` (the package): a changed
    kernel gets a fresh cache."""
    h = hashlib.sha1()
    root = root or Path(__file__).resolve().parents[1]
    for rel in KERNEL_SOURCES:
        try:
            h.update((root / rel).read_bytes())
        except OSError:
            h.update(rel.encode())
    return h.hexdigest()[:12]


def _private_cache_dir() -> str | None:
    """A cache directory only this user can write, under the temporary directory.

    ``None`` when it cannot be created or is not safely ours (another user could
    otherwise plant compiled code in it).
    """
    path = Path(tempfile.gettempdir()) / f"pmdc_ident-numba-{os.getuid()}"
    try:
        path.mkdir(mode=0o700, exist_ok=True)
        st = path.lstat()
    except OSError:
        return None
    mine = stat.S_ISDIR(st.st_mode) and st.st_uid == os.getuid()
    if not mine or st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
        return None
    return str(path)


def _user_cache_dir() -> str | None:
    """``$XDG_CACHE_HOME/pmdc_ident`` or ``~/.cache/pmdc_ident`` when writable."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    path = Path(base) / "pmdc_ident"
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return str(path) if os.access(path, os.W_OK | os.X_OK) else None


def _versioned_cache_dir() -> str | None:
    """``<user or private cache>/numba-<fingerprint>``, created; older versions'
    folders unused for a week are removed. ``None`` when nothing is writable."""
    for base in (_user_cache_dir(), _private_cache_dir()):
        if base is None:
            continue
        path = Path(base) / f"numba-{kernel_fingerprint()}"
        try:
            path.mkdir(mode=0o700, exist_ok=True)
        except OSError:
            continue
        _prune(Path(base), keep=path)
        return str(path)
    return None


def _prune(base: Path, keep: Path) -> None:
    now = time.time()
    for old in base.glob("numba-*"):
        try:
            if old != keep and now - old.stat().st_mtime > _STALE_AFTER_S:
                shutil.rmtree(old, ignore_errors=True)
        except OSError:
            pass


if _numba is not None and not _numba.config.CACHE_DIR:
    _numba.config.CACHE_DIR = _versioned_cache_dir() or ""


def njit(func: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit(cache=True, nogil=True)`` when numba is available, else the function."""
    if _numba is None:
        return func
    try:
        return _numba.njit(cache=True, nogil=True)(func)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return _numba.njit(nogil=True)(func)
