"""Drift monitor node: is the running motor still the identified one?

Runs beside any controller. Subscribes to the driver's ``voltage_applied``,
``current`` and ``encoder`` (raw CDR, joined by stamp), feeds
:class:`~pmdc_ident.core.drift_monitor.DriftMonitor` (all the numerics) and
publishes:

* ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``, every
  ``diagnostics_period_s``): one status ``pmdc_ident: <node> motor drift``, level
  OK/WARN/ERROR, each quantity with its 95 % interval and unit in the key names;
* ``model_drift`` (``std_msgs/String``, JSON, every ``report_period_s``): time,
  level, estimates, intervals, identified values, thresholds;
* ``reidentify_suggested`` (``std_msgs/String``, JSON, latched: transient local,
  depth 1): published when the monitor latches a suggestion to re-identify and
  when ``reset_suggestion`` (``std_srvs/Trigger``) clears it.
"""

from __future__ import annotations

import json
import signal
import sys
from dataclasses import fields
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from std_srvs.srv import Trigger

from pmdc_ident.core.drift_monitor import DriftMonitor, DriftReport, MonitorConfig
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import load_motor
from pmdc_ident.core.stream_join import StampJoiner
from pmdc_ident.dataio.bagio import parse_joint_state

__all__ = ["PARAMETERS", "MonitorNode", "main"]

NODE_NAME = "monitor_node"

# name -> (default, description, lower, upper): the one declaration table of this node.
PARAMETERS: dict[str, tuple[Any, str, float | None, float | None]] = {
    "params": (
        "seed000_ebike",
        "identified motor YAML (`identify --yaml`) or built-in",
        None,
        None,
    ),
    "rate_hz": (1000.0, "driver sample rate, Hz (sizes the subscription queues)", 1.0, 1e5),
    "process_period_s": (0.02, "samples are fed to the monitor this often, s", 0.001, 1.0),
    "report_period_s": (0.1, "model_drift publishing period, s", 0.01, 10.0),
    "diagnostics_period_s": (1.0, "/diagnostics publishing period, s", 0.05, 60.0),
    "r_warn_rel": (0.10, "R rise for WARN, relative to the identified R", 0.0, 10.0),
    "r_error_rel": (0.20, "R rise for ERROR, relative", 0.0, 10.0),
    "ke_warn_rel": (0.05, "Ke change for WARN, relative", 0.0, 1.0),
    "ke_error_rel": (0.10, "Ke change for ERROR, relative", 0.0, 1.0),
    "friction_warn_nm": (0.0, "friction rise for WARN, N*m (0: identified friction)", 0.0, 1e4),
    "friction_error_nm": (0.0, "friction rise for ERROR, N*m (0: 3x the WARN step)", 0.0, 1e4),
    "delay_warn_s": (0.002, "delay change for WARN, s", 0.0, 1.0),
    "delay_error_s": (0.010, "delay change for ERROR, s", 0.0, 1.0),
    "hold_s": (1.0, "a higher level must be proven again this much later, s", 0.01, 600.0),
    "suggest_after_s": (30.0, "WARN this long latches the re-identify suggestion, s", 0.1, 1e5),
}
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def _descriptor(desc: str, default: Any, lo: float | None, hi: float | None) -> Any:
    d = ParameterDescriptor(description=desc, read_only=True)
    if lo is not None and hi is not None and isinstance(default, float):
        d.floating_point_range = [FloatingPointRange(from_value=lo, to_value=hi, step=0.0)]
    return d


def _sample_qos(rate_hz: float) -> QoSProfile:
    """Reliable, two seconds of samples deep (a held-up node loses nothing)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=max(10, int(2.0 * rate_hz)),
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


class MonitorNode(Node):
    """Thin ROS layer over :class:`DriftMonitor`."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        for name, (default, desc, lo, hi) in PARAMETERS.items():
            self.declare_parameter(name, default, _descriptor(desc, default, lo, hi))
        p = self._p
        try:
            spec = load_motor(p("params"))
        except PmdcError as exc:
            raise PmdcError(f"parameter params: {exc}") from None
        names = {f.name for f in fields(MonitorConfig)}
        try:
            config = MonitorConfig(**{k: float(p(k)) for k in PARAMETERS if k in names})
        except PmdcError as exc:
            raise PmdcError(f"parameters: {exc}") from None
        self.monitor = DriftMonitor(spec, config)
        self.joiner = StampJoiner(max_pending=int(2.0 * p("rate_hz")))
        self.latest: DriftReport | None = None
        self._suggested = False
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.pub_drift = self.create_publisher(String, "model_drift", 10)
        self.pub_suggest = self.create_publisher(String, "reidentify_suggested", LATCHED_QOS)
        qos = _sample_qos(float(p("rate_hz")))
        self.create_subscription(JointState, "voltage_applied", self._on_voltage, qos, raw=True)
        self.create_subscription(JointState, "current", self._on_current, qos, raw=True)
        self.create_subscription(JointState, "encoder", self._on_encoder, qos, raw=True)
        self.create_service(Trigger, "reset_suggestion", self._on_reset)
        self.create_timer(float(p("process_period_s")), self._on_process)
        self.create_timer(float(p("diagnostics_period_s")), self._on_diagnostics)
        self._publish_suggestion()
        self.get_logger().info(f"monitoring motor '{spec.name}' against {p('params')}")

    def _p(self, name: str) -> Any:
        return self.get_parameter(name).value

    # Raw subscriptions: CDR decoded by parse_joint_state, no message objects.
    def _on_voltage(self, raw: bytes) -> None:
        ns, _, _, v, _ = parse_joint_state(raw)
        self.joiner.add("voltage", ns, v)

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
        if self.monitor.suggest_reidentify != self._suggested:
            self._publish_suggestion()

    def _publish_suggestion(self) -> None:
        self._suggested = self.monitor.suggest_reidentify
        reason = self.latest.message if self.latest is not None and self._suggested else ""
        data = {"suggest_reidentify": self._suggested, "reason": reason}
        self.pub_suggest.publish(String(data=json.dumps(data)))

    def _on_reset(self, _req: Trigger.Request, resp: Trigger.Response) -> Trigger.Response:
        self.monitor.reset_suggestion()
        self._publish_suggestion()
        resp.success, resp.message = True, "re-identify suggestion cleared"
        return resp

    def _on_diagnostics(self) -> None:
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        arr.status = [diagnostic_status(self.get_fully_qualified_name(), self.latest, self)]
        self.pub_diag.publish(arr)


def drift_json(r: DriftReport) -> dict[str, Any]:
    """The ``model_drift`` message body."""
    return {
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


def diagnostic_status(name: str, r: DriftReport | None, node: MonitorNode) -> DiagnosticStatus:
    st = DiagnosticStatus(name=f"pmdc_ident: {name} motor drift", hardware_id="pmdc_motor")
    if r is None:
        st.level = DiagnosticStatus.STALE
        st.message = "no driver samples yet"
        return st
    st.level = bytes([int(r.level)])
    st.message = r.message
    values = [("temperature_rise_k", r.temperature_rise_k), ("t_s", r.t_s)]
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


def _executor() -> Any:
    """rclpy's EventsExecutor where it exists (several times less overhead per message
    at 3 kHz of driver samples), else the SingleThreadedExecutor."""
    try:
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    except ImportError:
        from rclpy.executors import SingleThreadedExecutor

        return SingleThreadedExecutor()


def main(args: list[str] | None = None) -> int:
    # Own signal handling: SIGINT/SIGTERM end the spin loop below (the EventsExecutor's
    # spin() does not return on rclpy's default handlers).
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop: list[int] = []
    signal.signal(signal.SIGINT, lambda signum, _frame: stop.append(signum))
    signal.signal(signal.SIGTERM, lambda signum, _frame: stop.append(signum))
    node: MonitorNode | None = None
    status = 0
    try:
        node = MonitorNode()
        executor = _executor()
        executor.add_node(node)
        while rclpy.ok() and not stop:
            executor.spin_once(timeout_sec=0.05)
    except PmdcError as exc:
        print(f"{NODE_NAME}: {exc}", file=sys.stderr, flush=True)
        status = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
