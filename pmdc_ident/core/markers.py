"""Segment markers: the ``segment`` topic's JSON format.

The identification session publishes one :class:`Marker` per segment boundary on the
driver's clock; the recorder stores them in the bag and
:func:`pmdc_ident.dataio.bagio.assemble_run` cuts the recorded samples into segments
with them.
"""

from __future__ import annotations

import enum
import json
from dataclasses import asdict, dataclass

from pmdc_ident.core.errors import PmdcError

__all__ = ["Marker", "MarkerEvent"]


class MarkerEvent(enum.Enum):
    SESSION_START = "session_start"
    START = "start"  # a segment starts
    END = "end"  # a segment ends (exclusive: the first sample after it)
    SESSION_END = "session_end"
    ABORT = "abort"


@dataclass(frozen=True)
class Marker:
    """A segment boundary on the driver's clock (published on the ``segment`` topic).

    ``t_s`` is the driver time of the first sample the event applies to; a
    segment holds the samples with ``start.t_s <= t < end.t_s``.
    """

    event: MarkerEvent
    label: str
    t_s: float
    session: str = ""
    detail: str = ""

    def to_json(self) -> str:
        d = asdict(self)
        d["event"] = self.event.value
        return json.dumps(d, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> Marker:
        try:
            d = json.loads(text)
            return cls(
                event=MarkerEvent(d["event"]),
                label=str(d.get("label", "")),
                t_s=float(d["t_s"]),
                session=str(d.get("session", "")),
                detail=str(d.get("detail", "")),
            )
        except (ValueError, KeyError, TypeError) as exc:
            msg = f"not a segment marker ({exc.__class__.__name__}): {text[:80]!r}"
            raise PmdcError(msg) from None
