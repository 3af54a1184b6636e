"""Bounded numeric options: an absurd value is one line and exit 2, before any work.

``--bootstrap 1000000000`` ran without bound, ``--sample-rate-hz 1e12`` too, ``--every
nan`` and ``-1`` were accepted, ``--seed -1`` was an internal error. Every numeric
option of the commands goes through :func:`check_bounds`: finite, inside a range that
says what it means, the reason in the line. Light at import time (no numpy).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from pmdc_ident.core.errors import ParameterError

__all__ = ["Bound", "check_bounds"]


@dataclass(frozen=True)
class Bound:
    """An option, its range (inclusive unless ``open_low``) and why it has it."""

    option: str
    low: float
    high: float
    why: str = ""
    open_low: bool = False  # low itself is refused (a rate of 0 Hz)
    integer: bool = False

    def check(self, value: float | int | None) -> None:
        if value is None:
            return
        v = float(value)
        ok = math.isfinite(v) and (v > self.low if self.open_low else v >= self.low)
        ok = ok and v <= self.high and (not self.integer or v == int(v))
        if ok:
            return
        op = ">" if self.open_low else ">="
        kind = "a whole number " if self.integer else ""

        def fmt(x: float) -> str:
            return str(int(x)) if self.integer else f"{x:g}"

        rng = f"{kind}{op} {fmt(self.low)} and <= {fmt(self.high)}"
        why = f" ({self.why})" if self.why else ""
        shown = f"{value!r}" if isinstance(value, float) else f"{value}"
        msg = f"{self.option} must be {rng}{why}, got {shown}"
        raise ParameterError(msg)


def check_bounds(values: Iterable[tuple[Bound, float | int | None]]) -> None:
    """:meth:`Bound.check` of each (bound, value); the first violation is the error."""
    for bound, value in values:
        bound.check(value)
