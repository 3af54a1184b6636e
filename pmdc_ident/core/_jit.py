"""Optional numba acceleration for the simulation kernels.

numba is used when importable; otherwise the kernels run as plain Python (same
results, slower). Set ``PMDC_IDENT_NO_JIT=1`` to force plain Python.

Every kernel is compiled once and cached on disk (``cache=True``), so only the
first process pays the compilation. numba alone would invalidate a cached kernel
only when *its own* source file changes, not when a kernel it calls from another
module does (``output_error/kernel.py`` inlines ``model.effects_kernel``): after a
``git pull`` that changes only ``model.py`` the old physics would run on, silently.
So unless ``NUMBA_CACHE_DIR`` is set, the cache lives in a folder named by a hash of
every kernel source (:data:`KERNEL_SOURCES`, and the slot layout the kernels read,
:data:`KERNEL_CONSTANTS`): ``$XDG_CACHE_HOME/pmdc_ident`` (or
``~/.cache/pmdc_ident``), and where that is not writable (a service with no home)
a private directory under the system's temporary directory
(:func:`_private_cache_dir`). If even that is impossible the kernels are compiled
per process, never an import error.

numba itself is imported at the first call of a kernel, not when a module defining
one is imported (``import numba`` is ~0.2 s of CPU): a node that only reads a motor
file, or a command that never simulates, does not pay for it. Until then
:func:`njit` hands out a :class:`_LazyKernel`; the first call of any of them makes
every one a numba dispatcher and puts the dispatchers in place of the lazy kernels
in every loaded module's namespace, so a kernel calling another finds a dispatcher
there when numba compiles or loads it (kernels call each other only through module
globals).
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
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["HAVE_NUMBA", "KERNEL_CONSTANTS", "KERNEL_SOURCES", "njit"]

#: every module with a numba kernel, relative to the package; a test keeps it complete
KERNEL_SOURCES = (
    "core/_jit.py",
    "core/model.py",
    "core/estimators/output_error/kernel.py",
    "core/drift_estimator.py",
    "core/design/information.py",
    "dataio/mcap_scan.py",
    "dataio/csv_scan.py",
    "core/segmentation.py",
    "dataio/outliers.py",
    "benchmark/plant.py",
)
#: modules whose constants the kernels freeze when compiled (the slots they read): part
#: of the fingerprint as well, so a moved slot never runs with an old kernel
KERNEL_CONSTANTS = ("core/effects/layout.py",)
_STALE_AFTER_S = 7 * 24 * 3600.0  # caches of other source versions unused this long go

#: numba is importable (and not switched off): kernels are compiled. numba itself is
#: imported at the first kernel call (:func:`numba_module`).
HAVE_NUMBA = (
    not os.environ.get("PMDC_IDENT_NO_JIT") and importlib.util.find_spec("numba") is not None
)
_numba: Any = None  # the numba module once imported


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


def kernel_fingerprint(root: Path | None = None) -> str:
    """A short hash of every kernel source under ``root`` (the package): a changed
    kernel gets a fresh cache."""
    h = hashlib.sha1()
    root = root or Path(__file__).resolve().parents[1]
    for rel in (*KERNEL_SOURCES, *KERNEL_CONSTANTS):
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


def numba_module() -> Any:
    """numba, imported and configured (cache folder, BLAS probe) on first use; ``None``
    when it is not available."""
    global _numba, HAVE_NUMBA  # noqa: PLW0603 - the module's one-time import state
    if _numba is not None or not HAVE_NUMBA:
        return _numba
    try:
        import numba
    except ImportError:  # pragma: no cover - a broken numba install: plain Python
        HAVE_NUMBA = False
        return None
    _register_cython_blas()
    if not numba.config.CACHE_DIR:
        numba.config.CACHE_DIR = _versioned_cache_dir() or ""
    _numba = numba
    return numba


def _compile(func: Callable[..., Any]) -> Callable[..., Any]:
    numba = numba_module()
    if numba is None:
        return func
    try:
        return numba.njit(cache=True, nogil=True)(func)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return numba.njit(nogil=True)(func)


class _LazyKernel:
    """A kernel before numba is imported: its first call compiles every kernel."""

    def __init__(self, func: Callable[..., Any]) -> None:
        self.func = func
        self.target: Callable[..., Any] | None = None
        self.__name__ = func.__name__
        self.__qualname__ = func.__qualname__
        self.__module__ = func.__module__
        self.__doc__ = func.__doc__
        self.__wrapped__ = func

    def __call__(self, *args: Any) -> Any:
        target = self.target or _materialize(self)
        return target(*args)

    def __getattr__(self, name: str) -> Any:  # py_func, signatures...: the dispatcher's
        if name in ("func", "target") or name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.target or _materialize(self), name)

    def __repr__(self) -> str:
        return f"<lazy kernel {self.__module__}.{self.__qualname__}>"


_pending: list[_LazyKernel] = []
_materializing = threading.Lock()


def _materialize(kernel: _LazyKernel) -> Callable[..., Any]:
    """Compile every pending kernel and replace the lazy kernels in every loaded
    module's namespace by them; ``kernel``'s compiled form."""
    with _materializing:
        if kernel.target is None:
            for k in _pending:
                k.target = _compile(k.func)
            for module in list(sys.modules.values()):
                space = getattr(module, "__dict__", None)
                if not isinstance(space, dict):
                    continue
                for name, value in list(space.items()):
                    if isinstance(value, _LazyKernel) and value.target is not None:
                        space[name] = value.target
            _pending.clear()
    assert kernel.target is not None
    return kernel.target


def njit(func: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit(cache=True, nogil=True)`` when numba is available, else the function;
    before numba is imported, a :class:`_LazyKernel` (see the module docs)."""
    if not HAVE_NUMBA:
        return func
    if _numba is not None:
        return _compile(func)
    with _materializing:
        if _numba is None:
            kernel = _LazyKernel(func)
            _pending.append(kernel)
            return kernel
    return _compile(func)
