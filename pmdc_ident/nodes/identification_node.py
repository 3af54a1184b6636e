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
``identified_parameters/   std_msgs/Float64MultiArray    one per parameter, latched: value, 95 %
<name>``                                                 interval, stderr, identifiable (plottable;
                                                         :mod:`pmdc_ident.nodes.result_topics`)
``run_session``            std_srvs/srv/Trigger          start a session on demand
``abort_session``          std_srvs/srv/Trigger          stop the running session, motor safe
``recorder_status``        std_msgs/msg/String           the recorder's heartbeat and bag path
=========================  ============================  =========================================

The node only wires: every decision is
:class:`pmdc_ident.node_logic.session.controller.SessionController` (start-up, safety
defaults, latency, publish policy, confirming the safe state), which this node feeds
with its callbacks and which publishes through the methods below. Parameters are
declared from :data:`pmdc_ident.process.parameter_tables.IDENTIFICATION`; QoS profiles
come from :mod:`pmdc_ident.nodes.qos`. The finished session is identified in a child
process (:class:`~pmdc_ident.process.identify_call.IdentificationWorker`, started and
warmed up when the session starts) with the same function and options as
``pmdc-ident identify``.
"""

from __future__ import annotations

import json
import sys
import time
from collections.abc import Callable
from typing import Any

from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray, String
from std_srvs.srv import Trigger

from pmdc_ident.core.enums import ExitCode, LogLevel
from pmdc_ident.core.motors import MotorSpec
from pmdc_ident.dataio.bagio import parse_joint_state
from pmdc_ident.node_logic.session.controller import Phase, SessionController
from pmdc_ident.node_logic.session.ports import IdentificationJob
from pmdc_ident.node_logic.session.sequential import DesignOutcome
from pmdc_ident.nodes.parameters import declare
from pmdc_ident.nodes.qos import (
    COMMAND_QOS,
    LATCHED_QOS,
    SEGMENT_QOS,
    sample_qos,
)
from pmdc_ident.nodes.result_topics import array_message, parameter_topics
from pmdc_ident.nodes.runtime import log as node_log
from pmdc_ident.nodes.runtime import run_node
from pmdc_ident.process.identify_call import IdentificationWorker
from pmdc_ident.process.parameter_tables import IDENTIFICATION
from pmdc_ident.process.settings import controller_config

__all__ = ["IdentificationNode", "main"]

NODE_NAME = "identification_node"
TICK_S = 0.02
DELIVERY_TIMEOUT_S = 5.0
# A reader that started before this node gets its latched status and result only once
# the two have discovered each other, which takes seconds on a busy machine: a node
# that refuses its plan at once (1.3 s after start under load, before a waiting
# monitor had matched it) lives at least this long, so the refusal is not lost.
MIN_LIFE_S = 4.0


class IdentificationNode(Node):
    """Wires :class:`SessionController` to ROS; see the module docs for the graph."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        self._built_s = time.monotonic()
        values = declare(self, IDENTIFICATION)
        config = controller_config(values, namespace=self.get_namespace())
        self.controller = SessionController(config, ports=self)
        self.exit_code: int = ExitCode.OK
        self._worker: IdentificationWorker | None = None
        self._param_future: Any = None
        self._param_names: tuple[str, ...] = ()
        self.pub_cmd = self.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
        self.pub_segment = self.create_publisher(String, "segment", SEGMENT_QOS)
        self.pub_progress = self.create_publisher(String, "progress", LATCHED_QOS)
        self.pub_status = self.create_publisher(String, "status", LATCHED_QOS)
        self.pub_result = self.create_publisher(String, "identified_parameters", LATCHED_QOS)
        self._pub_arrays: dict[str, Any] = {}  # identified_parameters/<name> -> publisher
        self.open_client = self.create_client(Trigger, "open_armature")
        self.param_client = AsyncParameterClient(self, str(values["driver_node"]))
        self.create_service(Trigger, "run_session", self._on_run_session)
        self.create_service(Trigger, "abort_session", self._on_abort_session)
        self.create_subscription(String, "recorder_status", self._on_recorder, LATCHED_QOS)
        qos = sample_qos(max(float(values["rate_hz"]) or 1000.0, 1000.0))
        self.create_subscription(JointState, "current", self._on_current, qos, raw=True)
        self.create_subscription(JointState, "encoder", self._on_encoder, qos, raw=True)
        self.create_subscription(JointState, "voltage_applied", self._on_voltage, qos, raw=True)
        self.create_timer(TICK_S, self._on_timer)
        self.controller.start(bool(values["autostart"]), time.monotonic())

    # -- ManagedNode (pmdc_ident.nodes.runtime) ---------------------------------------------
    @property
    def finished(self) -> bool:
        return self.controller.finished

    def request_stop(self) -> None:
        self.controller.request_stop()

    def wind_down(self, spin_once: Callable[[float], None]) -> None:
        """See the safe state confirmed by the driver, then let every reader have our last
        command, markers, status and result (a Ctrl-C ends here too)."""
        self._stop_idle_worker()
        while self.controller.confirming:
            spin_once(0.02)
            self.controller.confirm_tick(time.monotonic())
        while time.monotonic() - self._built_s < MIN_LIFE_S:
            spin_once(0.05)  # readers still discovering us (see MIN_LIFE_S)
        self.wait_delivered(DELIVERY_TIMEOUT_S)
        self.exit_code = self.controller.exit_code

    def _stop_idle_worker(self) -> None:
        """A session that ended without an identification to run (aborted, refused, or
        its result already out) leaves its worker warming up or idle: stopped now, not
        after the wind-down, where its warm-up would take ~2 s of CPU for nothing. A
        worker with a job (a stop while identifying) is left to it, as before."""
        done = self.controller.phase in (Phase.FINISHED, Phase.IDLE)
        if done and self._worker is not None and not self._worker.busy:
            self._worker.terminate()
            self._worker = None

    def close(self) -> list[str]:
        if self._worker is not None:
            self._worker.terminate()
        return []

    def wait_delivered(self, timeout_s: float) -> bool:
        """Until every reader acknowledged our last command, markers, status and result.

        A reader whose receive thread was held up on a busy machine gets lost datagrams
        re-sent only while this node lives: a recorder must not miss the session's end.
        """
        end = time.monotonic() + timeout_s
        done = True
        for pub in (self.pub_cmd, self.pub_segment, self.pub_status, self.pub_progress):
            left = max(0.0, end - time.monotonic())
            done = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and done
        # the typed result topics are made when the result comes: a reader known to the
        # graph may not be matched to them yet, and would miss the value if we left now
        pubs = [self.pub_result, *self._pub_arrays.values()]
        while time.monotonic() < end and any(
            p.get_subscription_count() < self.count_subscribers(p.topic_name) for p in pubs
        ):
            time.sleep(0.02)
        for pub in pubs:
            left = max(0.0, end - time.monotonic())
            done = pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))) and done
        return done

    # -- callbacks -> controller --------------------------------------------------------------
    # Raw subscriptions: the CDR bytes are decoded by parse_joint_state, no message objects.
    def _on_current(self, raw: bytes) -> None:
        ns, _, _, i, _ = parse_joint_state(raw)
        self.controller.on_current(ns, i)

    def _on_voltage(self, raw: bytes) -> None:
        ns, _, _, v, vt = parse_joint_state(raw)
        self.controller.on_voltage(ns, v, vt)

    def _on_encoder(self, raw: bytes) -> None:
        ns, pos, spd, _, _ = parse_joint_state(raw)
        self.controller.on_encoder(ns, pos, spd, time.monotonic(), time.time_ns())

    def _on_recorder(self, msg: String) -> None:
        self.controller.on_recorder_status(msg.data, time.monotonic())

    def _on_run_session(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        resp.success, resp.message = self.controller.request_session(time.monotonic())
        return resp

    def _on_abort_session(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        resp.success, resp.message = self.controller.abort_session(time.monotonic())
        return resp

    def _on_timer(self) -> None:
        self._collect_driver_parameters()
        if self._worker is not None:
            outcome = self._worker.poll()
            if isinstance(outcome, DesignOutcome):
                self.controller.on_design(outcome, time.monotonic())
            elif outcome is not None and self.controller.design_pending:
                # the worker died under a plan: auto re-fit: end the session safely
                stop = DesignOutcome("stop", message=f"re-fit failed: {outcome.error}")
                self.controller.on_design(stop, time.monotonic())
            elif outcome is not None:
                self.controller.on_identified(outcome)
        self.controller.tick(time.monotonic())

    def _collect_driver_parameters(self) -> None:
        fut = self._param_future
        if fut is None or not fut.done():
            return
        self._param_future = None
        res = fut.result()
        names = self._param_names
        if res is None or len(res.values) != len(names):
            self.controller.on_driver_parameters(None)
            return
        values = [parameter_value_to_python(v) for v in res.values]
        self.controller.on_driver_parameters(dict(zip(names, values, strict=True)))

    # -- controller -> ROS (ControllerPorts) -------------------------------------------------
    def send_voltage(self, voltage_v: float) -> None:
        self.pub_cmd.publish(Float64(data=float(voltage_v)))

    def open_armature(self) -> bool:
        if not self.open_client.service_is_ready():
            return False
        self.open_client.call_async(Trigger.Request())
        return True

    def publish_marker(self, text: str) -> None:
        self.pub_segment.publish(String(data=text))

    def publish_progress(self, text: str) -> None:
        self.pub_progress.publish(String(data=text))

    def publish_status(self, text: str) -> None:
        self.pub_status.publish(String(data=text))

    def publish_result(self, text: str) -> None:
        self.pub_result.publish(String(data=text))
        topics = {t.topic: t for t in parameter_topics(json.loads(text))}
        for name, pub in self._pub_arrays.items():
            if name not in topics:  # a parameter this model does not have: no value now
                pub.publish(Float64MultiArray(data=[float("nan")] * 5))
        for t in topics.values():
            pub = self._pub_arrays.get(t.topic)
            if pub is None:
                pub = self.create_publisher(Float64MultiArray, t.topic, LATCHED_QOS)
                self._pub_arrays[t.topic] = pub
            pub.publish(array_message(t))

    def request_driver_parameters(self, names: tuple[str, ...]) -> bool:
        if self._param_future is not None or not self.param_client.services_are_ready():
            return False
        self._param_future = self.param_client.get_parameters(list(names))
        self._param_names = names
        return True

    def prepare_identification(self, nominal: MotorSpec | None) -> None:
        if self._worker is None or not self._worker.alive:
            self._worker = IdentificationWorker(nominal)

    def start_design(self, job: object) -> None:
        if self._worker is None or not self._worker.alive:
            self._worker = IdentificationWorker()
        self._worker.submit(job)  # type: ignore[arg-type]

    def start_identification(self, job: IdentificationJob) -> None:
        if self._worker is None or not self._worker.alive:
            self._worker = IdentificationWorker()
        self._worker.submit(job)

    def log(self, level: LogLevel, text: str) -> None:
        node_log(self, level, text)


def main(args: list[str] | None = None) -> int:
    return run_node(NODE_NAME, IdentificationNode, args, realtime=True)


if __name__ == "__main__":
    sys.exit(main())
