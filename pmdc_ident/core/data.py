"""Data containers for recorded or simulated runs (ROS-free).

A :class:`Run` is what one CSV file or bag holds: a tuple of :class:`Segment`
objects, each one experiment (a step, a sweep, a coast-down, one staircase
level...) sampled on its own time grid. Missing signals are ``None``; a NaN
voltage marks a sample whose armature was open (coast-down).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from numpy.typing import NDArray

from pmdc_ident.core.errors import DataError, SignalRangeError

__all__ = [
    "HISTORY_MAX_SAMPLES",
    "MIN_SAMPLE_STEP_S",
    "SIGNAL_LIMITS",
    "Run",
    "Segment",
    "TestKind",
    "check_excitation",
    "excitation_problem",
    "heat_state",
    "link_history",
    "same_clock",
    "segment_kind",
    "unique_labels",
]

FloatArray = NDArray[np.float64]
# Commanded voltages kept before a segment: enough for a delay of this many samples.
HISTORY_MAX_SAMPLES = 4096
# Segments are contiguous when the gap between them is within this many sample periods.
_CONTIGUOUS_GAP = 1.5
# Largest magnitude of each signal (SI) any motor test can produce: far beyond a
# real motor, far below where squares and integrals overflow. A value beyond is
# a unit mistake or garbage, refused before it reaches a fit.
SIGNAL_LIMITS: dict[str, tuple[float, str]] = {
    "t": (4e9, "s"),  # a bag stamps it in int64 ns: up to 9.2e9 s
    "voltage": (1e5, "V"),
    "current": (1e5, "A"),
    "position": (1e12, "rad"),
    "speed": (1e6, "rad/s"),
    "terminal_voltage": (1e5, "V"),
}
# Shortest time between two samples (s): no clock ticks faster; shorter steps
# are rounding noise or a unit mistake.
MIN_SAMPLE_STEP_S = 1e-9


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

    History, when the segment was cut from a longer contiguous recording (both
    optional; ``None`` = unknown, the segment is treated as starting the record):
    ``history_voltage`` V holds the commanded voltages of the samples just before
    the segment, oldest first (NaN = open), on the segment's sample period;
    ``history_heat_a2s`` A^2*s is the measured ``int i^2 dt`` over the driven
    samples of the record before the segment's first sample;
    ``history_heat_profile`` says when that heat was dissipated, so a winding that
    cools (first-order heating) can start warm by the right amount: rows of [age in
    sample periods of this segment, share of ``history_heat_a2s``] (unit-free, so a
    change of time or current unit leaves it valid), see :func:`heat_state`.
    """

    label: str
    t: FloatArray
    voltage: FloatArray | None
    current: FloatArray | None = None
    position: FloatArray | None = None
    speed: FloatArray | None = None
    terminal_voltage: FloatArray | None = None
    kind: TestKind = field(default=TestKind.OTHER)
    history_voltage: FloatArray | None = field(default=None, repr=False)
    history_heat_a2s: float | None = None
    history_heat_profile: FloatArray | None = field(default=None, repr=False)

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
        _check_magnitude(self.label, "t", t, t)
        if (dt < MIN_SAMPLE_STEP_S).any():
            k = int(np.argmax(dt < MIN_SAMPLE_STEP_S))
            msg = (
                f"segment {self.label!r}: samples {dt[k]:.3g} s apart at t = {t[k]:.9g} s "
                f"(the shortest possible step is {MIN_SAMPLE_STEP_S:g} s): is t in seconds?"
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
            _check_magnitude(self.label, name, arr, t)
            object.__setattr__(self, name, arr)
        if self.position is None and self.speed is None:
            msg = f"segment {self.label!r} has neither position nor speed"
            raise DataError(msg)
        if self.kind is TestKind.OTHER:
            object.__setattr__(self, "kind", segment_kind(self.label))
        if self.history_voltage is not None:
            hv = _float_array("history_voltage", self.history_voltage, self.label)
            if np.isinf(hv).any():
                msg = f"segment {self.label!r}: history_voltage holds infinite values"
                raise DataError(msg)
            object.__setattr__(self, "history_voltage", hv[-HISTORY_MAX_SAMPLES:])
        if self.history_heat_a2s is not None:
            q = float(self.history_heat_a2s)
            if not (math.isfinite(q) and q >= 0.0):
                msg = f"segment {self.label!r}: history_heat_a2s must be >= 0 A^2*s, got {q}"
                raise DataError(msg)
            object.__setattr__(self, "history_heat_a2s", q)
        if self.history_heat_profile is not None:
            hp = np.asarray(self.history_heat_profile, dtype=float).reshape(-1, 2)
            if not (np.isfinite(hp).all() and (hp >= 0.0).all()):
                msg = f"segment {self.label!r}: history_heat_profile must be finite and >= 0"
                raise DataError(msg)
            object.__setattr__(self, "history_heat_profile", hp)

    # -- derived ------------------------------------------------------------------
    @property
    def n(self) -> int:
        return int(self.t.size)

    @property
    def duration_s(self) -> float:
        return float(self.t[-1] - self.t[0])

    @cached_property
    def dt_s(self) -> float:
        """Median sample period (computed once: fits ask for it at every evaluation)."""
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

    def driven_heat_a2s(self, stop: int | None = None) -> float | None:
        """Measured ``int i^2 dt`` (trapezoid) over the driven intervals before sample ``stop``.

        ``None`` without a current column. An interval ``[t_k, t_k+1)`` counts when
        its command ``voltage[k]`` is not NaN (as the model integrates it).
        """
        if self.current is None:
            return None
        stop = self.n if stop is None else stop
        if stop < 2:
            return 0.0
        i2 = self.current[:stop] ** 2
        area = 0.5 * (i2[:-1] + i2[1:]) * np.diff(self.t[:stop])
        if self.voltage is not None:
            area = np.where(np.isnan(self.voltage[: stop - 1]), 0.0, area)
        return float(np.sum(area))

    def slice(self, start: int, stop: int, label: str | None = None) -> Segment:
        """Samples ``start:stop``; the samples cut off before ``start`` become history."""
        start, stop, _ = slice(start, stop).indices(self.n)

        def cut(a: FloatArray | None) -> FloatArray | None:
            return None if a is None else a[start:stop]

        hist_v, hist_q = self.history_voltage, self.history_heat_a2s
        hist_p = self.history_heat_profile
        if start > 0:
            if self.voltage is not None:
                before = self.voltage[:start]
                hist_v = before if hist_v is None else np.concatenate([hist_v, before])
                hist_v = _recent(hist_v, self.dt_s)
            heat = self.driven_heat_a2s(start + 1)
            if heat is not None:
                ages, a2s = _heat_blocks(self, start + 1, float(self.t[start]))
                old_ages, old_a2s = _profile_blocks(self, float(self.t[start] - self.t[0]))
                hist_q = (hist_q or 0.0) + heat
                hist_p = _profile(
                    np.concatenate([old_ages, ages]), np.concatenate([old_a2s, a2s]), self.dt_s
                )
        return replace(
            self,
            label=label or self.label,
            t=self.t[start:stop],
            voltage=cut(self.voltage),
            current=cut(self.current),
            position=cut(self.position),
            speed=cut(self.speed),
            terminal_voltage=cut(self.terminal_voltage),
            history_voltage=hist_v,
            history_heat_a2s=hist_q,
            history_heat_profile=hist_p,
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


def link_history(segments: Sequence[Segment]) -> tuple[Segment, ...]:
    """Give each segment the history of the contiguous segments before it.

    Segments are taken in the given (record) order; a segment continues the
    previous one when it starts one sample period (within half a period) after
    the previous one's last sample, on the same period, *and* its first samples
    follow from the previous one's last within what the motor does in one sample
    (:mod:`pmdc_ident.core.continuity`: a clock that runs on over joined runs is no
    continuation). The first segment of each contiguous stretch keeps the history it
    has; a separate run keeps none.
    """
    from pmdc_ident.core.continuity import boundary_jump, step_limits

    segs = list(segments)
    limits = step_limits(segs) if len(segs) > 1 else {}
    out: list[Segment] = []
    for seg in segs:
        prev = out[-1] if out else None
        if prev is None or not _contiguous(prev, seg):
            out.append(seg)
            continue
        if boundary_jump(prev, seg, limits) is not None:  # a separate run: its own start
            out.append(
                replace(
                    seg, history_voltage=None, history_heat_a2s=None, history_heat_profile=None
                )
            )
            continue
        hist_v = None
        if prev.voltage is not None and seg.voltage is not None:
            parts = (
                [prev.voltage]
                if prev.history_voltage is None
                else [
                    prev.history_voltage,
                    prev.voltage,
                ]
            )
            hist_v = _recent(np.concatenate(parts), seg.dt_s)
        hist_q, hist_p = None, None
        heat = prev.driven_heat_a2s()
        if heat is not None and seg.current is not None:
            # the interval from the previous segment's last sample to this one's first
            i2 = 0.5 * (prev.current[-1] ** 2 + seg.current[0] ** 2)  # type: ignore[index]
            gap = float(seg.t[0] - prev.t[-1]) * i2
            if prev.voltage is not None and np.isnan(prev.voltage[-1]):
                gap = 0.0
            hist_q = (prev.history_heat_a2s or 0.0) + heat + gap
            t0 = float(seg.t[0])
            ages, a2s = _heat_blocks(prev, prev.n, t0)
            old_ages, old_a2s = _profile_blocks(prev, t0 - float(prev.t[0]))
            hist_p = _profile(
                np.concatenate([old_ages, ages, [0.5 * (t0 - float(prev.t[-1]))]]),
                np.concatenate([old_a2s, a2s, [gap]]),
                seg.dt_s,
            )
        out.append(
            replace(
                seg, history_voltage=hist_v, history_heat_a2s=hist_q, history_heat_profile=hist_p
            )
        )
    return tuple(out)


def unique_labels(segments: Iterable[Segment]) -> list[Segment]:
    """The segments with repeated labels made unique, the one rule for every command:
    the second ``step_up`` becomes ``step_up_2`` (then ``_3``...), skipping labels
    already taken. Segments whose label is unique are returned as they are."""
    taken: set[str] = set()
    out: list[Segment] = []
    for s in segments:
        label = s.label
        k = 2
        while label in taken:
            label = f"{s.label}_{k}"
            k += 1
        taken.add(label)
        out.append(s if label == s.label else replace(s, label=label))
    return out


def heat_state(seg: Segment, time_constant_s: float) -> float:
    """The winding heat state ``q`` (A^2*s) at the segment's first sample for
    first-order heating ``dq/dt = i^2 - q/tau``: the history's heat, each part decayed
    by its age; without a profile (or with an infinite tau), ``history_heat_a2s``."""
    q = seg.history_heat_a2s or 0.0
    hp = seg.history_heat_profile
    if hp is None or not (math.isfinite(time_constant_s) and time_constant_s > 0.0):
        return q
    return q * float(np.sum(hp[:, 1] * np.exp(-hp[:, 0] * seg.dt_s / time_constant_s)))


def _heat_blocks(seg: Segment, stop: int, t_ref: float) -> tuple[FloatArray, FloatArray]:
    """Driven ``i^2 dt`` (trapezoid) of each interval before sample ``stop``, and the
    interval centres' ages (s) at time ``t_ref``."""
    if seg.current is None or stop < 2:
        return np.zeros(0), np.zeros(0)
    i2 = seg.current[:stop] ** 2
    t = seg.t[:stop]
    area = 0.5 * (i2[:-1] + i2[1:]) * np.diff(t)
    if seg.voltage is not None:
        area = np.where(np.isnan(seg.voltage[: stop - 1]), 0.0, area)
    return t_ref - 0.5 * (t[:-1] + t[1:]), area


def _profile_blocks(seg: Segment, shift_s: float) -> tuple[FloatArray, FloatArray]:
    """A segment's own heat profile as (age s, A^2*s), aged by ``shift_s``."""
    hp, q = seg.history_heat_profile, seg.history_heat_a2s
    if hp is None or not q:
        if q:  # heat of unknown age: taken as dissipated just before the segment
            return np.array([shift_s]), np.array([q])
        return np.zeros(0), np.zeros(0)
    return hp[:, 0] * seg.dt_s + shift_s, hp[:, 1] * q


HEAT_PROFILE_BINS = 192  # geometric bins in age: a few % wide, fine for any tau

# Commands kept as a segment's history: they fill a delay line (delay <= 1 s, a lag
# <= 1 s: after 10 lag times the older commands weigh < 5e-5). Keeping every command
# before every segment made the history quadratic in the length of a record.
HISTORY_S = 12.0


def _recent(history: FloatArray, dt_s: float) -> FloatArray:
    """The last :data:`HISTORY_S` seconds of commands of ``history``."""
    keep = int(math.ceil(HISTORY_S / dt_s)) if dt_s > 0 else history.size
    return history[-keep:] if history.size > keep else history


def _profile(ages_s: FloatArray, a2s: FloatArray, dt_s: float) -> FloatArray | None:
    """(age s, A^2*s) blocks binned geometrically in age -> rows [age in samples, share]."""
    total = float(np.sum(a2s))
    if not (total > 0.0 and math.isfinite(total)):
        return None
    x = np.maximum(ages_s / dt_s, 0.5)
    edges = np.geomspace(0.5, float(np.max(x)) * 1.001 + 0.5, HEAT_PROFILE_BINS + 1)
    w, _ = np.histogram(x, bins=edges, weights=a2s)
    wx, _ = np.histogram(x, bins=edges, weights=a2s * x)
    keep = w > 0.0
    return np.column_stack([wx[keep] / w[keep], w[keep] / total])


def same_clock(prev: Segment, seg: Segment) -> bool:
    """``seg`` starts one sample period (within half a period) after ``prev``'s last
    sample, on the same period: the clock allows a continuation (the samples decide,
    :func:`link_history`)."""
    return _contiguous(prev, seg)


def _contiguous(prev: Segment, seg: Segment) -> bool:
    dt = prev.dt_s
    if abs(seg.dt_s - dt) > 0.01 * dt:
        return False
    gap = float(seg.t[0] - prev.t[-1])
    return abs(gap - dt) <= 0.5 * dt


def _check_magnitude(label: str, name: str, arr: FloatArray, t: FloatArray) -> None:
    limit, unit = SIGNAL_LIMITS[name]
    with np.errstate(invalid="ignore"):
        beyond = np.abs(arr) > limit  # NaN (an open armature) is never beyond
    if beyond.any():
        k = int(np.argmax(beyond))
        at = "" if name == "t" else f" at t = {t[k]:.6g} s"
        msg = (
            f"segment {label!r}: {name} = {arr[k]:.6g} {unit}{at} is beyond "
            f"any motor test (|{name}| <= {limit:g} {unit}): a unit mistake?"
        )
        raise SignalRangeError(msg, signal=name, value=float(arr[k]), unit=unit)


def _float_array(name: str, value: object, label: str) -> FloatArray:
    try:
        arr = np.ascontiguousarray(np.asarray(value, dtype=float).ravel())
    except (TypeError, ValueError):
        msg = f"segment {label!r}: {name} is not numeric"
        raise DataError(msg) from None
    return arr


# Smallest swing that counts as excitation: far below any real test (a tenth of a
# volt, a milliamp, a fraction of a rad/s), far above rounding noise of data in
# SI units; a record that swings less is flat or in the wrong unit.
EXCITATION_FLOOR: dict[str, float] = {"voltage": 1e-6, "current": 1e-9, "speed": 1e-9}
# Fewest driven (voltage given) samples a record with a voltage column needs.
MIN_DRIVEN_SAMPLES = 3


def excitation_problem(segments: Sequence[Segment]) -> tuple[str, str] | None:
    """What makes a record carry no information (what is flat, what to record), or None.

    The one rule shared by :func:`check_excitation` (identify, diagnose) and the
    data-quality gate (``pmdc-ident check``), so they agree.
    """
    segs = list(segments)
    speeds = np.concatenate([s.speed_or_derivative() for s in segs])
    volts = [s.voltage[~np.isnan(s.voltage)] for s in segs if s.voltage is not None]
    v = np.concatenate(volts) if volts else np.zeros(0)
    has_open = any(s.open_mask.any() for s in segs)
    cur = [s.current for s in segs if s.current is not None]
    floor = EXCITATION_FLOOR
    moving = float(np.ptp(speeds)) > floor["speed"]
    v_flat = v.size == 0 or float(np.ptp(v)) <= floor["voltage"]
    still_input = v.size == 0 or (v_flat and float(np.max(np.abs(v))) <= floor["voltage"])
    if not moving and still_input and not has_open:
        held = f"{v[0]:g} V" if v.size else "no voltage column"
        what = f"the motor never moves ({held}, speed constant)"
        return what, "record a step, sweep, staircase or coast-down"
    if not moving:
        what = (
            f"the speed never changes (it spans {np.ptp(speeds):.3g} rad/s), "
            "so nothing mechanical can be identified"
        )
        return what, "record a run in which the motor speeds up or slows down, in SI units"
    driven = int(v.size)
    if volts and driven < MIN_DRIVEN_SAMPLES:
        what = (
            f"only {driven} driven sample(s), the armature is open in every other row: "
            "nothing drives the motor long enough to tell R, L or Ke"
        )
        return what, f"drive the motor for at least {MIN_DRIVEN_SAMPLES} samples (a step)"
    cur_flat = all(float(np.ptp(c)) <= floor["current"] for c in cur)
    if cur and cur_flat and v_flat and not has_open:
        return "voltage and current are constant in every segment", "record a step or a sweep"
    return None


def check_excitation(segments: Sequence[Segment]) -> None:
    """Refuse a record that carries no information: nothing moves or nothing is driven.

    One line (a :class:`DataError`) saying what is flat and what to record, before
    any fit runs into a singular problem.
    """
    problem = excitation_problem(segments)
    if problem is not None:
        what, fix = problem
        msg = f"no excitation: {what}; {fix}"
        raise DataError(msg)
