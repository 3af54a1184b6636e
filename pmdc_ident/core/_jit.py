"""Optional numba acceleration for the simulation kernels.

numba is used when importable; otherwise the kernels run as plain Python (same
results, slower). Set ``PMDC_IDENT_NO_JIT=1`` to force plain Python.
"""

from __future__ import annotations

import os
from collections.abc import Callable
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


def njit(func: Callable[..., Any]) -> Callable[..., Any]:
    """``numba.njit(cache=True)`` when numba is available, else the function itself."""
    if _numba is None:
        return func
    return _numba.njit(cache=True, nogil=True)(func)
