"""The identification node's decisions, ROS-free.

:class:`SessionController` owns everything the identification node decides: when a
session may start (:mod:`.startup`), the session itself (:class:`Session`), which
commands go out and when (:class:`CommandPolicy`), the latency of the driver's
samples (:class:`Latency`), the link and recorder checks, the flush of the last
samples, the hand-over to the identification, and the confirmation that the motor is
safe (:class:`SafeConfirmation`). The node turns ROS callbacks into the ``on_*``
inputs and :meth:`SessionController.tick`, and the controller's outputs into
publications through :class:`ControllerPorts`. Times are the host's monotonic
clock in seconds (``now_s``) unless the name says otherwise.

Phases: ``idle`` -> ``preparing`` (waiting for the driver, its limits and the
recorder) -> ``running`` -> ``flushing`` (the last samples) -> ``identifying`` ->
``finished`` (then ``idle`` again, or the node exits with ``exit_when_done``).
"""

from __future__ import annotations

import enum
import json
import re
import secrets
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from pmdc_ident.core.enums import AbortReason, ExitCode, LogLevel, SafeMode, SessionStatus
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.markers import MarkerEvent
from pmdc_ident.core.schema import SCHEMA_VERSION
from pmdc_ident.core.stream_join import HeldStream
from pmdc_ident.node_logic.session.link import CommandPolicy, Latency, SafeConfirmation
from pmdc_ident.node_logic.session.machine import Session, SessionState, SessionStep
from pmdc_ident.node_logic.session.ports import (
    ControllerPorts,
    ExportRequest,
    IdentificationJob,
    IdentificationOutcome,
)
from pmdc_ident.node_logic.session.recording import Recording
from pmdc_ident.node_logic.session.remedy import abort_remedy
from pmdc_ident.node_logic.session.sequential import (
    DesignJob,
    DesignOutcome,
    PlanSetting,
    build_planned_session,
)
from pmdc_ident.node_logic.session.startup import (
    DRIVER_PARAMETERS,
    Peers,
    SessionSettings,
    StartCheck,
    StartRules,
    build_session,
)

__all__ = [
    "ControllerConfig",
    "ControllerPorts",
    "IdentificationJob",
    "Phase",
    "SessionController",
    "default_session_name",
]

PROGRESS_EVERY_S = 0.2
DRIVER_GONE_S = 2.0  # flushing: no driver sample for this long, the rest will not come
DRIVER_QUIET_S = 0.5  # stopped while idle: no driver sample for this long, it stopped too
LATE_TICK_S = 0.1  # a timer this late means the node itself was held up
# A driver sample waits this long (host clock) for its current: the node's executor
# can drain a backlog of encoder samples before the current samples of the same stamps
CURRENT_WAIT_S = 0.1
EARLY_SAMPLES = 16384  # current/voltage samples kept before a session runs (~16 s at 1 kHz)
LATE_TICK_GRACE_S = 0.05
LATE_WINDOW_S = 2.0  # an abort out of travel: how far back samples count for its lateness
# plan: auto starts its pre-test once the driver has applied this session's 0 V this long
RELEASE_AFTER_NS = 100_000_000
RELEASE_TIMEOUT_S = 10.0
START_RETRIES = 3  # plan: auto on a joint: re-designs for one extension before it ends
RECENT_NS = 100_000_000  # a joint that moved farther than its tolerance in this is moving


class Phase(enum.Enum):
    IDLE = "idle"
    PREPARING = "preparing"  # waiting for the driver, its limits and the recorder
    RUNNING = "running"
    FLUSHING = "flushing"  # session over: waiting for the last samples
    IDENTIFYING = "identifying"
    FINISHED = "finished"

    @property
    def status(self) -> SessionStatus | None:
        """The ``status`` topic's state in this phase (flushing: still the running
        session's); None when finished: the outcome says it (done, aborted, ...)."""
        return _PHASE_STATUS.get(self)


_PHASE_STATUS = {
    Phase.IDLE: SessionStatus.IDLE,
    Phase.PREPARING: SessionStatus.PREPARING,
    Phase.RUNNING: SessionStatus.RUNNING,
    Phase.FLUSHING: SessionStatus.RUNNING,
    Phase.IDENTIFYING: SessionStatus.IDENTIFYING,
}


@dataclass(frozen=True)
class ControllerConfig:
    """The node's settings the controller acts on (the node's parameter table)."""

    session: SessionSettings
    start: StartRules
    confirm_timeout_s: float
    exit_when_done: bool
    output_dir: str
    flush_timeout_s: float  # longest wait for a session's last samples (the QoS buffer)
    fixed: Mapping[str, float] = field(default_factory=dict)
    exports: ExportRequest | None = None  # write the exports beside the results
    namespace: str = ""  # the node's namespace: part of the default session name
    plan: PlanSetting = field(default_factory=PlanSetting)  # default, auto or a plan CSV


class SessionController:
    """The identification node's state machine; see the module docs."""

    def __init__(self, config: ControllerConfig, ports: ControllerPorts) -> None:
        self.config = config
        self.ports = ports
        self.phase = Phase.IDLE
        self.session: Session | None = None
        self.finished = False
        self.exit_code: int = ExitCode.OK
        self.result_json: str | None = None
        self.recording = Recording()
        self.latency = Latency()
        self.commands = CommandPolicy()
        self.confirmation = SafeConfirmation(config.confirm_timeout_s)
        self._stop_requested: AbortReason | None = None
        self.peers = Peers()  # what is known of the driver and the recorder
        self._prep_deadline_s = 0.0
        self._last_current_a = 0.0
        self._currents = HeldStream()  # the current, held at each encoder stamp
        # current and voltage samples that came before the session ran but stamped after
        # the last encoder sample seen: they belong to the session (see _start_recording)
        self._early_current: deque[tuple[int, float]] = deque(maxlen=EARLY_SAMPLES)
        self._early_voltage: deque[tuple[int, float, float]] = deque(maxlen=EARLY_SAMPLES)
        self._applied = HeldStream()  # the driver's applied voltage, likewise
        self._held: deque[tuple[int, float, float, float]] = (
            deque()
        )  # stamp, speed, arrived, angle
        self._last_tick_s: float | None = None
        self._suspect_until_s = 0.0
        self._last_progress_s = 0.0
        self._flush_deadline_s = 0.0
        self._session_count = 0
        self._stopped_idle = False  # a stop that cut nothing short (see confirm_tick)
        # plan: auto (node_logic.session.sequential): the design state, a job at the worker
        self.design: Any = None
        self._design_pending = False
        self._design_seen = 0  # segment ends already re-fitted
        self._design_samples = 0  # samples recorded at the last re-fit
        self._applied_since = 0  # plan: auto: the driver applies our command since (stamp)
        self._running_since_s = 0.0
        self._last_position = 0.0
        self._last_speed = 0.0
        self._start_retries = 0  # extensions re-designed in a row: the joint rested elsewhere

    # -- state ---------------------------------------------------------------------------
    @property
    def safe_mode(self) -> SafeMode:
        return self.config.session.safe_mode

    @property
    def confirming(self) -> bool:
        return self.confirmation.pending

    @property
    def safe_confirmed(self) -> bool:
        return self.confirmation.confirmed

    @property
    def recording_samples(self) -> bool:
        return self.phase in (Phase.RUNNING, Phase.FLUSHING)

    # -- inputs: requests ----------------------------------------------------------------
    def start(self, autostart: bool, now_s: float) -> None:
        """The node is up: say so, and request a session when ``autostart``."""
        self._last_tick_s = now_s
        self._publish_phase()
        fixed = dict(self.config.fixed) or "none"
        self.ports.log(
            LogLevel.INFO,
            f"identification ready: nominal motor {self.config.session.nominal.name}, "
            f"safe mode {self.safe_mode.value}, fixed {fixed}",
        )
        if autostart:
            self.request_session(now_s)

    def request_session(self, now_s: float) -> tuple[bool, str]:
        busy = (Phase.PREPARING, Phase.RUNNING, Phase.FLUSHING, Phase.IDENTIFYING)
        if self.phase in busy:
            return False, f"a session is {self.phase.value}"
        self.phase = Phase.PREPARING
        self._prep_deadline_s = now_s + self.config.start.driver_wait_s
        self.peers.reset()
        self._publish_phase()
        return True, "session requested"

    def abort_session(self, now_s: float) -> tuple[bool, str]:
        if self.phase is Phase.RUNNING and self.session is not None:
            step = self.session.abort(AbortReason.INTERRUPTED, None, "abort_session called")
            self._apply(step, now_s)
            return True, "session aborted, motor safe"
        return False, f"no session running ({self.phase.value})"

    def request_stop(self, reason: AbortReason = AbortReason.INTERRUPTED) -> None:
        """Ctrl-C / SIGTERM (from a signal handler): acted on at the next tick."""
        self._stop_requested = reason

    # -- inputs: data --------------------------------------------------------------------
    def on_current(self, stamp_ns: int, current_a: float) -> None:
        self.peers.on_stamp("current", stamp_ns)
        if self.recording_samples:
            self.recording.current.append(stamp_ns, current_a)
        else:
            self._early_current.append((stamp_ns, current_a))
        self._currents.add(stamp_ns, current_a)
        self._release(None)

    def on_voltage(self, stamp_ns: int, voltage_v: float, terminal_v: float) -> None:
        self.peers.on_stamp("voltage_applied", stamp_ns)
        self._applied.add(stamp_ns, voltage_v)
        if self.recording_samples:
            self.recording.voltage.append(stamp_ns, voltage_v, terminal_v)
            s = self.session
            if s is not None and s.awaiting_release and voltage_v == voltage_v:
                # plan: auto: the driver applies this session's command (not NaN: the
                # armature closed on it): the pre-test may start - once this node is
                # caught up with the driver again. Making the session held it up once:
                # it started a joint's square wave 0.56 s behind the driver, and the
                # driver held its first level for those 0.56 s (out_of_travel on a CI
                # machine at load 3)
                self._applied_since = self._applied_since or stamp_ns
                caught_up = self.latency.last_ns <= self.config.start.max_start_latency_s * 1e9
                if stamp_ns - self._applied_since >= RELEASE_AFTER_NS and caught_up:
                    self._apply(s.release(), self._last_tick_s or 0.0)
        else:
            self._early_voltage.append((stamp_ns, voltage_v, terminal_v))
            if self.confirmation.pending:
                state = self.confirmation.on_voltage(stamp_ns, voltage_v)
                if state:
                    self.ports.log(LogLevel.INFO, f"motor confirmed safe by the driver: {state}")
        self._release(None)

    def on_encoder(
        self, stamp_ns: int, position_rad: float, speed_rad_s: float, now_s: float, now_ns: int
    ) -> None:
        """A driver sample; ``now_ns`` is the host's wall clock (the latency's)."""
        self.peers.last_sample_s = now_s
        self.peers.on_stamp("encoder", stamp_ns)
        self._last_position, self._last_speed = position_rad, speed_rad_s
        lag_ns = self.latency.update(stamp_ns, now_ns)
        if not self.recording_samples:
            return
        self.recording.encoder.append(stamp_ns, position_rad, speed_rad_s)
        self.recording.latency.append(lag_ns)
        if self.phase is not Phase.RUNNING or self.session is None:
            return
        if lag_ns > self.config.session.data_timeout_s * 1e9:
            detail = f"driver samples arrive {lag_ns * 1e-9:.2f} s late: commands would be too"
            s = self.session
            self._held.clear()
            self._apply(s.abort(AbortReason.LOST_DRIVER_DATA, stamp_ns * 1e-9, detail), now_s)
            return
        self._held.append((stamp_ns, speed_rad_s, now_s, position_rad))
        self._release(now_s)

    def _release(self, now_s: float | None) -> None:
        """Step the session on each held encoder sample with the current and the applied
        voltage of its stamp (the newest at or before it), in stamp order, once they have
        arrived: a node held up by the host drains its queues one topic after another,
        and a stall judged on a stale current would be judged late, a staircase level on
        a stale voltage settled before it was applied. A sample waits at most
        :data:`CURRENT_WAIT_S`, and not at all for a topic the driver does not send (the
        joining policy's rule 4: :mod:`pmdc_ident.core.stream_join`)."""
        held, cur, vol = self._held, self._currents, self._applied
        while held and self.phase is Phase.RUNNING and self.session is not None:
            stamp_ns, speed_rad_s, arrived_s, position_rad = held[0]
            waiting = cur.waiting_for(stamp_ns) or vol.waiting_for(stamp_ns)
            if waiting and (now_s is None or now_s - arrived_s < CURRENT_WAIT_S):
                return
            held.popleft()
            self._last_current_a = cur.at(stamp_ns, self._last_current_a)
            step = self.session.on_sample(
                stamp_ns * 1e-9,
                self._last_current_a,
                speed_rad_s,
                arrived_s,
                position_rad,
                self._applied_at(stamp_ns),
            )
            self._apply(step, arrived_s)
        held.clear()  # the session is over: nothing left to step

    def _applied_at(self, stamp_ns: int) -> float | None:
        """The driver's applied voltage at ``stamp_ns`` (the newest at or before it: one
        still on its way after :data:`CURRENT_WAIT_S` reads as the previous one, which
        only delays a staircase's steady-state test), None before the first arrives."""
        return self._applied.at(stamp_ns, None)

    def on_recorder_status(self, text: str, now_s: float) -> None:
        self.peers.on_recorder_status(text, now_s)

    def on_driver_parameters(self, values: Mapping[str, Any] | None) -> None:
        """The driver's answer (``None``: no usable answer, ask again)."""
        self.peers.driver_asked = False
        if values is not None:
            self.peers.driver = dict(values)

    def on_identified(self, outcome: IdentificationOutcome) -> None:
        s = self.session
        name = s.name if s is not None else ""
        for level, text in outcome.notes:
            self.ports.log(level, text)
        if outcome.error:
            self.ports.log(
                LogLevel.ERROR, f"session {name}: identification failed: {outcome.error}"
            )
            self._publish_status(SessionStatus.FAILED, detail=outcome.error)
            self.exit_code = outcome.exit_code or ExitCode.FAILED
        else:
            self.result_json = outcome.json_text
            self.ports.publish_result(outcome.json_text)
            self.ports.log(
                LogLevel.INFO,
                f"session {name}: identified from {outcome.n_samples} samples\n{outcome.table}",
            )
            self._publish_status(
                SessionStatus.DONE,
                detail=f"{outcome.n_samples} samples",
                results=outcome.output_dir,
            )
        self.phase = Phase.FINISHED

    # -- the timer -----------------------------------------------------------------------
    def tick(self, now_s: float) -> None:
        """The node's periodic timer: start-up, link checks, progress, end of session."""
        if self._last_tick_s is not None and now_s - self._last_tick_s > LATE_TICK_S:
            # This node itself was held up (the timer is late): samples may be waiting
            # in its queue, so judge the driver's link only after they are processed.
            self._suspect_until_s = now_s + LATE_TICK_GRACE_S
        self._last_tick_s = now_s
        if self._stop_requested is not None:
            reason, self._stop_requested = self._stop_requested, None
            self._stop(reason, now_s)
            return
        if self.phase is Phase.PREPARING:
            self._prepare(now_s)
        elif self.phase is Phase.RUNNING and self.session is not None:
            self._watch_running(self.session, now_s)
            self._design_tick(now_s)
        elif self.phase is Phase.FLUSHING:
            self._maybe_identify(now_s)
        elif self.phase is Phase.FINISHED:
            if self.confirmation.pending:
                self.confirm_tick(now_s)
            elif self.config.exit_when_done:
                self.finished = True
            else:
                self.phase = Phase.IDLE

    def confirm_tick(self, now_s: float) -> None:
        """Repeat the safe command until the driver confirms it, up to the timeout."""
        quiet = now_s - self.peers.last_sample_s > DRIVER_QUIET_S
        if self._stopped_idle and quiet and self.confirmation.pending:
            # ros2 launch stops every node at once: a driver that stops makes its motor
            # safe itself, and a stop while idle left nothing applied to confirm away
            self.confirmation.cancel()
            self.ports.log(
                LogLevel.INFO, "the driver stopped too (it makes the motor safe when it stops)"
            )
            return
        what = self.confirmation.tick(now_s)
        if what == "timeout":
            self.ports.log(
                LogLevel.ERROR,
                "could NOT confirm the safe state: the driver did not report 0 V or an open "
                f"armature within {self.config.confirm_timeout_s:g} s (its watchdog opens it)",
            )
        elif what == "repeat":
            self._make_safe(now_s)  # the first command may have been lost

    # -- start-up ------------------------------------------------------------------------
    def start_check(self, now_s: float) -> StartCheck:
        """The first start-up check not met yet (see :mod:`.startup`)."""
        return self.peers.start_check(now_s, self.latency.last_ns, self.config.start)

    def _prepare(self, now_s: float) -> None:
        if self.config.plan.auto:
            # plan: auto designs in the worker from the pre-test's end on: started now,
            # its interpreter's start-up is over before the motor moves (started with the
            # pre-test, it competed with the node's first commands on a busy host)
            self.ports.prepare_identification(None)
        if now_s > self._prep_deadline_s:
            why = self.peers.refusal(now_s, self.latency.last_ns, self.config.start)
            self._fail(f"session not started, motor untouched: {why}")
            return
        if self.peers.driver is None:
            self.peers.note_wait(StartCheck.DRIVER, now_s)
            if not self.peers.driver_asked:
                self.peers.driver_asked = self.ports.request_driver_parameters(DRIVER_PARAMETERS)
            return
        check = self.start_check(now_s)
        self.peers.note_wait(check, now_s)
        if check is not StartCheck.READY:
            return
        try:
            if self.config.plan.default:
                session = build_session(self.config.session, self.peers.driver, self._next_name())
            else:
                session, self.design = build_planned_session(
                    self.config.session,
                    self.config.plan,
                    self.peers.driver,
                    self._next_name(),
                    self._last_position,
                )
                self._design_pending, self._design_seen, self._design_samples = False, 0, 0
                self._applied_since, self._running_since_s = 0, now_s
        except PmdcError as exc:
            self._fail(str(exc))
            return
        self._start_recording()
        self.session = session
        self.commands.armature_open = False
        session.start()
        self.phase = Phase.RUNNING
        # the identification warms up while the motor runs: the end costs only the fit
        # (plan: auto needs its worker at once, for the pre-test: no warm-up run first)
        self.ports.prepare_identification(
            None if self.design is not None else self.config.session.nominal
        )
        self.ports.log(
            LogLevel.INFO,
            f"session {session.name}: {len(session.plan.segments)} segments, nominal "
            f"{session.plan.duration_s:.1f} s ({', '.join(session.plan_labels)}); start-up "
            f"waited for {self.peers.waits_line()}",
        )
        self._publish_phase()

    def _start_recording(self) -> None:
        """Record from now on, with the current and voltage samples already here that are
        stamped after the last encoder sample seen: the session starts at the next encoder
        sample, and a host that drains its queues one topic after another hands those
        over first (the first 0.34 s of current and voltage were missing from a session's
        own record at load 6, though every sample was in the bag)."""
        self.recording.clear()
        after = self.peers.stamps_ns.get("encoder", -1)
        for ns, a in self._early_current:
            if ns > after:
                self.recording.current.append(ns, a)
        for ns, v, term in self._early_voltage:
            if ns > after:
                self.recording.voltage.append(ns, v, term)
        self._early_current.clear()
        self._early_voltage.clear()

    def _next_name(self) -> str:
        self._session_count += 1
        name = self.config.session.session_name or default_session_name(self.config.namespace)
        return f"{name}_{self._session_count}" if self._session_count > 1 else name

    def _fail(self, text: str) -> None:
        self.ports.log(LogLevel.ERROR, text)
        self.exit_code = ExitCode.USER_ERROR
        self._publish_status(SessionStatus.REFUSED, detail=text)
        if self.config.exit_when_done:
            self.phase = Phase.FINISHED
            self.finished = True
        else:
            self.phase = Phase.IDLE

    # -- running -------------------------------------------------------------------------
    def _watch_running(self, s: Session, now_s: float) -> None:
        if self._suspect_until_s > now_s:
            return
        step = s.check_link(now_s)
        recorder_lost = now_s - self.peers.recorder_seen_s > self.config.start.peer_timeout_s
        if step is None and self.config.start.require_recorder and recorder_lost:
            step = s.abort(
                AbortReason.PEER_CRASHED, None, "recorder heartbeat lost: recorder gone"
            )
        if step is not None:
            self._apply(step, now_s)
        elif now_s - self._last_progress_s > PROGRESS_EVERY_S:
            self._last_progress_s = now_s
            self.ports.publish_progress(s.progress().to_json())

    def _apply(self, step: SessionStep, now_s: float) -> None:
        for m in step.markers:
            self.ports.publish_marker(m.to_json())
        cmd = step.command
        if cmd is not None:
            if cmd.open_armature:
                if not self.commands.armature_open:
                    self._open_armature(now_s)
            elif self.commands.should_send(cmd.voltage_v, now_s):
                self.commands.armature_open = False
                self._send(cmd.voltage_v, now_s)
        if step.abort_reason is not None:
            self._on_aborted(now_s)
        elif self.session is not None and self.session.state is SessionState.DONE:
            self._begin_flush(now_s)

    def _send(self, voltage_v: float, now_s: float) -> None:
        self.ports.send_voltage(float(voltage_v))
        self.commands.sent(voltage_v, now_s)

    def _open_armature(self, now_s: float) -> None:
        self.commands.armature_open = True
        if not self.ports.open_armature():
            # No service: 0 V is the other safe state (the driver's watchdog opens later).
            self._send(0.0, now_s)
            self.ports.log(LogLevel.WARNING, "open_armature service not available: sent 0 V")

    def _make_safe(self, now_s: float) -> None:
        if self.safe_mode is SafeMode.OPEN:
            self.commands.armature_open = False
            self._open_armature(now_s)
        else:
            self._send(0.0, now_s)

    # -- ways out ------------------------------------------------------------------------
    def _stop(self, reason: AbortReason, now_s: float) -> None:
        """Ctrl-C / SIGTERM: abort a running session, make the motor safe, finish.

        The exit status is 130 when the stop cut something short (a session being
        prepared, run, flushed or identified); a node stopped while idle or after its
        work exits as it stands (0 unless something failed), as ``ros2 launch``
        expects of a node it stops."""
        cut_short = self.phase not in (Phase.IDLE, Phase.FINISHED)
        if self.phase is Phase.RUNNING and self.session is not None:
            self._apply(self.session.abort(reason, None, f"{reason.value} by signal"), now_s)
        else:
            self._make_safe(now_s)
            self.ports.log(
                LogLevel.WARNING if cut_short else LogLevel.INFO,
                f"stopped by signal while {self.phase.value}: no session running, 0 V / open sent",
            )
            self._stopped_idle = not cut_short
            self._publish_status(SessionStatus.STOPPED, reason=reason.value)
            self.confirmation.start(self.peers.stamps_ns.get("encoder", 0), now_s)
        self.finished = True
        if cut_short:
            self.exit_code = ExitCode.INTERRUPTED

    def _on_aborted(self, now_s: float) -> None:
        s = self.session
        assert s is not None
        self._make_safe(now_s)
        reason = s.abort_reason.value if s.abort_reason else "?"
        late_s = self.recording.max_latency_s(round((s.markers[-1].t_s - LATE_WINDOW_S) * 1e9))
        remedy = abort_remedy(
            s.abort_reason or AbortReason.INTERRUPTED,
            s.monitor.config,
            self.config.start.peer_timeout_s,
            late_s=late_s,
            command_delay_s=self.config.plan.command_delay_s,
        )
        self.ports.log(
            LogLevel.ERROR,
            f"session {s.name} ABORTED ({reason}): {s.abort_detail}; safe command sent"
            + (f"; {remedy}" if remedy else ""),
        )
        self.ports.publish_progress(s.progress().to_json())
        self._publish_status(
            SessionStatus.ABORTED, reason=reason, detail=s.abort_detail, remedy=remedy
        )
        self.exit_code = ExitCode.ABORTED
        self.phase = Phase.FINISHED
        self.confirmation.start(round(s.markers[-1].t_s * 1e9), now_s)

    # -- after the session ---------------------------------------------------------------
    def _begin_flush(self, now_s: float) -> None:
        s = self.session
        assert s is not None
        self._make_safe(now_s)
        self.ports.publish_progress(s.progress().to_json())
        self.phase = Phase.FLUSHING
        # every sample up to the end is on its way (reliable, buffered): wait for it
        self._flush_deadline_s = now_s + self.config.flush_timeout_s
        self.ports.log(
            LogLevel.INFO,
            f"session {s.name} complete: {s.progress().samples} samples; driver-to-node "
            f"latency {self.recording.latency_summary()}",
        )

    def _maybe_identify(self, now_s: float) -> None:
        s = self.session
        assert s is not None
        end_ns = round(s.markers[-1].t_s * 1e9)
        arriving = now_s - self.peers.last_sample_s < DRIVER_GONE_S  # else the driver is gone
        if not self.recording.complete_until(end_ns) and now_s < self._flush_deadline_s:
            if arriving:
                return  # still arriving (a backlog on a loaded machine)
        self.phase = Phase.IDENTIFYING
        waited = now_s - (self._flush_deadline_s - self.config.flush_timeout_s)
        self.ports.log(
            LogLevel.INFO, f"session {s.name}: last samples in after {waited:.2f} s; identifying"
        )
        self._publish_phase()
        self.ports.start_identification(
            IdentificationJob(
                samples=self.recording.samples(s.markers),
                session=s.name,
                source=self._bag_path(s.name) or f"session {s.name}",
                output_dir=self._output_dir(s.name),
                fixed=dict(self.config.fixed),
                exports=self._exports(s),
                extra=(
                    {
                        "experiment_design": self.design.report(
                            sum(s.held_samples.values()) * s.dt_s
                        )
                    }
                    if self.design is not None
                    else None
                ),
            )
        )

    # -- plan: auto (node_logic.session.sequential) ----------------------------------------------
    @property
    def design_pending(self) -> bool:
        return self._design_pending

    def _design_tick(self, now_s: float) -> None:
        """Hand the worker a re-fit when the pre-test or the plan has run out (the
        session holds meanwhile), or when a segment has ended since the last one."""
        s = self.session
        if self.design is None or s is None or self._design_pending or not s.active:
            return
        if s.awaiting_release:
            if now_s - self._running_since_s > RELEASE_TIMEOUT_S:
                late = self.latency.last_ns * 1e-9
                why = (
                    f"driver samples still arrive {late:.2f} s late: commands would be too"
                    if late > self.config.start.max_start_latency_s
                    else "voltage_cmd not reaching it?"
                )
                detail = (
                    f"the driver did not apply this session's commands within "
                    f"{RELEASE_TIMEOUT_S:g} s ({why})"
                )
                self._apply(s.abort(AbortReason.DRIVER_FAULT, None, detail), now_s)
            return
        ends = [m for m in s.markers if m.event is MarkerEvent.END]
        if not ends:
            return
        if not s.holding and len(ends) <= self._design_seen:
            return
        if not s.holding and self.design.designs == 0:
            return  # the pre-test: designed once it is over
        if not s.holding and self.recording.encoder.n < 1.25 * self._design_samples:
            return  # a re-fit while the plan runs: once a quarter more data is in
        end_ns = round(ends[-1].t_s * 1e9)
        if not self.recording.complete_until(end_ns) and now_s - self.peers.last_sample_s < 1.0:
            return  # its last samples are still arriving
        self._design_seen = len(ends)
        self._design_samples = self.recording.encoder.n
        self._design_pending = True
        self.ports.start_design(
            DesignJob(
                samples=self.recording.samples(s.markers),
                session=s.name,
                source=f"session {s.name}",
                design=self.design,
                plan_done=s.holding,
                position_rad=self._last_position,
                speed_rad_s=self._last_speed,
                current_a=self._last_current_a,
            )
        )

    def on_design(self, outcome: DesignOutcome, now_s: float) -> None:
        """The worker's decision for a ``plan: auto`` session."""
        self._design_pending = False
        for level, text in outcome.notes:
            self.ports.log(level, text)
        s = self.session
        live = s is not None and s.active and self.phase is Phase.RUNNING
        off = self._start_off(outcome) if live else ""
        if off and self._start_retries < START_RETRIES:
            # dropped, its design state with it: the hold is re-fitted at the next tick,
            # from where the joint is then
            self._start_retries += 1
            self.ports.log(
                LogLevel.INFO, f"session {s.name}: plan auto: {off}: re-designing from there"
            )
            return
        if outcome.design is not None:
            self.design = outcome.design
        if not live:
            return
        if off:
            why = f"plan not extended: {off}, after {START_RETRIES} re-designs"
            self.ports.log(LogLevel.WARNING, f"session {s.name}: plan auto: {why}")
            self._apply(s.finish(why), now_s)
            return
        self._start_retries = 0
        self.ports.log(
            LogLevel.INFO, f"session {s.name}: plan auto: {outcome.action}: {outcome.message}"
        )
        if outcome.action == "extend":
            try:
                self._apply(s.extend(outcome.segments), now_s)
            except PmdcError as exc:
                self._apply(s.finish(f"plan not extended: {exc}"), now_s)
        elif outcome.action == "stop":
            self._apply(s.finish(outcome.message), now_s)
        # continue: the plan runs on; a hold is re-fitted at the next tick

    def _start_off(self, outcome: DesignOutcome) -> str:
        """Why an extension may not start here ('' when it may): a joint's plan is
        designed from the rest position its worker predicted; one that rests farther
        from it than :func:`~pmdc_ident.core.design.sequential.start_tolerance_rad`
        would carry that offset through the whole plan, into its travel margin."""
        start = outcome.start_rad
        travel = self.config.plan.travel_rad
        if outcome.action != "extend" or start is None or travel is None:
            return ""
        from pmdc_ident.core.design.sequential import start_tolerance_rad

        tol = start_tolerance_rad(travel)
        off = self._last_position - start
        enc = self.recording.encoder  # the session's samples: the last RECENT_NS of them
        seen = enc.values_since(enc.last_ns() - RECENT_NS, 0)
        moved = float(seen.max() - seen.min()) if seen.size else 0.0
        if moved > tol:
            return (
                f"the joint is still moving ({moved:.3g} rad in the last "
                f"{RECENT_NS * 1e-9:g} s, tolerance {tol:.3g} rad)"
            )
        if abs(off) <= tol:
            return ""
        return (
            f"the joint is at {self._last_position:.4g} rad, {off:+.3g} rad from the "
            f"{start:.4g} rad its extension was designed from (tolerance {tol:.3g} rad)"
        )

    def _exports(self, s: Session) -> ExportRequest | None:
        """The configured exports at the session's sample rate (the gains' rate)."""
        e = self.config.exports
        if e is None:
            return None
        joint = e.joint or str((self.peers.driver or {}).get("joint_name") or "")
        return replace(e, sample_rate_hz=e.sample_rate_hz or 1.0 / s.dt_s, joint=joint)

    def _bag_path(self, session: str) -> str:
        """The recorder's bag of ``session`` as an absolute path ('' without one): the
        result's ``sources`` must name it wherever the document is read."""
        path = self.peers.recorder_paths.get(session)
        return str(Path(path).expanduser().absolute()) if path else ""

    def _output_dir(self, session: str) -> Path:
        path = self._bag_path(session)
        if path:
            return Path(path)
        return Path(self.config.output_dir).expanduser().absolute() / session

    def _publish_phase(self) -> None:
        """The status of the phase just entered (idle, preparing, running, identifying)."""
        status = self.phase.status
        assert status is not None, self.phase  # a finished phase publishes its outcome
        self._publish_status(status)

    def _publish_status(self, state: SessionStatus, **extra: str) -> None:
        d: dict[str, Any] = {
            "schema_version": SCHEMA_VERSION,
            "state": state.value,
            "session": self.session.name if self.session else "",
        }
        d.update(extra)
        if self.session is not None:
            d["bag"] = self.peers.recorder_paths.get(self.session.name, "")
        self.ports.publish_status(json.dumps(d))


def default_session_name(namespace: str = "", now: datetime | None = None) -> str:
    """``session_<UTC time>[_<namespace>]_<6 hex digits>``: unique even for two motors
    started in the same second (``session_20261127_100501_left_wheel_3fa9c1``); the
    namespace makes a robot's bags tell their motors apart at a glance."""
    stamp = (now or datetime.now(UTC)).strftime("%Y%m%d_%H%M%S")
    ns = re.sub(r"[^A-Za-z0-9_]+", "_", namespace).strip("_")
    return "_".join(part for part in ("session", stamp, ns, secrets.token_hex(3)) if part)
