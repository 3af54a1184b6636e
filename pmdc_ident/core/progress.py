"""Progress messages: the one callback type the long computations report through.

``identify``, ``diagnose`` and the benchmark take ``progress: ProgressCallback | None``
and call it with one human-readable line per step (the CLI prints them on stderr
unless ``--quiet``). A running session's state is a different thing:
:class:`pmdc_ident.node_logic.session.SessionProgress`.
"""

from __future__ import annotations

from collections.abc import Callable

__all__ = ["ProgressCallback", "silent"]

ProgressCallback = Callable[[str], None]


def silent(_message: str) -> None:
    """A :data:`ProgressCallback` that says nothing."""
