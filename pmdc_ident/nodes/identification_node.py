"""The identification node: runs the test sequence through a driver and publishes the result.

Graph (names relative, so namespaces and remaps work):

=========================  ============================  =========================================
name                       type                          meaning
=========================  ============================  =========================================
``current``, ``encoder``,  sensor_msgs/msg/JointState    the driver's samples (subscribed)
``voltage_applied``
``voltage_cmd``            std_msgs/msg/Float64          the command for the next driver sample
``open_armature``          std_srvs/srv/Trigger (call)   coast-down and the ``open`` safe mode
``segment``                std_msgs/msg/String           JSON segment marker at each segment start
                                                         and end, on the driver's clock (reliable,
                                                         transient-local, KEEP_LAST(1000))
``progress``               std_msgs/msg/String           JSON: state, test, segment i/n, fractions
``status``                 std_msgs/msg/String           JSON: state, abort reason, detail, bag
``identified_parameters``  std_msgs/msg/String           the JSON of ``pmdc-ident identify --json``
                                                         (reliable, transient-local, KEEP_LAST(1))
``run_session``            std_srvs/srv/Trigger          start a session on demand
``abort_session``          std_srvs/srv/Trigger          stop the running session, motor safe
``recorder_status``        std_msgs/msg/String           the recorder's heartbeat and bag path
=========================  ============================  =========================================

The node holds no algorithm: the sequence, steady-state waits and safety checks are
:class:`pmdc_ident.core.session.Session`; the run is assembled with
:func:`pmdc_ident.dataio.bagio.assemble_run` (the function ``read_bag`` uses) and
identified with the same function and options as ``pmdc-ident identify``.
"""

from __future__ import annotations

import enum
import json
import math
import os
import signal
import sys
import threading
import time
from dataclasses import fields, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import rclpy
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.duration import Duration
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter_client import AsyncParameterClient
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String
from std_srvs.srv import Trigger

from pmdc_ident.core.enums import SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.excitation import SequenceConfig, default_plan, plan_for_motor
from pmdc_ident.core.fixed import parse_fix
from pmdc_ident.core.motors import Limits, MotorSpec, load_motor
from pmdc_ident.core.session import (
    AbortReason,
    SafetyConfig,
    Session,
    SessionState,
    SessionStep,
    SteadyStateConfig,
    check_plan,
)
from pmdc_ident.dataio.bagio import DriverArrays, assemble_run, parse_joint_state
from pmdc_ident.dataio.completeness import Completeness, completeness
from pmdc_ident.nodes.identify_call import identify_session_run
from pmdc_ident.nodes.qos import (
    COMMAND_QOS,
    LATCHED_QOS,
    SAMPLE_BUFFER_S,
    SEGMENT_QOS,
    sample_qos,
)

__all__ = ["IdentificationNode", "main"]

NODE_NAME = "identification_node"
EXIT_ABORTED = 3

# name -> (default, description, lower, upper); sequence.* and steady_state.* come from
# the core dataclasses below.
PARAMETERS: dict[str, tuple[Any, str, float | None, float | None]] = {
    "motor": (
        "seed000_ebike",
        "nominal motor (built-in name or YAML path) sizing the plan",
        None,
        None,
    ),
    "tau_m_s": (0.0, "rough mechanical time constant, s (0 = the nominal motor's)", 0.0, 1000.0),
    "rate_hz": (0.0, "driver sample rate, Hz (0 = read from the driver)", 0.0, 20000.0),
    "driver_node": (
        "driver_node",
        "driver node name (its limits are read before anything moves)",
        None,
        None,
    ),
    "driver_wait_s": (20.0, "how long to wait for the driver, s", 0.1, 600.0),
    "voltage_max_v": (
        0.0,
        "voltage the fractions refer to, V (0 = the driver's limit)",
        0.0,
        10000.0,
    ),
    "safe_mode": (
        "zero",
        "safe state on abort/end: 'open' (armature open) or 'zero' (0 V)",
        None,
        None,
    ),
    "safety.current_max_a": (
        0.0,
        "abort above this |current|, A (0 = 90 % of the driver's)",
        0.0,
        1e5,
    ),
    "safety.speed_max_rad_s": (
        0.0,
        "abort above this |speed|, rad/s (0 = 90 % of the driver's)",
        0.0,
        1e6,
    ),
    "safety.stall_current_a": (
        0.0,
        "stall: |current| above this, A (0 = half the current abort)",
        0.0,
        1e5,
    ),
    "safety.stall_speed_rad_s": (1.0, "stall: while |speed| below this, rad/s", 0.0, 1e4),
    "safety.stall_time_s": (0.0, "stall: for this long, s (0 = 3 tau_m)", 0.0, 60.0),
    "safety.data_timeout_s": (
        0.5,
        "abort when no driver sample came for this long, s",
        0.01,
        60.0,
    ),
    "max_start_latency_s": (
        0.05,
        "start only once driver samples arrive within this of their stamp, s",
        0.001,
        10.0,
    ),
    "settle_s": (1.0, "driver samples must arrive on time this long before a start, s", 0.0, 60.0),
    "confirm_timeout_s": (
        3.0,
        "after an abort, resend the safe command until the driver reports it, s",
        0.1,
        60.0,
    ),
    "require_recorder": (True, "wait for the recorder and abort if it disappears", None, None),
    "peer_timeout_s": (1.5, "recorder heartbeat timeout, s", 0.1, 60.0),
    "autostart": (True, "start a session as soon as the driver is up", None, None),
    "exit_when_done": (False, "exit after one session (bring-up uses this)", None, None),
    "output_dir": ("pmdc_sessions", "where results go when no recorder names a bag", None, None),
    "fix": (
        [""],
        "identification: fixed values NAME=VALUE (as pmdc-ident identify --fix)",
        None,
        None,
    ),
    "session_name": ("", "name of the next session (default: session_<UTC time>)", None, None),
}


class Phase(enum.Enum):
    IDLE = "idle"
    PREPARING = "preparing"  # waiting for the driver, its limits and the recorder
    RUNNING = "running"
    FLUSHING = "flushing"  # session over: waiting for the last samples
    IDENTIFYING = "identifying"
    FINISHED = "finished"


class _Columns:
    """Preallocated, growing numpy columns (stamp ns + values) for one topic."""

    def __init__(self, n_values: int, capacity: int = 65536) -> None:
        self.ns = np.zeros(capacity, dtype=np.int64)
        self.v = np.zeros((capacity, n_values))
        self.n = 0

    def clear(self) -> None:
        self.n = 0

    def append(self, ns: int, *values: float) -> None:
        if self.n >= self.ns.size:
            self.ns = np.concatenate([self.ns, np.zeros_like(self.ns)])
            self.v = np.concatenate([self.v, np.zeros_like(self.v)])
        self.ns[self.n] = ns
        self.v[self.n] = values
        self.n += 1

    def last_ns(self) -> int:
        return int(self.ns[self.n - 1]) if self.n else -1


def _descriptor(
    desc: str, default: Any, lo: float | None, hi: float | None
) -> ParameterDescriptor:
    d = ParameterDescriptor(description=desc, read_only=True)
    if lo is not None and hi is not None and not isinstance(default, bool):
        if isinstance(default, float):
            d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
        elif isinstance(default, int):
            d.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=1)]
    return d


class IdentificationNode(Node):
    """Thin ROS layer over :class:`Session`; see the module docs for the graph."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._declare()
        p = self._p
        self.nominal: MotorSpec = self._load_nominal(p("motor"))
        self.seq_config = self._dataclass_from_params(SequenceConfig, "sequence.")
        self.steady_config = self._dataclass_from_params(SteadyStateConfig, "steady_state.")
        modes = tuple(m.value for m in SafeMode)
        if p("safe_mode") not in modes:
            msg = f"parameter safe_mode must be one of {', '.join(modes)}, got {p('safe_mode')!r}"
            raise PmdcError(msg)
        self.safe_mode = SafeMode(p("safe_mode"))
        try:
            self.fixed = parse_fix([s for s in p("fix") if s])
        except PmdcError as exc:
            raise PmdcError(f"parameter fix: {exc}") from None
        self.finished = False
        self.exit_code = 0
        self.stop_requested: AbortReason | None = None
        self.phase = Phase.IDLE
        self.session: Session | None = None
        self.result_json: str | None = None
        self._prep_deadline = 0.0
        self._driver_params: dict[str, Any] | None = None
        self._param_future: Any = None
        self._armature_open = False
        self._last_progress = 0.0
        self._flush_deadline = 0.0
        self._recorder_seen = -math.inf
        self._recorder_receiving = False  # the recorder has driver samples on every topic
        self._recorder_paths: dict[str, str] = {}
        self._session_count = 0
        self._worker: threading.Thread | None = None

        self._cur = _Columns(1)
        self._enc = _Columns(2)
        self._volt = _Columns(2)
        self._last_current = 0.0
        self._last_sample_wall = -math.inf
        self._last_lag_ns = 0
        self._lag_base_ns = 2**62
        self._settled_since = math.inf
        self._last_tick = time.monotonic()
        self._confirm_after_ns: int | None = None
        self._confirm_deadline = 0.0
        self._confirm_sent = 0.0
        self.safe_confirmed = False
        self._last_enc_ns_seen = 0
        self._suspect_until = 0.0
        self._max_lag_ns = int(float(p("safety.data_timeout_s")) * 1e9)
        self._lag = _Columns(0)  # receive time - driver stamp, ns (latency report)
        self._last_cmd_v = math.nan
        self._last_cmd_wall = -math.inf

        self.pub_cmd = self.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
        self.pub_segment = self.create_publisher(String, "segment", SEGMENT_QOS)
        self.pub_progress = self.create_publisher(String, "progress", LATCHED_QOS)
        self.pub_status = self.create_publisher(String, "status", LATCHED_QOS)
        self.pub_result = self.create_publisher(String, "identified_parameters", LATCHED_QOS)
        self.open_client = self.create_client(Trigger, "open_armature")
        self.param_client = AsyncParameterClient(self, p("driver_node"))
        self.create_service(Trigger, "run_session", self._on_run_session)
        self.create_service(Trigger, "abort_session", self._on_abort_session)
        self.create_subscription(String, "recorder_status", self._on_recorder, LATCHED_QOS)
        self._subscribe_samples(float(p("rate_hz")) or 1000.0)
        self.create_timer(0.02, self._on_timer)
        self._publish_status("idle")
        self.get_logger().info(
            f"identification ready: nominal motor {self.nominal.name}, safe mode "
            f"{self.safe_mode.value}, fixed {self.fixed or 'none'}"
        )
        if p("autostart"):
            self.request_session()

    # -- parameters -------------------------------------------------------------------------
    def _p(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _declare(self) -> None:
        table = dict(PARAMETERS)
        for prefix, cls in (("sequence.", SequenceConfig), ("steady_state.", SteadyStateConfig)):
            for f in fields(cls):
                default = getattr(cls(), f.name)
                if isinstance(default, tuple):
                    default = [int(x) for x in default]
                table[prefix + f.name] = (
                    default,
                    f"{cls.__name__}.{f.name} (see the core docs)",
                    None,
                    None,
                )
        for name, (default, desc, lo, hi) in table.items():
            try:
                self.declare_parameter(name, default, _descriptor(desc, default, lo, hi))
            except Exception as exc:  # rclpy raises several types for a bad override
                text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                raise PmdcError(f"parameter {name}: {text} ({desc})") from None

    def _dataclass_from_params(self, cls: Any, prefix: str) -> Any:
        kwargs = {}
        for f in fields(cls):
            v = self._p(prefix + f.name)
            if isinstance(getattr(cls(), f.name), tuple):
                v = tuple(int(x) for x in v)
            kwargs[f.name] = v
        try:
            return cls(**kwargs)
        except (PmdcError, TypeError) as exc:
            raise PmdcError(f"parameters {prefix}*: {exc}") from None

    def _load_nominal(self, motor: str) -> MotorSpec:
        try:
            return load_motor(motor)
        except PmdcError as exc:
            raise PmdcError(f"parameter motor: {exc}") from None

    # -- subscriptions ---------------------------------------------------------------------
    def _subscribe_samples(self, rate_hz: float) -> None:
        qos = sample_qos(max(rate_hz, 1000.0))
        self.create_subscription(JointState, "current", self._on_current, qos, raw=True)
        self.create_subscription(JointState, "encoder", self._on_encoder, qos, raw=True)
        self.create_subscription(JointState, "voltage_applied", self._on_voltage, qos, raw=True)

    def _recording(self) -> bool:
        return self.phase in (Phase.RUNNING, Phase.FLUSHING)

    # Raw subscriptions: the CDR bytes are decoded by parse_joint_state, no message objects.
    def _on_current(self, raw: bytes) -> None:
        ns, _, _, i, _ = parse_joint_state(raw)
        self._last_current = i
        if self._recording():
            self._cur.append(ns, i)

    def _on_voltage(self, raw: bytes) -> None:
        if self._recording():
            ns, _, _, v, vt = parse_joint_state(raw)
            self._volt.append(ns, v, vt)
        elif self._confirm_after_ns is not None:
            ns, _, _, v, _ = parse_joint_state(raw)
            self._check_confirm(ns, v)

    def _on_encoder(self, raw: bytes) -> None:
        ns, pos, spd, _, _ = parse_joint_state(raw)
        wall = time.monotonic()
        self._last_sample_wall = wall
        self._last_enc_ns_seen = ns
        # Latency = arrival - stamp, less the smallest such difference seen: a board's
        # clock may be offset from this host's (a serial driver stamps on the board's
        # clock), and the transport delay is never negative.
        raw_lag = time.time_ns() - ns
        self._lag_base_ns = min(self._lag_base_ns, raw_lag)
        lag_ns = raw_lag - self._lag_base_ns
        self._last_lag_ns = lag_ns
        if not self._recording():
            return
        self._enc.append(ns, pos, spd)
        self._lag.append(lag_ns)
        if self.phase is Phase.RUNNING and self.session is not None:
            s = self.session
            if lag_ns > self._max_lag_ns:
                detail = f"driver samples arrive {lag_ns * 1e-9:.2f} s late: commands would be too"
                self._apply(s.abort(AbortReason.LOST_DRIVER_DATA, ns * 1e-9, detail))
                return
            self._apply(s.on_sample(ns * 1e-9, self._last_current, spd, wall))

    def _on_recorder(self, msg: String) -> None:
        self._recorder_seen = time.monotonic()
        try:
            d = json.loads(msg.data)
        except ValueError:
            return
        if d.get("session") and d.get("path"):
            self._recorder_paths[str(d["session"])] = str(d["path"])
        got = d.get("receiving") or {}
        self._recorder_receiving = len(got) == 3 and min(got.values()) >= 0

    # -- commands to the driver ---------------------------------------------------------------
    def _apply(self, step: SessionStep) -> None:
        for m in step.markers:
            self.pub_segment.publish(String(data=m.to_json()))
        cmd = step.command
        if cmd is not None:
            if cmd.open_armature:
                if not self._armature_open:
                    self._open_armature()
            else:
                # publish on change, and every 0.1 s so the driver's watchdog stays fed
                now = time.monotonic()
                if (
                    cmd.voltage_v != self._last_cmd_v
                    or self._armature_open
                    or now - self._last_cmd_wall > 0.1
                ):
                    self._armature_open = False
                    self._send(cmd.voltage_v, now)
        if step.abort_reason is not None:
            self._on_aborted()
        elif self.session is not None and self.session.state is SessionState.DONE:
            self._begin_flush()

    def _send(self, voltage_v: float, now: float | None = None) -> None:
        self.pub_cmd.publish(Float64(data=float(voltage_v)))
        self._last_cmd_v = voltage_v
        self._last_cmd_wall = time.monotonic() if now is None else now

    def _open_armature(self) -> None:
        self._armature_open = True
        if self.open_client.service_is_ready():
            self.open_client.call_async(Trigger.Request())
        else:
            # No service: 0 V is the other safe state (the driver's watchdog opens later).
            self._send(0.0)
            self.get_logger().warning("open_armature service not available: sent 0 V")

    def _make_safe(self) -> None:
        if self.safe_mode is SafeMode.OPEN:
            self._armature_open = False
            self._open_armature()
        else:
            self._send(0.0)

    # -- session control ----------------------------------------------------------------------
    def request_session(self) -> tuple[bool, str]:
        if self.phase in (Phase.PREPARING, Phase.RUNNING, Phase.FLUSHING, Phase.IDENTIFYING):
            return False, f"a session is {self.phase.value}"
        self.phase = Phase.PREPARING
        self._prep_deadline = time.monotonic() + float(self._p("driver_wait_s"))
        self._driver_params = None
        self._param_future = None
        self._settled_since = math.inf
        self._publish_status("preparing")
        return True, "session requested"

    def _on_run_session(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        resp.success, resp.message = self.request_session()
        return resp

    def _on_abort_session(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        if self.phase is Phase.RUNNING and self.session is not None:
            self._apply(self.session.abort(AbortReason.INTERRUPTED, None, "abort_session called"))
            resp.success, resp.message = True, "session aborted, motor safe"
        else:
            resp.success, resp.message = False, f"no session running ({self.phase.value})"
        return resp

    def _prepare(self) -> None:
        """Driver up, its limits read, recorder present: build and check the plan, start."""
        now = time.monotonic()
        if now > self._prep_deadline:
            waited = f"{self._p('driver_wait_s'):g} s"
            if self._driver_params is None:
                why = (
                    f"no driver node {self._p('driver_node')!r} answered within {waited} "
                    "(is it running, on this ROS_DOMAIN_ID?)"
                )
            elif now - self._last_sample_wall > 0.5:
                why = f"the driver sent no samples within {waited}"
            elif self._last_lag_ns > float(self._p("max_start_latency_s")) * 1e9:
                why = f"driver samples still arrive late after {waited}"
            elif now - self._recorder_seen <= float(self._p("peer_timeout_s")):
                why = f"the recorder received no driver samples within {waited}"
            else:
                why = (
                    f"no recorder within {waited} (start recorder_node, or run without "
                    "a bag: -p require_recorder:=false)"
                )
            self._fail(f"session not started, motor untouched: {why}")
            return
        if self._driver_params is None:
            if self._param_future is None:
                if not self.param_client.services_are_ready():
                    return
                self._param_future = self.param_client.get_parameters(
                    ["voltage_limit_v", "current_limit_a", "speed_limit_rad_s", "motor", "rate_hz"]
                )
                return
            if not self._param_future.done():
                return
            res = self._param_future.result()
            self._param_future = None
            if res is None or len(res.values) != 5:
                return
            names = ("voltage_limit_v", "current_limit_a", "speed_limit_rad_s", "motor", "rate_hz")
            vals = [
                v.double_value if v.type == 3 else (v.string_value if v.type == 4 else None)
                for v in res.values
            ]
            self._driver_params = dict(zip(names, vals, strict=True))
        if now - self._last_sample_wall > 0.5:
            return  # no driver samples yet
        if self._last_lag_ns > float(self._p("max_start_latency_s")) * 1e9:
            self._settled_since = math.inf  # still working through a backlog
            return
        # samples must have kept arriving on time for settle_s (the other processes are
        # done starting up), so the first commands are not late
        self._settled_since = min(self._settled_since, now)
        if now - self._settled_since < float(self._p("settle_s")):
            return
        if self._p("require_recorder") and (
            now - self._recorder_seen > float(self._p("peer_timeout_s"))
            or not self._recorder_receiving  # its subscriptions must match first: the
        ):  # driver's samples are volatile, so any it missed before would be lost
            return
        try:
            session = self._build_session()
        except PmdcError as exc:
            self._fail(str(exc))
            return
        for col in (self._cur, self._enc, self._volt, self._lag):
            col.clear()
        self.session = session
        self._armature_open = False
        session.start()
        self.phase = Phase.RUNNING
        self.get_logger().info(
            f"session {session.name}: {len(session.plan.segments)} segments, nominal "
            f"{session.plan.duration_s:.1f} s ({', '.join(session.plan_labels)})"
        )
        self._publish_status("running")

    def _driver_limits(self) -> tuple[Limits, float]:
        d = self._driver_params or {}
        try:
            spec = load_motor(d.get("motor") or self.nominal.name)
            base = spec.limits
        except PmdcError:
            base = self.nominal.limits
        limits = Limits(
            voltage_max_v=d.get("voltage_limit_v") or base.voltage_max_v,
            current_max_a=d.get("current_limit_a") or base.current_max_a,
            speed_max_rad_s=d.get("speed_limit_rad_s") or base.speed_max_rad_s,
        )
        rate = float(self._p("rate_hz") or d.get("rate_hz") or 1000.0)
        return limits, rate

    def _build_session(self) -> Session:
        driver, rate_hz = self._driver_limits()
        dt = 1.0 / rate_hz
        vmax = float(self._p("voltage_max_v")) or driver.voltage_max_v
        p = self.nominal.model.params
        tau = float(self._p("tau_m_s")) or p.mechanical_time_constant_s
        c_abort = float(self._p("safety.current_max_a")) or 0.9 * driver.current_max_a
        w_abort = float(self._p("safety.speed_max_rad_s")) or 0.9 * driver.speed_max_rad_s
        safety = SafetyConfig(
            current_max_a=c_abort,
            speed_max_rad_s=w_abort,
            stall_current_a=float(self._p("safety.stall_current_a")) or 0.5 * c_abort,
            stall_speed_rad_s=float(self._p("safety.stall_speed_rad_s")),
            stall_time_s=float(self._p("safety.stall_time_s")) or max(3.0 * tau, 0.05),
            data_timeout_s=float(self._p("safety.data_timeout_s")),
        )
        plan_limits = Limits(vmax, c_abort, w_abort)
        if self._p("tau_m_s"):
            plan = default_plan(dt, plan_limits, tau, self.seq_config)
        else:
            plan = plan_for_motor(replace(self.nominal, limits=plan_limits), dt, self.seq_config)
        problems = check_plan(
            plan, driver, safety, self.nominal if not self._p("tau_m_s") else None
        )
        if problems:
            raise PmdcError("plan refused before anything moved: " + "; ".join(problems))
        self._session_count += 1
        name = self._p("session_name") or (
            "session_" + datetime.now(UTC).strftime("%Y%m%d_%H%M%S")
        )
        if self._session_count > 1:
            name = f"{name}_{self._session_count}"
        return Session(
            plan,
            safety,
            tau_m_s=tau,
            steady=self.steady_config,
            safe_mode=self.safe_mode,
            name=name,
        )

    def _fail(self, text: str) -> None:
        self.get_logger().error(text)
        self.phase = Phase.FINISHED
        self.exit_code = 2
        self._publish_status("refused", detail=text)
        if self._p("exit_when_done"):
            self.finished = True
        else:
            self.phase = Phase.IDLE

    # -- timer: link checks, progress, end of session -----------------------------------------
    def _on_timer(self) -> None:
        now = time.monotonic()
        if now - self._last_tick > 0.1:
            # This node itself was held up (the timer is late): samples may be waiting
            # in its queue, so judge the driver's link only after they are processed.
            self._suspect_until = now + 0.05
        self._last_tick = now
        if self.stop_requested is not None:
            reason, self.stop_requested = self.stop_requested, None
            self._stop(reason)
            return
        if self.phase is Phase.PREPARING:
            self._prepare()
        elif self.phase is Phase.RUNNING and self.session is not None:
            if self._suspect_until > now:
                return
            step = self.session.check_link(now)
            if (
                step is None
                and self._p("require_recorder")
                and (now - self._recorder_seen > float(self._p("peer_timeout_s")))
            ):
                step = self.session.abort(
                    AbortReason.PEER_CRASHED, None, "recorder heartbeat lost: recorder gone"
                )
            if step is not None:
                self._apply(step)
            elif now - self._last_progress > 0.2:
                self._last_progress = now
                self.pub_progress.publish(String(data=self.session.progress().to_json()))
        elif self.phase is Phase.FLUSHING:
            self._maybe_identify(now)
        elif self.phase is Phase.FINISHED:
            if self.confirming:
                self._confirm_tick(now)
            elif self._worker is None or not self._worker.is_alive():
                self._worker = None
                if self._p("exit_when_done"):
                    self.finished = True
                else:
                    self.phase = Phase.IDLE

    def _stop(self, reason: AbortReason) -> None:
        """Ctrl-C / SIGTERM: abort a running session, make the motor safe, finish."""
        if self.phase is Phase.RUNNING and self.session is not None:
            self._apply(self.session.abort(reason, None, f"{reason.value} by signal"))
        else:
            self._make_safe()
            self.get_logger().warning(
                f"stopped by signal while {self.phase.value}: no session running, 0 V / open sent"
            )
            self._publish_status("stopped", reason=reason.value)
            self._start_confirm(self._last_enc_ns_seen)
        self.finished = True
        self.exit_code = 130

    def _on_aborted(self) -> None:
        s = self.session
        assert s is not None
        self._make_safe()
        reason = s.abort_reason.value if s.abort_reason else "?"
        self.get_logger().error(
            f"session {s.name} ABORTED ({reason}): {s.abort_detail}; safe command sent"
        )
        self.pub_progress.publish(String(data=s.progress().to_json()))
        self._publish_status("aborted", reason=s.abort_reason.value, detail=s.abort_detail)
        self.exit_code = EXIT_ABORTED
        self.phase = Phase.FINISHED
        self._start_confirm(round(s.markers[-1].t_s * 1e9))

    # -- confirming the safe state on the driver's own telemetry ------------------------------
    def _start_confirm(self, after_ns: int) -> None:
        """Watch voltage_applied until the driver shows 0 V or an open armature."""
        self._confirm_after_ns = after_ns
        self._confirm_deadline = time.monotonic() + float(self._p("confirm_timeout_s"))
        self._confirm_sent = time.monotonic()

    @property
    def confirming(self) -> bool:
        return self._confirm_after_ns is not None

    def _check_confirm(self, ns: int, v: float) -> None:
        if self._confirm_after_ns is not None and ns >= self._confirm_after_ns:
            if v == 0.0 or math.isnan(v):
                state = "armature open" if math.isnan(v) else "0 V applied"
                self.get_logger().info(f"motor confirmed safe by the driver: {state}")
                self._confirm_after_ns = None
                self.safe_confirmed = True

    def _confirm_tick(self, now: float) -> None:
        if now > self._confirm_deadline:
            self.get_logger().error(
                "could NOT confirm the safe state: the driver did not report 0 V or an open "
                f"armature within {self._p('confirm_timeout_s'):g} s (its watchdog opens it)"
            )
            self._confirm_after_ns = None
        elif now - self._confirm_sent > 0.1:
            self._confirm_sent = now
            self._make_safe()  # repeat: the first command may have been lost

    def _begin_flush(self) -> None:
        s = self.session
        assert s is not None
        self._make_safe()
        self.pub_progress.publish(String(data=s.progress().to_json()))
        self.phase = Phase.FLUSHING
        # every sample up to the end is on its way (reliable, 10 s deep): wait for it
        self._flush_deadline = time.monotonic() + SAMPLE_BUFFER_S + 5.0
        lag_ms = self._lag.ns[: self._lag.n] * 1e-6
        self.get_logger().info(
            f"session {s.name} complete: {s.progress().samples} samples; driver-to-node "
            f"latency median {np.median(lag_ms):.1f} ms, 99th percentile "
            f"{np.percentile(lag_ms, 99):.1f} ms, max {lag_ms.max():.1f} ms at sample "
            f"{int(np.argmax(lag_ms))}"
        )

    def _maybe_identify(self, now: float) -> None:
        s = self.session
        assert s is not None
        end_ns = round(s.markers[-1].t_s * 1e9)
        have = min(self._cur.last_ns(), self._volt.last_ns(), self._enc.last_ns())
        if have < end_ns and now < self._flush_deadline and now - self._last_sample_wall < 2.0:
            return  # still arriving (a backlog on a loaded machine); else the driver is gone
        arrays = DriverArrays(
            current_ns=self._cur.ns[: self._cur.n].copy(),
            current_a=self._cur.v[: self._cur.n, 0].copy(),
            encoder_ns=self._enc.ns[: self._enc.n].copy(),
            position_rad=self._enc.v[: self._enc.n, 0].copy(),
            speed_rad_s=self._enc.v[: self._enc.n, 1].copy(),
            voltage_ns=self._volt.ns[: self._volt.n].copy(),
            voltage_v=self._volt.v[: self._volt.n, 0].copy(),
            terminal_v=self._volt.v[: self._volt.n, 1].copy(),
            markers=list(s.markers),
        )
        if not np.isfinite(arrays.terminal_v).any():
            arrays.terminal_v = None
        self.phase = Phase.IDENTIFYING
        self._publish_status("identifying")
        self._worker = threading.Thread(target=self._identify, args=(arrays, s), daemon=True)
        self._worker.start()

    def _identify(self, arrays: DriverArrays, s: Session) -> None:
        log = self.get_logger()
        _normal_priority()  # the fit is batch work: never at the loop's real-time priority
        try:
            source = self._recorder_paths.get(s.name) or f"session {s.name}"
            run = assemble_run(arrays, source=source, session=s.name)
            n = sum(seg.n for seg in run.segments)
            out = self._output_dir(s.name)
            found = _completeness(arrays, s)
            (log.warning if found.missing else log.info)(f"session {s.name}: {found.line()}")
            result = identify_session_run(
                run, self.fixed, name=s.name, extra={"driver_samples": found.to_dict()}
            )
            out.mkdir(parents=True, exist_ok=True)
            (out / "parameters.json").write_text(result.json_text)
            (out / "parameters.yaml").write_text(result.yaml_text)
            self.result_json = result.json_text
            self.pub_result.publish(String(data=result.json_text))
            log.info(f"session {s.name}: identified from {n} samples\n{result.table}")
            self._publish_status("done", detail=f"{n} samples", results=str(out))
        except PmdcError as exc:
            log.error(f"session {s.name}: identification failed: {exc}")
            self._publish_status("failed", detail=str(exc))
            self.exit_code = 2
        except Exception as exc:  # noqa: BLE001 - report in one line, keep the node alive
            log.error(f"session {s.name}: identification failed: {exc!r}")
            self._publish_status("failed", detail=repr(exc))
            self.exit_code = 1
        self.phase = Phase.FINISHED

    def wait_delivered(self, timeout_s: float) -> bool:
        """Until every reader acknowledged our last command, markers, status and result.

        A reader whose receive thread was held up on a busy machine gets lost datagrams
        re-sent only while this node lives: a recorder must not miss the session's end.
        """
        end = time.monotonic() + timeout_s
        pubs = (self.pub_cmd, self.pub_segment, self.pub_status, self.pub_progress)
        done = True
        for pub in (*pubs, self.pub_result):
            left = max(0.0, end - time.monotonic())
            done = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and done
        return done

    def _output_dir(self, session: str) -> Path:
        path = self._recorder_paths.get(session)
        if path:
            return Path(path)
        return Path(self._p("output_dir")).expanduser() / session

    def _publish_status(self, state: str, **extra: str) -> None:
        d: dict[str, Any] = {"state": state, "session": self.session.name if self.session else ""}
        d.update(extra)
        if self.session is not None:
            d["bag"] = self._recorder_paths.get(self.session.name, "")
        self.pub_status.publish(String(data=json.dumps(d)))


def _normal_priority() -> None:
    """This thread back to the normal scheduler if the node runs real-time (bringup)."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


def _completeness(arrays: DriverArrays, s: Session) -> Completeness:
    """The session's driver samples this node received vs the stamp grid."""
    enc = np.unique(arrays.encoder_ns)
    dt_ns = int(np.median(np.diff(enc))) if enc.size > 2 else 1_000_000
    stamps = {
        "current": arrays.current_ns,
        "encoder": arrays.encoder_ns,
        "voltage_applied": arrays.voltage_ns,
    }
    return completeness(
        stamps, round(s.markers[0].t_s * 1e9), round(s.markers[-1].t_s * 1e9), dt_ns
    )


def make_executor() -> Executor:
    """rclpy's EventsExecutor where it exists (several times less overhead per message
    at 3 kHz of driver samples), else the SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    except ImportError:
        return SingleThreadedExecutor()


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node: IdentificationNode | None = None
    status = 0
    stop: list[AbortReason] = []

    def on_signal(signum: int, _frame: Any) -> None:
        stop.append(AbortReason.INTERRUPTED)
        if node is not None:
            node.stop_requested = AbortReason.INTERRUPTED

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        node = IdentificationNode()
        if stop:
            node.stop_requested = stop[0]
        executor = make_executor()
        executor.add_node(node)
        while rclpy.ok() and not node.finished:
            executor.spin_once(timeout_sec=0.05)
        # see the safe state confirmed by the driver (a Ctrl-C ends here)
        while rclpy.ok() and node.confirming:
            executor.spin_once(timeout_sec=0.02)
            if node.confirming:
                node._confirm_tick(time.monotonic())
        node.wait_delivered(timeout_s=5.0)
        status = node.exit_code
    except PmdcError as exc:
        print(f"{NODE_NAME}: {exc}", file=sys.stderr, flush=True)
        status = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
