"""The identification session as a ROS-free state machine (see the package docs)."""

from __future__ import annotations

import enum
import json
import math
from dataclasses import asdict, dataclass, field, replace

from pmdc_ident.core.data import TestKind
from pmdc_ident.core.enums import AbortReason, SafeMode
from pmdc_ident.core.errors import ParameterError, PmdcError
from pmdc_ident.core.excitation import PlannedSegment, TestPlan
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor
from pmdc_ident.core.schema import SCHEMA_VERSION
from pmdc_ident.node_logic.session.steady_state import SteadyStateConfig, SteadyStateDetector

__all__ = ["Command", "Session", "SessionProgress", "SessionState", "SessionStep"]


class SessionState(enum.Enum):
    IDLE = "idle"  # built, not started
    WAITING = "waiting"  # started, waiting for the first driver sample
    RUNNING = "running"
    DONE = "done"
    ABORTED = "aborted"


@dataclass(frozen=True)
class Command:
    """The voltage for the next driver sample; NaN = armature open."""

    voltage_v: float

    @property
    def open_armature(self) -> bool:
        return math.isnan(self.voltage_v)


@dataclass(frozen=True)
class SessionProgress:
    state: SessionState
    test: str  # current segment label ('' before/after)
    segment_index: int  # 0-based
    n_segments: int
    segment_fraction: float  # 0..1 of the nominal segment length
    total_fraction: float  # 0..1 of the nominal plan
    samples: int  # driver samples consumed by the session
    abort_reason: AbortReason | None = None

    def to_json(self) -> str:
        d: dict[str, object] = {"schema_version": SCHEMA_VERSION, **asdict(self)}
        d["state"] = self.state.value
        d["abort_reason"] = self.abort_reason.value if self.abort_reason else None
        return json.dumps(d, separators=(",", ":"))


@dataclass(frozen=True)
class SessionStep:
    """What the node does after one sample: command (None = send nothing), markers."""

    command: Command | None
    markers: tuple[Marker, ...] = ()
    abort_reason: AbortReason | None = None


@dataclass
class _Cursor:
    seg: int = 0
    pos: int = 0  # commands issued within the current segment
    samples: int = 0
    last_v: float = 0.0
    before_v: float = 0.0  # the command before the current segment (0 V: the session's start)
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
        open_ended: bool = False,
        hold_first: bool = False,
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
        # plan: auto: when the plan runs out the session holds the safe command (no
        # segment open) until more segments come (extend) or it is told to end (finish)
        self.open_ended = open_ended
        # hold_first: the safe command until release() (the driver shown to apply it)
        self.holding = hold_first
        self.awaiting_release = hold_first

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

    def progress(self) -> SessionProgress:
        c = self._c
        n_seg = len(self.plan.segments)
        running = self.state is SessionState.RUNNING
        label = self.plan.segments[c.seg].label if running and c.seg < n_seg else ""
        nominal = self.plan.segments[min(c.seg, n_seg - 1)].voltage.size
        seg_frac = min(1.0, c.pos / nominal) if running else float(self.state is SessionState.DONE)
        total = (
            1.0 if self.state is SessionState.DONE else min(1.0, c.issued / self.plan.n_samples)
        )
        return SessionProgress(
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
        self,
        t_s: float,
        current_a: float,
        speed_rad_s: float,
        wall_s: float | None = None,
        position_rad: float | None = None,
        applied_v: float | None = None,
    ) -> SessionStep:
        """Consume the driver sample at ``t_s``; return the command for the next sample.

        The plan advances by driver time: when samples were lost on the way, the
        plan skips as many samples as the driver produced, so segments keep their
        length on the driver's clock. A sample not newer than the last is ignored.
        ``applied_v``: the voltage the driver applied at ``t_s`` (NaN: armature open;
        None: not known). A staircase level is judged settled only on samples at which
        the driver applies that level: a command that reaches it late (a loaded host,
        a command topic matched late) leaves a rotor at rest, 'steady' at the wrong
        level, and the level ended at its minimum hold without ever being applied.
        """
        if wall_s is not None:
            self._last_wall_s = wall_s
        t_prev = self._t_last_s
        if not self.active:
            return SessionStep(None)
        reason = self.monitor.check(t_s, current_a, speed_rad_s, position_rad)
        if reason is not None:
            self._t_last_s = max(t_s, t_prev)
            return self.abort(reason, t_s, self.monitor.detail)
        markers: list[Marker] = []
        if self.state is SessionState.WAITING:
            self._t_last_s = t_s
            self.state = SessionState.RUNNING
            t_next = t_s + self.dt_s
            markers.append(self._mark(MarkerEvent.SESSION_START, "", t_next))
            if self.holding:  # until release(): 0 V at rest (closes the armature)
                return SessionStep(Command(0.0), tuple(markers))
            markers.append(self._mark(MarkerEvent.START, self.plan.segments[0].label, t_next))
            self.detector.reset()
            return SessionStep(Command(self._next_voltage()), tuple(markers))
        steps = int(round((t_s - t_prev) / self.dt_s))
        if steps < 1:
            return SessionStep(None)
        self._t_last_s = t_s
        self.skipped_samples += steps - 1
        if self.holding:
            return SessionStep(Command(0.0) if self.awaiting_release else self.safe_command)
        for j in range(steps):
            t = t_prev + (j + 1) * self.dt_s
            real = j == steps - 1
            if self._advance(t, current_a, speed_rad_s, markers, real, applied_v):
                return SessionStep(self.safe_command, tuple(markers))
        if self._c.seg >= len(self.plan.segments):
            return SessionStep(self.safe_command, tuple(markers))
        return SessionStep(Command(self._next_voltage()), tuple(markers))

    def _advance(
        self,
        t_s: float,
        current_a: float,
        speed_rad_s: float,
        markers: list[Marker],
        real: bool,
        applied_v: float | None = None,
    ) -> bool:
        """One driver sample of the plan; True when the session just completed."""
        c = self._c
        c.samples += 1
        seg = self.plan.segments[c.seg]
        if real and seg.kind is TestKind.STAIRCASE:
            if _applies(applied_v, c.last_v, c.before_v):
                self.detector.push(t_s, current_a, speed_rad_s)
            else:  # the level is not applied yet: its settling has not started
                self.detector.reset()
        if not self._segment_finished(seg):
            if not real:
                self._next_voltage()  # a lost sample still used its plan slot
            return False
        t_next = t_s + self.dt_s
        self.held_samples[seg.label] = c.pos
        markers.append(self._mark(MarkerEvent.END, seg.label, t_next))
        c.seg += 1
        c.pos = 0
        c.before_v = c.last_v
        self.detector.reset()
        if c.seg >= len(self.plan.segments) and self.open_ended:
            self.holding = True  # more may come (extend) or the end (finish)
            return True
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

    def extend(self, segments: tuple[PlannedSegment, ...]) -> SessionStep:
        """More segments for an open-ended session (``plan: auto``): they run after the
        current plan; from a hold, the first starts at the next driver sample."""
        if not self.active or not segments or self.awaiting_release:
            return SessionStep(None)
        known = set(self.plan_labels)
        clash = [s.label for s in segments if s.label in known]
        if clash:
            msg = f"segments {', '.join(clash)} are already in the plan"
            raise ParameterError(msg)
        self.plan = replace(self.plan, segments=self.plan.segments + tuple(segments))
        if not self.holding:
            return SessionStep(None)
        self.holding = False
        self._c.before_v = 0.0  # the hold's safe command (0 V or an open armature)
        t_next = self._t_last_s + self.dt_s
        mark = self._mark(MarkerEvent.START, self.plan.segments[self._c.seg].label, t_next)
        return SessionStep(Command(self._next_voltage()), (mark,))

    def release(self) -> SessionStep:
        """Start the plan of a session built with ``hold_first``, at the next sample."""
        if not self.awaiting_release or self.state is not SessionState.RUNNING:
            return SessionStep(None)
        self.awaiting_release = False
        self.holding = False
        t_next = self._t_last_s + self.dt_s
        mark = self._mark(MarkerEvent.START, self.plan.segments[0].label, t_next)
        self.detector.reset()
        return SessionStep(Command(self._next_voltage()), (mark,))

    def finish(self, detail: str = "") -> SessionStep:
        """End an open-ended session now (its target is met, or nothing is left to run):
        the segment running ends at the next sample, and the session with it."""
        if not self.active:
            return SessionStep(None)
        t = self._t_last_s + self.dt_s
        markers: list[Marker] = []
        if self.state is SessionState.RUNNING and not self.holding:
            if self._c.seg < len(self.plan.segments):
                label = self.plan.segments[self._c.seg].label
                self.held_samples[label] = self._c.pos
                markers.append(self._mark(MarkerEvent.END, label, t))
        markers.append(self._mark(MarkerEvent.SESSION_END, "", t, detail))
        self.state = SessionState.DONE
        self.holding = False
        return SessionStep(self.safe_command, tuple(markers))

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
        running = self.state is SessionState.RUNNING and not self.holding
        if running and self._c.seg < len(self.plan.segments):
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


def _applies(applied_v: float | None, level_v: float, before_v: float) -> bool:
    """Whether the driver applies the staircase level ``level_v`` (commanded after
    ``before_v``): armature closed and nearer this level than the one before it (a
    board's reading of its own output, or a sagging supply, is close, not exact).
    ``None``: not known, taken as applied."""
    if applied_v is None:
        return True
    if not math.isfinite(applied_v):
        return False
    if not math.isfinite(before_v) or before_v == level_v:
        return True
    return abs(applied_v - level_v) <= abs(applied_v - before_v)
