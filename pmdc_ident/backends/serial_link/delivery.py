"""Samples from the reader thread to ``poll()``, and the one-line report of a lost link.

Host stalls: a caller that polls late gets every sample waiting, up to ``max_catch_up``
of them (a bound on the backlog, set by the backend); past it only the newest are
returned, the first carries :attr:`Fault.LINK` and :attr:`SampleQueue.skipped` counts
the rest (which the driver reports).
"""

from __future__ import annotations

import collections
import threading
from dataclasses import replace

from pmdc_ident.backends.base import BackendError, Telemetry
from pmdc_ident.core.enums import Fault

__all__ = ["SampleQueue"]


class SampleQueue:
    """The hand-over between the thread that decodes and the caller that polls."""

    def __init__(self, max_catch_up: int) -> None:
        self.max_catch_up = max_catch_up
        self.skipped = 0  # left out because the host fell behind
        self._lock = threading.Lock()
        self._samples: collections.deque[Telemetry] = collections.deque()
        self._pending_error: str | None = None

    def put(self, sample: Telemetry) -> None:
        with self._lock:
            self._samples.append(sample)

    def report(self, error: str) -> None:
        """Raise ``error`` from the first :meth:`take` that finds no sample waiting."""
        with self._lock:
            self._pending_error = error

    def take(self) -> list[Telemetry]:
        """Every sample waiting (the newest ``max_catch_up`` of them); raises the
        reported BackendError, once, when none waits."""
        with self._lock:
            out = list(self._samples)
            self._samples.clear()
            if len(out) > self.max_catch_up:
                # The host fell behind past the bound: deliver only the newest.
                skip = len(out) - self.max_catch_up
                out = out[skip:]
                self.skipped += skip
                out[0] = replace(out[0], faults=out[0].faults | Fault.LINK)
            error = self._pending_error
            if error is not None and not out:
                self._pending_error = None
        if error is not None and not out:
            raise BackendError(error)
        return out
