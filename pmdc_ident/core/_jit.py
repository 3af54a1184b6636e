"""Optional numba acceleration for the simulation kernels.

numba is used when importable; otherwise the kernels run as plain Python (same
results, slower). Set ``PMDC_IDENT_NO_JIT=1`` to force plain Python.

Every kernel is compiled once and cached on disk (``cache=True``), so only the
first process on a machine pays the compilation. numba looks for a writable
place in this order: ``NUMBA_CACHE_DIR``, the ``__pycache__`` beside the source,
the user's cache directory (``~/.cache/numba``). An installed package is often
read-only and a service may have no writable home: then the kernels are cached
in a private directory under the system's temporary directory instead (see
:func:`_private_cache_dir`), and if even that is impossible they are compiled
per process, never an import error.
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

__all__ = ["HAVE_NUMBA", "njit"]

try:
    if os.environ.get("PMDC_IDENT_NO_JIT"):
        raise ImportError
    import numba as _numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    _numba = None
    HAVE_NUMBA = False


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


def njit(func: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit(cache=True, nogil=True)`` when numba is available, else the function."""
    if _numba is None:
        return func
    try:
        return _numba.njit(cache=True, nogil=True)(func)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        pass
    if not _numba.config.CACHE_DIR and (private := _private_cache_dir()) is not None:
        _numba.config.CACHE_DIR = private  # numba reads it for every later kernel too
        try:
            return _numba.njit(cache=True, nogil=True)(func)
        except RuntimeError:
            pass
    return _numba.njit(nogil=True)(func)
