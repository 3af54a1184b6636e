"""Data containers for recorded or simulated runs (ROS-free).

A :class:`Run` is what one CSV file or bag holds: a tuple of :class:`Segment`
objects, each one experiment (a step, a sweep, a coast-down, one staircase
level...) sampled on its own time grid. Missing signals are ``None``; a NaN
voltage marks a sample whose armature was open (coast-down).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.errors import DataError

__all__ = ["Run", "Segment", "TestKind", "segment_kind"]

FloatArray = NDArray[np.float64]


class TestKind(enum.Enum):
    """The test types the identification runs; segment labels start with the value."""

    __test__ = False  # not a pytest test class

    STEP = "step"
    SWEEP = "sweep"
    COAST = "coast"
    STAIRCASE = "staircase"
    OTHER = "other"


def segment_kind(label: str) -> TestKind:
    """Test type from a segment label such as ``step_up_1`` or ``coast``."""
    low = label.strip().lower()
    for kind in (TestKind.STEP, TestKind.SWEEP, TestKind.COAST, TestKind.STAIRCASE):
        if low.startswith(kind.value):
            return kind
    return TestKind.OTHER


@dataclass(frozen=True)
class Segment:
    """One experiment: sampled signals on a common, strictly increasing time grid.

    Attributes are SI: ``t`` s, ``voltage`` V (commanded; NaN = armature open),
    ``current`` A, ``position`` rad, ``speed`` rad/s, ``terminal_voltage`` V
    (measured at the motor, when the hardware has it).
    """

    label: str
    t: FloatArray
    voltage: FloatArray | None
    current: FloatArray | None = None
    position: FloatArray | None = None
    speed: FloatArray | None = None
    terminal_voltage: FloatArray | None = None
    kind: TestKind = field(default=TestKind.OTHER)

    def __post_init__(self) -> None:
        t = _float_array("t", self.t, self.label)
        n = t.size
        if n < 2:
            msg = f"segment {self.label!r} has {n} sample(s); at least 2 are needed"
            raise DataError(msg)
        if not np.isfinite(t).all():
            msg = f"segment {self.label!r}: time column holds NaN or inf"
            raise DataError(msg)
        dt = np.diff(t)
        if (dt <= 0).any():
            k = int(np.argmax(dt <= 0))
            msg = (
                f"segment {self.label!r}: time is not strictly increasing "
                f"(t[{k + 1}] = {t[k + 1]:.6g} s after t[{k}] = {t[k]:.6g} s)"
            )
            raise DataError(msg)
        object.__setattr__(self, "t", t)
        for name in ("voltage", "current", "position", "speed", "terminal_voltage"):
            value = getattr(self, name)
            if value is None:
                continue
            arr = _float_array(name, value, self.label)
            if arr.size != n:
                msg = f"segment {self.label!r}: {name} has {arr.size} samples, t has {n}"
                raise DataError(msg)
            if np.isinf(arr).any():
                msg = f"segment {self.label!r}: {name} holds infinite values"
                raise DataError(msg)
            if name != "voltage" and np.isnan(arr).any():
                k = int(np.argmax(np.isnan(arr)))
                msg = f"segment {self.label!r}: {name} is NaN at t = {t[k]:.6g} s"
                raise DataError(msg)
            object.__setattr__(self, name, arr)
        if self.position is None and self.speed is None:
            msg = f"segment {self.label!r} has neither position nor speed"
            raise DataError(msg)
        if self.kind is TestKind.OTHER:
            object.__setattr__(self, "kind", segment_kind(self.label))

    # -- derived ------------------------------------------------------------------
    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @property
    def dt_s(self) -> float:
        """Median sample period."""
        return float(np.median(np.diff(self.t)))

    @property
    def is_uniform(self) -> bool:
        """True when every sample period is within 1 % of the median."""
        dt = np.diff(self.t)
        return bool(np.all(np.abs(dt - self.dt_s) <= 0.01 * self.dt_s))

    @property
    def open_mask(self) -> NDArray[np.bool_]:
        """Samples with the armature open (NaN voltage)."""
        if self.voltage is None:
            return np.zeros(self.n, dtype=bool)
        return np.isnan(self.voltage)

    def speed_or_derivative(self) -> FloatArray:
        """Measured speed, or the central difference of position when speed is absent."""
        if self.speed is not None:
            return self.speed
        assert self.position is not None
        return np.gradient(self.position, self.t)

    def slice(self, start: int, stop: int, label: str | None = None) -> Segment:
        def cut(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[start:stop]

        return replace(
            self,
            label=label or self.label,
            t=self.t[start:stop],
            voltage=cut(self.voltage),
            current=cut(self.current),
            position=cut(self.position),
            speed=cut(self.speed),
            terminal_voltage=cut(self.terminal_voltage),
        )


@dataclass(frozen=True)
class Run:
    """All segments of one data source (CSV file, bag, simulation)."""

    segments: tuple[Segment, ...]
    source: str = ""

    def __post_init__(self) -> None:
        segs = tuple(self.segments)
        if not segs:
            msg = f"{self.source or 'run'}: no segments"
            raise DataError(msg)
        object.__setattr__(self, "segments", segs)

    def __iter__(self):  # type: ignore[no-untyped-def]
        return iter(self.segments)

    def __len__(self) -> int:
        return len(self.segments)

    def of_kind(self, kind: TestKind) -> tuple[Segment, ...]:
        return tuple(s for s in self.segments if s.kind is kind)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(s.label for s in self.segments)

    @property
    def has_voltage(self) -> bool:
        return any(s.voltage is not None for s in self.segments)

    @property
    def has_current(self) -> bool:
        return all(s.current is not None for s in self.segments)


def _float_array(name: str, value: object, label: str) -> FloatArray:
    try:
        arr = np.ascontiguousarray(np.asarray(value, dtype=float).ravel())
    except (TypeError, ValueError):
        msg = f"segment {label!r}: {name} is not numeric"
        raise DataError(msg) from None
    return arr
