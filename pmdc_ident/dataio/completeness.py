"""How complete a session's driver samples are: expected on the stamp grid vs present.

The driver stamps every sample on an exact grid (``start + k * dt``), so a missing
sample is a hole in that grid. :func:`topic_completeness` counts, for one topic,
the samples a session should hold (``start <= stamp < end``, half a period of
tolerance, as :func:`pmdc_ident.dataio.bagio.assemble_run` cuts segments), those
present, and where the holes are (seconds from the session start). A hole on all
three topics at the same stamps was usually never published (the driver skipped a
host stall, or a board's link lost them, and the driver's log says so); a hole on
one topic was lost on the way. Either way the bag's metadata, ``parameters.json``
and the node's result say so: nothing goes missing silently.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["Completeness", "TopicCompleteness", "completeness", "topic_completeness"]

MAX_GAPS = 20  # holes listed per topic (the count covers all of them)


@dataclass(frozen=True)
class TopicCompleteness:
    """One topic: samples expected on the grid, present, missing, and the first holes."""

    topic: str
    expected: int
    present: int
    gaps: tuple[tuple[float, int], ...]  # (seconds from the session start, samples missing)

    @property
    def missing(self) -> int:
        return self.expected - self.present

    def to_dict(self) -> dict[str, Any]:
        return {
            "expected": self.expected,
            "present": self.present,
            "missing": self.missing,
            "gaps_s_n": [[round(t, 6), n] for t, n in self.gaps],
        }


@dataclass(frozen=True)
class Completeness:
    """Every driver topic of one session."""

    topics: tuple[TopicCompleteness, ...]

    @property
    def missing(self) -> int:
        return max((t.missing for t in self.topics), default=0)

    def to_dict(self) -> dict[str, Any]:
        return {
            "missing_max": self.missing,
            "topics": {t.topic: t.to_dict() for t in self.topics},
        }

    def line(self) -> str:
        """One line: 'every driver sample present' or what is missing where."""
        if not self.missing:
            n = max((t.expected for t in self.topics), default=0)
            return f"all {n} driver samples of the session present on every topic"
        parts = []
        for t in self.topics:
            if t.missing:
                where = ", ".join(f"{n} at {s:.3f} s" for s, n in t.gaps[:3])
                more = ", ..." if len(t.gaps) > 3 else ""
                parts.append(f"{t.topic} {t.missing} of {t.expected} ({where}{more})")
        return "driver samples missing: " + "; ".join(parts)


def topic_completeness(
    topic: str, stamps_ns: Iterable[int], start_ns: int, end_ns: int, dt_ns: int
) -> TopicCompleteness:
    """Grid samples of ``[start, end)`` expected vs present in ``stamps_ns`` (any order)."""
    dt = max(int(dt_ns), 1)
    half = dt // 2
    s = np.asarray(stamps_ns if isinstance(stamps_ns, np.ndarray) else list(stamps_ns))
    s = s.astype(np.int64, copy=False)
    s = s[(s >= start_ns - half) & (s < end_ns - half)]
    expected = max(0, int(round((end_ns - start_ns) / dt)))
    # grid index of each present sample; holes are jumps of more than one index
    k = np.round((s - start_ns) / dt).astype(np.int64)
    k = np.unique(k[(k >= 0) & (k < expected)])
    edges = np.concatenate(([-1], k, [expected]))
    jumps = np.diff(edges) - 1
    holes = np.nonzero(jumps > 0)[0]
    gaps = tuple((float((edges[h] + 1) * dt * 1e-9), int(jumps[h])) for h in holes[:MAX_GAPS])
    return TopicCompleteness(topic, expected, int(k.size), gaps)


def completeness(
    stamps_by_topic: Mapping[str, Iterable[int]], start_ns: int, end_ns: int, dt_ns: int
) -> Completeness:
    """:func:`topic_completeness` of every topic."""
    return Completeness(
        tuple(
            topic_completeness(t, ns, start_ns, end_ns, dt_ns) for t, ns in stamps_by_topic.items()
        )
    )
