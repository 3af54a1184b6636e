"""Joining the driver's three topics (voltage, current, encoder) on their stamps: the one policy.

The driver stamps the three messages of one sample with the same driver time; they
arrive on separate topics, in any order, and a topic may run at a lower rate or
lose a message. Every consumer joins them by the same rules:

1. **The stamp is the key.** Values are paired by their driver stamp, never by
   arrival order or host time.
2. **A hole stays a hole.** Topics at one rate are joined on the stamps they share;
   a stamp missing on one of them is not made up: the sample is left out and counted
   (:attr:`Joined.missing` offline, :attr:`StampJoiner.dropped` on line), and the fit
   steps over it as a gap.
3. **A topic at a lower rate is never allowed to thin the others out silently.** A
   measured topic (``current``, ``encoder``) at a lower rate sets the grid: the run is
   joined on its stamps, the other measured topic taken at them (interpolated where
   it has no sample there) and the applied voltage *averaged* over each interval of
   the grid (its volt-seconds kept, so the model's zero-order hold sees the voltage
   the motor got; taking one held value per interval instead shifts every edge by up
   to a sample: R +4 %, J -4 %, outside their intervals, on a seed-000 session with
   every other current sample). ``voltage_applied`` alone at a lower rate is *held*
   between its samples (the command changes only when it is published). Either way
   a note names the rates and what was done.
4. **On line, a sample waits a bounded time.** A consumer that must answer as the
   samples arrive hands complete samples out in stamp order, never past an older one
   still being completed; one still incomplete ``hold_s`` behind the newest stamp is a
   hole (rule 2) - :class:`StampJoiner`, the monitor's join. The session controller
   steps the session on *every* encoder sample (the session's clock: a plan sample
   per driver sample, none may be skipped), so there the current is the one value
   of a slower topic (rule 3's hold): the newest at or before the encoder's stamp,
   waited for a bounded time (:class:`HeldStream`).

:func:`join_driver_samples` is the offline form (a bag, and the identification node's
run of a finished session: :func:`pmdc_ident.dataio.bagio.assemble_run`);
:class:`StampJoiner` (the monitor node) and :class:`HeldStream` (the session
controller) are the on-line forms. One difference remains, said here so it is not
mistaken for a second policy: the monitor's :class:`StampJoiner` does not apply rule 3
- a topic at a lower rate thins its samples to that topic's stamps, every sample left
out counted in :attr:`StampJoiner.dropped` (the node's ``samples_dropped``
diagnostic), so never silently.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.errors import DataError
from pmdc_ident.core.samples import DriverSamples

__all__ = ["HeldStream", "Joined", "StampJoiner", "held_at", "join_driver_samples"]

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]


@dataclass(frozen=True)
class Joined:
    """Driver samples on one stamp grid (rules 2 and 3): the grid (ns), the columns
    (``position``, ``speed``, ``voltage``, ``terminal``, ``current``; None where the
    data has none), what was done in words, and how many samples are holes."""

    stamps: IntArray
    columns: dict[str, FloatArray | None]
    notes: tuple[str, ...]
    missing: int


def held_at(ns: IntArray, values: FloatArray, stamps: IntArray) -> FloatArray:
    """The newest of ``values`` (stamped ``ns``, sorted) at or before each of ``stamps``
    (the first value before the first stamp): a held topic's value on a grid."""
    return values[np.clip(np.searchsorted(ns, stamps, side="right") - 1, 0, ns.size - 1)]


def _period(ns: IntArray) -> int:
    return int(np.median(np.diff(ns))) if ns.size > 2 else 0


def join_driver_samples(arrays: DriverSamples, source: str = "") -> Joined:
    """The driver topics of ``arrays`` joined on their stamps by the module's rules."""
    enc_ns = np.asarray(arrays.encoder_ns, dtype=np.int64)
    v_ns = np.asarray(arrays.voltage_ns, dtype=np.int64)
    c_ns = np.asarray(arrays.current_ns, dtype=np.int64)
    topics = {"encoder": enc_ns, "voltage_applied": v_ns}
    if c_ns.size:
        topics["current"] = c_ns
    periods = {k: _period(v) for k, v in topics.items()}
    fast = min((p for p in periods.values() if p > 0), default=0)
    slow = {k for k, p in periods.items() if fast and p > 1.5 * fast}
    if len(slow) == len(topics):
        slow = set()
    measured_slow = sorted(slow - {"voltage_applied"})
    notes: list[str] = []
    if measured_slow:
        grid_topics = measured_slow
    else:
        grid_topics = [k for k in topics if k not in slow]
    stamps = topics[grid_topics[0]]
    union = stamps
    for k in grid_topics[1:]:
        stamps = np.intersect1d(stamps, topics[k])
        union = np.union1d(union, topics[k])
    stamps = np.unique(stamps)
    # a hole is a stamp inside every grid topic's span that one of them lacks (where a
    # truncated file ends the topics one sample apart, nothing is missing)
    first = max(int(topics[k].min()) for k in grid_topics)
    last = min(int(topics[k].max()) for k in grid_topics)
    union = union[(union >= first) & (union <= last)]
    missing = int(union.size - np.count_nonzero((stamps >= first) & (stamps <= last)))
    if missing:
        per = {k: int(np.setdiff1d(union, topics[k]).size) for k in grid_topics}
        which = ", ".join(f"{k} {n}" for k, n in per.items() if n)
        notes.append(
            f"{missing} driver sample(s) are missing on some topic ({which}): those stamps "
            "are holes the fit steps over (gaps)"
        )
    others = [k for k in topics if k not in grid_topics]
    for k in others:  # the grid within every other topic's span
        ns = topics[k]
        if ns.size:
            stamps = stamps[(stamps >= ns.min()) & (stamps <= ns.max())]
    if stamps.size < 2:
        msg = f"{source or 'data'}: fewer than 2 driver samples with matching stamps"
        raise DataError(msg)
    if measured_slow:
        rate = 1e9 / periods[measured_slow[0]]
        what = ", ".join(repr(k) for k in measured_slow)
        fast_ones = ", ".join(repr(k) for k in topics if k not in slow)
        notes.append(
            f"{what} arrives every {periods[measured_slow[0]] * 1e-6:.4g} ms, "
            f"{periods[measured_slow[0]] / fast:.3g} x the period of {fast_ones} "
            f"({fast * 1e-6:.4g} ms): joined on its stamps ({rate:.4g} Hz), the voltage "
            "averaged over each of its intervals (volt-seconds kept), the other topics "
            "taken at its stamps; their samples in between are not fitted"
        )
    elif "voltage_applied" in slow:
        notes.append(
            f"'voltage_applied' arrives every {periods['voltage_applied'] * 1e-6:.4g} ms, "
            f"{periods['voltage_applied'] / fast:.3g} x the period of the measured topics "
            f"({fast * 1e-6:.4g} ms): each applied voltage is held until the next one"
        )

    voltage = "mean" if measured_slow else "held"
    cols: dict[str, FloatArray | None] = {
        "position": _on_grid(enc_ns, arrays.position_rad, stamps, "linear"),
        "speed": _on_grid(enc_ns, arrays.speed_rad_s, stamps, "linear"),
        "voltage": _on_grid(v_ns, arrays.voltage_v, stamps, voltage),
        "terminal": _on_grid(v_ns, arrays.terminal_v, stamps, voltage),
        "current": _on_grid(c_ns, arrays.current_a, stamps, "linear") if c_ns.size else None,
    }
    return Joined(stamps, cols, tuple(notes), missing)


def _on_grid(
    ns: IntArray, values: FloatArray | None, stamps: IntArray, how: str
) -> FloatArray | None:
    """``values`` (stamped ``ns``) on the grid ``stamps``: exact where every stamp has a
    sample, else ``linear`` (interpolated), ``held`` (:func:`held_at`) or ``mean``
    (averaged over each grid interval)."""
    if values is None or not ns.size:
        return None
    values = np.asarray(values, dtype=float)
    if values.size != ns.size:
        return None
    order = np.argsort(ns, kind="stable")
    ns, values = ns[order], values[order]
    if how == "mean":
        return _interval_mean(ns, values, stamps)
    idx = np.searchsorted(ns, stamps)
    exact = (idx < ns.size) & (ns[np.minimum(idx, ns.size - 1)] == stamps)
    if exact.all():
        return values[idx]
    if how == "held":
        return held_at(ns, values, stamps)
    return np.interp(stamps.astype(float), ns.astype(float), values)


def _interval_mean(ns: IntArray, values: FloatArray, grid: IntArray) -> FloatArray:
    """The mean of the held ``values`` whose stamps fall in each interval of ``grid``
    (the last interval as long as the one before it). An interval entirely open (NaN)
    stays open; one that opens or closes inside takes its last value's state."""
    edges = np.append(grid, grid[-1] + (grid[-1] - grid[-2]))
    lo = np.searchsorted(ns, edges[:-1], side="left")
    hi = np.searchsorted(ns, edges[1:], side="left")
    finite = np.isfinite(values)
    filled = np.where(finite, values, 0.0)
    csum = np.concatenate(([0.0], np.cumsum(filled)))
    ccount = np.concatenate(([0], np.cumsum(finite)))
    n = hi - lo
    nf = ccount[hi] - ccount[lo]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (csum[hi] - csum[lo]) / nf
    last = values[np.clip(hi - 1, 0, values.size - 1)]
    out = np.where(nf == n, mean, last)  # partly open: the state it ends in
    return np.where(n > 0, out, last)


_VOLTAGE, _CURRENT, _SPEED = 0, 1, 2
_KINDS = {"voltage": _VOLTAGE, "current": _CURRENT, "speed": _SPEED}


class StampJoiner:
    """Complete samples (t s, voltage V, current A, speed rad/s) from three streams, on
    line (rules 1, 2 and 4): a sample is handed out once all three values of its stamp
    are there, in stamp order, never past an older sample still being completed; one
    still incomplete ``hold_s`` behind the newest stamp (or beyond ``max_pending``
    partial samples) is a hole, dropped and counted in :attr:`dropped`, so a lost
    message never stalls the stream."""

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


_D = TypeVar("_D", float, None)


class HeldStream:
    """One topic's recent samples on line, read as held values (rule 4): the newest at
    or before a stamp. Samples are added in stamp order; those older than the newest
    one at or before the last stamp read are let go."""

    def __init__(self, maxlen: int = 8192) -> None:
        self._samples: deque[tuple[int, float]] = deque(maxlen=maxlen)

    def add(self, stamp_ns: int, value: float) -> None:
        self._samples.append((stamp_ns, value))

    def waiting_for(self, stamp_ns: int) -> bool:
        """Samples have come, but none yet at or after ``stamp_ns`` (one may be on its way)."""
        return bool(self._samples) and self._samples[-1][0] < stamp_ns

    def at(self, stamp_ns: int, default: _D) -> float | _D:
        """The newest value at or before ``stamp_ns`` (``default`` when none is)."""
        s = self._samples
        while len(s) > 1 and s[1][0] <= stamp_ns:
            s.popleft()
        return s[0][1] if s and s[0][0] <= stamp_ns else default
