"""The identification session as a ROS-free state machine.

The identification node feeds every driver sample (driver time, current, speed)
to :meth:`Session.on_sample`, which answers with the command for the next
sample, the segment markers to publish and the progress. The session follows
the *driver's* clock (one plan sample per driver sample), so a slow host never
stretches or shrinks a test. Staircase levels are held until the motor has
really settled (:class:`SteadyStateDetector`: speed drift and current drift over
a trailing window within the measurement noise), with a timeout.

A :class:`SafetyMonitor` checks every sample for over-current, over-speed and
stall (current high while the shaft does not turn); the node adds lost driver
data (:meth:`Session.check_link`), a crashed peer and Ctrl-C through
:meth:`Session.abort`. Every way out of a running session returns the safe
command (armature open, or zero volts, by configuration).

Command convention: ``Command.voltage_v`` is volts, NaN = armature open.
"""

from __future__ import annotations

import enum
import json
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from pmdc_ident.backends.base import SafeMode
from pmdc_ident.core.data import TestKind
from pmdc_ident.core.errors import ParameterError, PmdcError
from pmdc_ident.core.excitation import TestPlan
from pmdc_ident.core.motors import Limits, MotorSpec

__all__ = [
    "AbortReason",
    "Command",
    "Marker",
    "MarkerEvent",
    "PlanCheckError",
    "Progress",
    "SafetyConfig",
    "SafetyMonitor",
    "Session",
    "SessionState",
    "SessionStep",
    "SteadyStateConfig",
    "SteadyStateDetector",
    "check_plan",
]


class PlanCheckError(PmdcError):
    """The planned sequence would exceed the driver's or the session's limits."""


class AbortReason(enum.Enum):
    """Why a session stopped early (the value is what the ``status`` topic carries)."""

    OVER_CURRENT = "over_current"
    OVER_SPEED = "over_speed"
    STALL = "stall"
    LOST_DRIVER_DATA = "lost_driver_data"
    PEER_CRASHED = "peer_crashed"
    INTERRUPTED = "interrupted"
    DRIVER_FAULT = "driver_fault"


class SessionState(enum.Enum):
    IDLE = "idle"  # built, not started
    WAITING = "waiting"  # started, waiting for the first driver sample
    RUNNING = "running"
    DONE = "done"
    ABORTED = "aborted"


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


@dataclass(frozen=True)
class Command:
    """The voltage for the next driver sample; NaN = armature open."""

    voltage_v: float

    @property
    def open_armature(self) -> bool:
        return math.isnan(self.voltage_v)


@dataclass(frozen=True)
class Progress:
    state: SessionState
    test: str  # current segment label ('' before/after)
    segment_index: int  # 0-based
    n_segments: int
    segment_fraction: float  # 0..1 of the nominal segment length
    total_fraction: float  # 0..1 of the nominal plan
    samples: int  # driver samples consumed by the session
    abort_reason: AbortReason | None = None

    def to_json(self) -> str:
        d = asdict(self)
        d["state"] = self.state.value
        d["abort_reason"] = self.abort_reason.value if self.abort_reason else None
        return json.dumps(d, separators=(",", ":"))


@dataclass(frozen=True)
class SessionStep:
    """What the node does after one sample: command (None = send nothing), markers."""

    command: Command | None
    markers: tuple[Marker, ...] = ()
    abort_reason: AbortReason | None = None


# ---------------------------------------------------------------------------
# Safety
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SafetyConfig:
    """Abort thresholds. Units in the names; a stall is current above
    ``stall_current_a`` while ``|speed| < stall_speed_rad_s`` for ``stall_time_s``."""

    current_max_a: float
    speed_max_rad_s: float
    stall_current_a: float
    stall_speed_rad_s: float = 1.0
    stall_time_s: float = 1.0
    data_timeout_s: float = 0.5

    def __post_init__(self) -> None:
        for f in ("current_max_a", "speed_max_rad_s", "stall_current_a", "stall_time_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v > 0):
                msg = f"safety.{f} must be a positive number, got {v}"
                raise ParameterError(msg)
        for f in ("stall_speed_rad_s", "data_timeout_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v >= 0):
                msg = f"safety.{f} must be a number >= 0, got {v}"
                raise ParameterError(msg)

    @classmethod
    def for_limits(
        cls,
        limits: Limits,
        tau_m_s: float,
        *,
        stall_current_fraction: float = 0.5,
        stall_speed_rad_s: float = 1.0,
        data_timeout_s: float = 0.5,
    ) -> SafetyConfig:
        """Defaults from motor limits: stall after 3 tau_m (a free rotor is at 95 %)."""
        return cls(
            current_max_a=limits.current_max_a,
            speed_max_rad_s=limits.speed_max_rad_s,
            stall_current_a=stall_current_fraction * limits.current_max_a,
            stall_speed_rad_s=stall_speed_rad_s,
            stall_time_s=max(3.0 * tau_m_s, 0.05),
            data_timeout_s=data_timeout_s,
        )


class SafetyMonitor:
    """Checks each sample; the first violation is latched as the abort reason."""

    def __init__(self, config: SafetyConfig) -> None:
        self.config = config
        self._stall_since: float | None = None
        self.reason: AbortReason | None = None
        self.detail = ""

    def check(self, t_s: float, current_a: float, speed_rad_s: float) -> AbortReason | None:
        c = self.config
        if not (math.isfinite(current_a) and math.isfinite(speed_rad_s)):
            return self._trip(AbortReason.DRIVER_FAULT, "driver sent a non-finite reading")
        if abs(current_a) > c.current_max_a:
            return self._trip(
                AbortReason.OVER_CURRENT,
                f"|current| {abs(current_a):.3g} A > {c.current_max_a:.3g} A at t={t_s:.3f} s",
            )
        if abs(speed_rad_s) > c.speed_max_rad_s:
            return self._trip(
                AbortReason.OVER_SPEED,
                f"|speed| {abs(speed_rad_s):.4g} rad/s > {c.speed_max_rad_s:.4g} rad/s "
                f"at t={t_s:.3f} s",
            )
        if abs(current_a) > c.stall_current_a and abs(speed_rad_s) < c.stall_speed_rad_s:
            if self._stall_since is None:
                self._stall_since = t_s
            elif t_s - self._stall_since >= c.stall_time_s:
                return self._trip(
                    AbortReason.STALL,
                    f"stall: |current| > {c.stall_current_a:.3g} A with |speed| < "
                    f"{c.stall_speed_rad_s:.3g} rad/s for {t_s - self._stall_since:.2f} s",
                )
        else:
            self._stall_since = None
        return None

    def _trip(self, reason: AbortReason, detail: str) -> AbortReason:
        if self.reason is None:
            self.reason, self.detail = reason, detail
        return reason


# ---------------------------------------------------------------------------
# Steady state
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class SteadyStateConfig:
    """When a staircase level counts as settled.

    Over the trailing ``window_s`` the fitted drift (slope x window) of speed and of
    current must both be within ``n_sigma`` times their residual noise, or within
    ``rel_tol`` of their mean. A level is held at least ``min_hold_fraction`` and at
    most ``timeout_factor`` times its nominal (planned) length.
    """

    window_s: float = 0.0  # 0: one mechanical time constant
    n_sigma: float = 3.0
    rel_tol: float = 0.002
    min_hold_fraction: float = 0.5
    timeout_factor: float = 4.0
    check_every_s: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < self.min_hold_fraction <= self.timeout_factor:
            msg = "steady_state: need 0 < min_hold_fraction <= timeout_factor"
            raise ParameterError(msg)
        for f in ("window_s", "n_sigma", "rel_tol", "check_every_s"):
            v = float(getattr(self, f))
            if not (math.isfinite(v) and v >= 0):
                msg = f"steady_state.{f} must be a number >= 0, got {v}"
                raise ParameterError(msg)


class SteadyStateDetector:
    """Trailing-window drift test on speed and current (preallocated ring buffer)."""

    def __init__(self, window_samples: int, config: SteadyStateConfig) -> None:
        self.n = max(8, int(window_samples))
        self.config = config
        self._t = np.zeros(self.n)
        self._i = np.zeros(self.n)
        self._w = np.zeros(self.n)
        self._k = 0

    def reset(self) -> None:
        self._k = 0

    def push(self, t_s: float, current_a: float, speed_rad_s: float) -> None:
        j = self._k % self.n
        self._t[j], self._i[j], self._w[j] = t_s, current_a, speed_rad_s
        self._k += 1

    @property
    def full(self) -> bool:
        return self._k >= self.n

    def drift(self) -> tuple[float, float, float, float]:
        """(speed drift, speed tolerance, current drift, current tolerance) over the window."""
        t = self._t - self._t.mean()
        stt = float(t @ t)
        out: list[float] = []
        for y in (self._w, self._i):
            ym = float(y.mean())
            slope = float(t @ (y - ym)) / stt if stt > 0 else 0.0
            resid = y - ym - slope * t
            sigma = float(np.sqrt(resid @ resid / max(self.n - 2, 1)))
            span = float(self._t.max() - self._t.min())
            tol = max(self.config.n_sigma * sigma, self.config.rel_tol * abs(ym))
            out += [abs(slope) * span, tol]
        return out[0], out[1], out[2], out[3]

    def is_steady(self) -> bool:
        if not self.full:
            return False
        dw, tw, di, ti = self.drift()
        return dw <= tw and di <= ti


# ---------------------------------------------------------------------------
# Plan check
# ---------------------------------------------------------------------------
def check_plan(
    plan: TestPlan,
    driver_limits: Limits,
    safety: SafetyConfig,
    nominal: MotorSpec | None = None,
) -> list[str]:
    """Reasons the plan must not run (empty: fine). Checked before anything moves."""
    problems: list[str] = []
    v_all = np.concatenate([s.voltage for s in plan.segments])
    v_max = float(np.nanmax(np.abs(v_all))) if np.isfinite(v_all).any() else 0.0
    if v_max > driver_limits.voltage_max_v * (1 + 1e-9):
        problems.append(
            f"plan needs {v_max:.3g} V but the driver's voltage limit is "
            f"{driver_limits.voltage_max_v:.3g} V"
        )
    if safety.current_max_a > driver_limits.current_max_a * (1 + 1e-9):
        problems.append(
            f"session current abort {safety.current_max_a:.3g} A is above the driver's "
            f"current limit {driver_limits.current_max_a:.3g} A"
        )
    if safety.speed_max_rad_s > driver_limits.speed_max_rad_s * (1 + 1e-9):
        problems.append(
            f"session speed abort {safety.speed_max_rad_s:.4g} rad/s is above the driver's "
            f"speed limit {driver_limits.speed_max_rad_s:.4g} rad/s"
        )
    if nominal is not None:
        p = nominal.model.params
        i_ss, w_ss = p.steady_state(v_max)
        if abs(w_ss) > safety.speed_max_rad_s:
            problems.append(
                f"nominal motor would reach {w_ss:.4g} rad/s at {v_max:.3g} V, above the "
                f"speed abort {safety.speed_max_rad_s:.4g} rad/s: lower the voltage fractions"
            )
        if abs(i_ss) > safety.current_max_a:
            problems.append(
                f"nominal motor would draw {i_ss:.3g} A steadily at {v_max:.3g} V, above "
                f"the current abort {safety.current_max_a:.3g} A"
            )
    return problems


# ---------------------------------------------------------------------------
# The session
# ---------------------------------------------------------------------------
@dataclass
class _Cursor:
    seg: int = 0
    pos: int = 0  # commands issued within the current segment
    samples: int = 0
    last_v: float = 0.0
    issued: int = 0  # plan samples issued over the session
    markers: list[Marker] = field(default_factory=list)


class Session:
    """Runs a :class:`TestPlan` sample by sample on the driver's clock."""

    def __init__(
        self,
        plan: TestPlan,
        safety: SafetyConfig,
        *,
        tau_m_s: float,
        steady: SteadyStateConfig | None = None,
        safe_mode: SafeMode = SafeMode.ZERO,
        name: str = "session",
    ) -> None:
        if not plan.segments:
            msg = "the plan holds no segment"
            raise ParameterError(msg)
        self.plan = plan
        self.dt_s = plan.dt_s
        self.name = name
        self.safe_mode = SafeMode(safe_mode)
        self.monitor = SafetyMonitor(safety)
        self.steady_config = steady or SteadyStateConfig()
        window_s = self.steady_config.window_s or tau_m_s
        self.detector = SteadyStateDetector(int(round(window_s / self.dt_s)), self.steady_config)
        self._check_every = max(1, int(round(self.steady_config.check_every_s / self.dt_s)))
        self.state = SessionState.IDLE
        self.abort_reason: AbortReason | None = None
        self.abort_detail = ""
        self._c = _Cursor()
        self._last_wall_s: float | None = None
        self._t_last_s = 0.0
        self.skipped_samples = 0  # driver samples that never reached the session
        self.held_samples: dict[str, int] = {}  # label -> samples actually held
        self.settled: dict[str, bool] = {}  # staircase label -> steady state reached

    # -- public -----------------------------------------------------------------
    @property
    def plan_labels(self) -> tuple[str, ...]:
        return tuple(s.label for s in self.plan.segments)

    @property
    def safe_command(self) -> Command:
        return Command(math.nan if self.safe_mode is SafeMode.OPEN else 0.0)

    @property
    def markers(self) -> tuple[Marker, ...]:
        return tuple(self._c.markers)

    @property
    def active(self) -> bool:
        return self.state in (SessionState.WAITING, SessionState.RUNNING)

    def start(self) -> None:
        if self.state is not SessionState.IDLE:
            msg = f"session {self.name} already {self.state.value}"
            raise PmdcError(msg)
        self.state = SessionState.WAITING

    def progress(self) -> Progress:
        c = self._c
        n_seg = len(self.plan.segments)
        running = self.state is SessionState.RUNNING
        label = self.plan.segments[c.seg].label if running and c.seg < n_seg else ""
        nominal = self.plan.segments[min(c.seg, n_seg - 1)].voltage.size
        seg_frac = min(1.0, c.pos / nominal) if running else float(self.state is SessionState.DONE)
        total = (
            1.0 if self.state is SessionState.DONE else min(1.0, c.issued / self.plan.n_samples)
        )
        return Progress(
            state=self.state,
            test=label,
            segment_index=min(c.seg, n_seg - 1),
            n_segments=n_seg,
            segment_fraction=seg_frac,
            total_fraction=total,
            samples=c.samples,
            abort_reason=self.abort_reason,
        )

    def on_sample(
        self, t_s: float, current_a: float, speed_rad_s: float, wall_s: float | None = None
    ) -> SessionStep:
        """Consume the driver sample at ``t_s``; return the command for the next sample.

        The plan advances by driver time: when samples were lost on the way, the
        plan skips as many samples as the driver produced, so segments keep their
        length on the driver's clock. A sample not newer than the last is ignored.
        """
        if wall_s is not None:
            self._last_wall_s = wall_s
        t_prev = self._t_last_s
        if not self.active:
            return SessionStep(None)
        reason = self.monitor.check(t_s, current_a, speed_rad_s)
        if reason is not None:
            self._t_last_s = max(t_s, t_prev)
            return self.abort(reason, t_s, self.monitor.detail)
        markers: list[Marker] = []
        if self.state is SessionState.WAITING:
            self._t_last_s = t_s
            self.state = SessionState.RUNNING
            t_next = t_s + self.dt_s
            markers.append(self._mark(MarkerEvent.SESSION_START, "", t_next))
            markers.append(self._mark(MarkerEvent.START, self.plan.segments[0].label, t_next))
            self.detector.reset()
            return SessionStep(Command(self._next_voltage()), tuple(markers))
        steps = int(round((t_s - t_prev) / self.dt_s))
        if steps < 1:
            return SessionStep(None)
        self._t_last_s = t_s
        self.skipped_samples += steps - 1
        for j in range(steps):
            t = t_prev + (j + 1) * self.dt_s
            if self._advance(t, current_a, speed_rad_s, markers, real=j == steps - 1):
                return SessionStep(self.safe_command, tuple(markers))
        return SessionStep(Command(self._next_voltage()), tuple(markers))

    def _advance(
        self, t_s: float, current_a: float, speed_rad_s: float, markers: list[Marker], real: bool
    ) -> bool:
        """One driver sample of the plan; True when the session just completed."""
        c = self._c
        c.samples += 1
        seg = self.plan.segments[c.seg]
        if real and seg.kind is TestKind.STAIRCASE:
            self.detector.push(t_s, current_a, speed_rad_s)
        if not self._segment_finished(seg):
            if not real:
                self._next_voltage()  # a lost sample still used its plan slot
            return False
        t_next = t_s + self.dt_s
        self.held_samples[seg.label] = c.pos
        markers.append(self._mark(MarkerEvent.END, seg.label, t_next))
        c.seg += 1
        c.pos = 0
        self.detector.reset()
        if c.seg >= len(self.plan.segments):
            self.state = SessionState.DONE
            markers.append(self._mark(MarkerEvent.SESSION_END, "", t_next))
            return True
        markers.append(self._mark(MarkerEvent.START, self.plan.segments[c.seg].label, t_next))
        if not real:
            self._next_voltage()
        return False

    def _next_voltage(self) -> float:
        c = self._c
        seg = self.plan.segments[c.seg]
        if c.pos < seg.voltage.size:
            v = float(seg.voltage[c.pos])
            c.issued += 1
        else:
            v = c.last_v  # staircase held beyond its nominal length
        c.pos += 1
        c.last_v = v
        return v

    def check_link(self, wall_s: float) -> SessionStep | None:
        """Lost driver data: no sample within ``data_timeout_s`` of wall time."""
        timeout = self.monitor.config.data_timeout_s
        if self.state is not SessionState.RUNNING or self._last_wall_s is None or timeout <= 0:
            return None
        gap = wall_s - self._last_wall_s
        if gap > timeout:
            detail = f"no driver sample for {gap:.2f} s (timeout {timeout:.2f} s)"
            return self.abort(AbortReason.LOST_DRIVER_DATA, None, detail)
        return None

    def abort(
        self, reason: AbortReason, t_s: float | None = None, detail: str = ""
    ) -> SessionStep:
        """Stop now: the safe command, an abort marker and the end of the open segment."""
        if not self.active:
            return SessionStep(self.safe_command, (), self.abort_reason)
        t = (self._last_t() if t_s is None else t_s) + self.dt_s
        markers: list[Marker] = []
        if self.state is SessionState.RUNNING:
            label = self.plan.segments[self._c.seg].label
            self.held_samples[label] = self._c.pos
            markers.append(self._mark(MarkerEvent.END, label, t))
        markers.append(self._mark(MarkerEvent.ABORT, "", t, detail or reason.value))
        markers.append(self._mark(MarkerEvent.SESSION_END, "", t, reason.value))
        self.state = SessionState.ABORTED
        self.abort_reason = reason
        self.abort_detail = detail or reason.value
        return SessionStep(self.safe_command, tuple(markers), reason)

    # -- internals --------------------------------------------------------------
    def _last_t(self) -> float:
        return self._t_last_s

    def _segment_finished(self, seg) -> bool:  # type: ignore[no-untyped-def]
        c = self._c
        n = seg.voltage.size
        if seg.kind is not TestKind.STAIRCASE:
            return c.pos >= n
        cfg = self.steady_config
        if c.pos >= int(math.ceil(cfg.timeout_factor * n)):
            self.settled[seg.label] = False
            return True
        if c.pos < int(math.ceil(cfg.min_hold_fraction * n)):
            return False
        if c.pos % self._check_every:
            return False
        if self.detector.is_steady():
            self.settled[seg.label] = True
            return True
        return False

    def _mark(self, event: MarkerEvent, label: str, t_s: float, detail: str = "") -> Marker:
        m = Marker(event, label, float(t_s), self.name, detail)
        self._c.markers.append(m)
        return m
