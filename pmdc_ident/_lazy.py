"""Lazy package exports (PEP 562): a name is imported from its submodule on first use.

A package ``__init__`` that re-exports names from heavy submodules (numpy, scipy,
numba) would make importing any light submodule of it heavy too: the command
line imports ``pmdc_ident.core.errors`` to build its help, and must answer in a
fraction of a second. Such a package declares where each name lives instead::

    __getattr__, __dir__ = lazy_exports(__name__, {"Model": "model", ...})
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Mapping
from typing import Any

__all__ = ["lazy_exports"]


def lazy_exports(
    package: str, sources: Mapping[str, str]
) -> tuple[Callable[[str], Any], Callable[[], list[str]]]:
    """Module ``__getattr__`` and ``__dir__`` for ``package``: name -> submodule defining it."""

    def module_getattr(name: str) -> Any:
        module = sources.get(name)
        if module is None:
            msg = f"module {package!r} has no attribute {name!r}"
            raise AttributeError(msg)
        value = getattr(importlib.import_module(f"{package}.{module}"), name)
        setattr(sys.modules[package], name, value)  # later look-ups skip this function
        return value

    def module_dir() -> list[str]:
        return sorted(set(vars(sys.modules[package])) | set(sources))

    return module_getattr, module_dir
