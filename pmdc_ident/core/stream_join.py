"""Join the driver's three sample streams (voltage, current, encoder) by their stamps.

The driver stamps the three messages of one sample with the same time, but they
arrive on separate topics, in any order. :class:`StampJoiner` keeps partial
samples until all three are there and hands complete ones out in time order,
never past an older sample still being completed. A sample still incomplete
``hold_s`` behind the newest stamp seen (or beyond ``max_pending`` partial
samples) is dropped and counted in :attr:`StampJoiner.dropped`, so a lost
message never stalls the stream.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

__all__ = ["StampJoiner"]

_VOLTAGE, _CURRENT, _SPEED = 0, 1, 2
_KINDS = {"voltage": _VOLTAGE, "current": _CURRENT, "speed": _SPEED}


class StampJoiner:
    """Complete samples (t s, voltage V, current A, speed rad/s) from three streams."""

    def __init__(self, max_pending: int = 2000, hold_s: float = 0.1) -> None:
        self.max_pending = int(max_pending)
        self.hold_ns = int(hold_s * 1e9)
        self._newest_ns = -1
        self._pending: dict[int, list[float]] = {}
        self._ready: list[tuple[int, float, float, float]] = []
        self._last_out_ns = -1
        self.dropped = 0

    def add(self, kind: str, stamp_ns: int, value: float) -> None:
        """One value of one stream (``voltage``, ``current`` or ``speed``)."""
        if stamp_ns <= self._last_out_ns:
            self.dropped += 1  # older than what was already handed out
            return
        self._newest_ns = max(self._newest_ns, stamp_ns)
        slot = self._pending.get(stamp_ns)
        if slot is None:
            slot = self._pending[stamp_ns] = [math.inf, math.inf, math.inf]
        slot[_KINDS[kind]] = value
        if all(x != math.inf for x in slot):
            del self._pending[stamp_ns]
            self._ready.append((stamp_ns, slot[0], slot[1], slot[2]))

    def take(self) -> tuple[NDArray[np.float64], ...]:
        """Complete samples in time order since the last call: (t_s, v, i, w) arrays."""
        cutoff = self._newest_ns - self.hold_ns
        lost = [ns for ns in self._pending if ns <= cutoff]
        if len(self._pending) - len(lost) > self.max_pending:
            lost = sorted(self._pending)[: len(self._pending) - self.max_pending]
        for ns in lost:
            del self._pending[ns]
        self.dropped += len(lost)
        oldest = min(self._pending) if self._pending else None
        ready = sorted(self._ready)
        if oldest is not None:
            keep = [r for r in ready if r[0] > oldest]
            ready = [r for r in ready if r[0] < oldest]
            self._ready = keep
        else:
            self._ready = []
        if ready:
            self._last_out_ns = ready[-1][0]
        arr = np.array(ready, dtype=float).reshape(-1, 4)
        t0 = arr[:, 0] * 1e-9
        return t0, arr[:, 1], arr[:, 2], arr[:, 3]
