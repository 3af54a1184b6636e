"""Drift monitor node: is the running motor still the identified one?

Runs beside any controller. Subscribes to the driver's ``voltage_applied``,
``current`` and ``encoder`` (raw CDR, joined by stamp), feeds
:class:`~pmdc_ident.node_logic.drift_monitor.DriftMonitor` (all the numerics) and
publishes:

* ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, every
  ``diagnostics_period_s``): one status ``<namespace>/monitor_node: motor drift``
  (:mod:`pmdc_ident.process.diagnostics`), hardware id ``pmdc_motor<namespace>`` (or
  the ``hardware_id`` parameter), level OK/WARN/ERROR, or STALE when no driver sample
  came for ``stale_s``; each quantity with its 95 % interval and unit in the key
  names; every level change is logged once;
* ``model_drift`` (``std_msgs/String``, JSON, every ``report_period_s``): time,
  level, estimates, intervals, identified values, thresholds; and each quantity as a
  plottable ``std_msgs/Float64MultiArray`` on ``model_drift/<quantity>``
  (:mod:`pmdc_ident.nodes.result_topics`);
* ``reidentify_suggested`` (``std_msgs/String``, JSON, latched: transient local,
  depth 1): published when the monitor latches a suggestion to re-identify and
  when ``reset_suggestion`` (``std_srvs/Trigger``) clears it; the reset also starts
  the estimates over, so only new evidence latches it again.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import fields
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import load_motor
from pmdc_ident.core.schema import SCHEMA_VERSION
from pmdc_ident.core.stream_join import StampJoiner
from pmdc_ident.dataio.bagio import parse_joint_state
from pmdc_ident.node_logic.drift_monitor import (
    DriftMonitor,
    DriftReport,
    MonitorConfig,
    diagnostic_status,
)
from pmdc_ident.nodes.parameters import declare
from pmdc_ident.nodes.qos import COMMAND_QOS, DIAGNOSTICS_QOS, LATCHED_QOS, sample_qos
from pmdc_ident.nodes.result_topics import NumericTopic, array_message, drift_topics
from pmdc_ident.nodes.runtime import log as node_log
from pmdc_ident.nodes.runtime import run_node
from pmdc_ident.process.diagnostics import LevelLog, hardware_id, status_name
from pmdc_ident.process.parameter_tables import MONITOR

__all__ = ["MonitorNode", "main"]

NODE_NAME = "monitor_node"


class MonitorNode(Node):
    """Thin ROS layer over :class:`DriftMonitor`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare(self, MONITOR)
        self.finished = False  # a signal arrived
        self.exit_code: int = ExitCode.OK

        def p(name: str) -> Any:
            return values[name]

        try:
            spec = load_motor(p("params"))
        except PmdcError as exc:
            raise PmdcError(f"parameter params: {exc}") from None
        names = {f.name for f in fields(MonitorConfig)}
        try:
            config = MonitorConfig(**{k: float(p(k)) for k in MONITOR.names if k in names})
        except PmdcError as exc:
            raise PmdcError(f"parameters: {exc}") from None
        self.monitor = DriftMonitor(spec, config)
        self.joiner = StampJoiner(max_pending=int(2.0 * p("rate_hz")))
        self.latest: DriftReport | None = None
        self._suggested = False
        self._stale_s = float(p("stale_s"))
        self._last_sample_s: float | None = None  # host clock of the last driver sample
        self._hardware_id = hardware_id(self.get_namespace(), str(p("hardware_id")))
        self._levels = LevelLog("motor drift")
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self.pub_drift = self.create_publisher(String, "model_drift", COMMAND_QOS)
        self._pub_arrays: dict[str, Any] = {}  # model_drift/<quantity> -> publisher
        self.pub_suggest = self.create_publisher(String, "reidentify_suggested", LATCHED_QOS)
        qos = sample_qos(float(p("rate_hz")), seconds=2.0)
        self.create_subscription(JointState, "voltage_applied", self._on_voltage, qos, raw=True)
        self.create_subscription(JointState, "current", self._on_current, qos, raw=True)
        self.create_subscription(JointState, "encoder", self._on_encoder, qos, raw=True)
        self.create_service(Trigger, "reset_suggestion", self._on_reset)
        self.create_timer(float(p("process_period_s")), self._on_process)
        self.create_timer(float(p("diagnostics_period_s")), self._on_diagnostics)
        self._publish_suggestion()
        self.get_logger().info(f"monitoring motor '{spec.name}' against {p('params')}")

    # -- ManagedNode (pmdc_ident.nodes.runtime) ---------------------------------------------
    def request_stop(self) -> None:
        self.finished = True

    def wind_down(self, spin_once: Any) -> None:
        """Nothing to finish."""

    def close(self) -> list[str]:
        return []

    # Raw subscriptions: CDR decoded by parse_joint_state, no message objects.
    def _on_voltage(self, raw: bytes) -> None:
        ns, _, _, v, _ = parse_joint_state(raw)
        self.joiner.add("voltage", ns, v)
        self._last_sample_s = time.monotonic()

    def _on_current(self, raw: bytes) -> None:
        ns, _, _, i, _ = parse_joint_state(raw)
        self.joiner.add("current", ns, i)

    def _on_encoder(self, raw: bytes) -> None:
        ns, _, w, _, _ = parse_joint_state(raw)
        self.joiner.add("speed", ns, w)

    def _on_process(self) -> None:
        t, v, i, w = self.joiner.take()
        if not t.size:
            return
        for report in self.monitor.process(t, v, i, w):
            self.latest = report
            self.pub_drift.publish(String(data=json.dumps(drift_json(report))))
            for topic in drift_topics(report):
                self._publish_array(topic)
        if self.monitor.suggest_reidentify != self._suggested:
            self._publish_suggestion()

    def _publish_suggestion(self) -> None:
        self._suggested = self.monitor.suggest_reidentify
        reason = self.latest.message if self.latest is not None and self._suggested else ""
        data = {
            "schema_version": SCHEMA_VERSION,
            "suggest_reidentify": self._suggested,
            "reason": reason,
        }
        self.pub_suggest.publish(String(data=json.dumps(data)))

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.monitor.reset_suggestion()
        self._publish_suggestion()
        resp.success, resp.message = True, "re-identify suggestion cleared"
        return resp

    def _publish_array(self, topic: NumericTopic) -> None:
        pub = self._pub_arrays.get(topic.topic)
        if pub is None:
            pub = self.create_publisher(Float64MultiArray, topic.topic, COMMAND_QOS)
            self._pub_arrays[topic.topic] = pub
        pub.publish(array_message(topic))

    def _on_diagnostics(self) -> None:
        since = None if self._last_sample_s is None else time.monotonic() - self._last_sample_s
        level, message = diagnostic_status(self.latest, since, self._stale_s)
        change = self._levels.update(level, message)
        if change is not None:
            node_log(self, *change)
        st = monitor_status(self.latest, level, message, self)
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [st]
        self.pub_diag.publish(arr)


def drift_json(r: DriftReport) -> dict[str, Any]:
    """The ``model_drift`` message body."""
    return {
        "schema_version": SCHEMA_VERSION,
        "t_s": r.t_s,
        "level": r.level.name,
        "suggest_reidentify": r.suggest_reidentify,
        "temperature_rise_k": r.temperature_rise_k,
        "temperature_rise_ci95_k": r.temperature_ci95_k,
        "quantities": {
            q.name: {
                "value": q.value,
                "ci95": q.ci95,
                "unit": q.unit,
                "identified": q.reference,
                "warn": q.warn,
                "error": q.error,
                "level": q.level.name,
                "excited": q.excited,
            }
            for q in r.quantities
        },
        "message": r.message,
    }


def monitor_status(
    r: DriftReport | None, level: int, message: str, node: MonitorNode
) -> DiagnosticStatus:
    """The ``/diagnostics`` status: ``level`` and ``message`` (:func:`diagnostic_status`),
    the last report's values (``t_s`` = its driver time, seconds since the epoch)."""
    st = DiagnosticStatus(
        name=status_name(node.get_fully_qualified_name(), "motor drift"),
        hardware_id=node._hardware_id,
        level=bytes([level]),
        message=message,
    )
    if r is None:
        return st
    values: list[tuple[str, Any]] = [
        ("temperature_rise_k", r.temperature_rise_k),
        ("t_s", f"{r.t_s:.3f}"),
    ]
    for q in r.quantities:
        unit = q.unit.replace("*", "_").replace("/", "_per_").replace("^", "")
        values += [(f"{q.name}_{unit}", q.value), (f"{q.name}_ci95_{unit}", q.ci95)]
        values += [(f"{q.name}_level", q.level.name)]
    values.append(("suggest_reidentify", str(r.suggest_reidentify).lower()))
    values.append(("samples_dropped", node.joiner.dropped))
    st.values = [
        KeyValue(key=k, value=f"{v:.6g}" if isinstance(v, float) else str(v)) for k, v in values
    ]
    return st


def main(args: list[str] | None = None) -> int:
    return run_node(NODE_NAME, MonitorNode, args)


if __name__ == "__main__":
    sys.exit(main())
