"""The motor driver node: a thin ROS 2 layer over a motor backend (simulated or serial).

Graph (names relative, so namespaces and remaps work):

=====================  ===============================  =========================================
name                   type                             meaning
=====================  ===============================  =========================================
``voltage_cmd``        std_msgs/msg/Float64 (sub)       commanded armature voltage, V
``open_armature``      std_srvs/srv/Trigger (service)   open the winding (coast-down); the next
                                                        valid ``voltage_cmd`` closes it again
``reset_faults``       std_srvs/srv/Trigger (service)   clear a latched over-current/speed trip
``current``            sensor_msgs/msg/JointState       ``name [joint]``, ``effort`` [A]
``encoder``            sensor_msgs/msg/JointState       ``name [joint]``, ``position`` [rad],
                                                        ``velocity`` [rad/s]
``voltage_applied``    sensor_msgs/msg/JointState       ``name [joint(, joint_terminal)]``,
                                                        ``effort`` [command V, NaN while open
                                                        (, measured terminal V)]
``/diagnostics``       diagnostic_msgs/DiagnosticArray  1 Hz status of the driver
=====================  ===============================  =========================================

``joint`` is the ``joint_name`` parameter (``motor_joint``, the exports' default joint).
One message of each sample topic per backend sample, all three with the same
``header.stamp``: the backend's sample time since its start plus the ROS time
at which it started, so stamps are comparable to ROS time and exactly on the
sample grid (a recorder aligns the topics by stamp).

QoS: :mod:`pmdc_ident.nodes.qos` (sample topics RELIABLE, KEEP_LAST ten seconds of
samples, VOLATILE, so a reader stalled on a loaded machine has its missed samples
re-sent instead of lost; ``voltage_cmd`` RELIABLE KEEP_LAST(10), the ROS default a
controller publishes with; ``/diagnostics`` RELIABLE KEEP_LAST(10)).

The node only wires: every decision (refusing, clamping, trips, watchdog, the
status) is :class:`pmdc_ident.node_logic.driver.Driver`, the plant is
:class:`pmdc_ident.backends.sim.SimBackend` or the board behind
:class:`pmdc_ident.backends.serial_board.SerialBackend`; parameters are declared from
:data:`pmdc_ident.process.parameter_tables.DRIVER`. The motor is made safe on every way
out (Ctrl-C, SIGTERM, exception, shutdown: :mod:`pmdc_ident.nodes.runtime`); a
stop holds 0 V while a node still commands the driver (at most ``stop_wait_s``), so
the identification node's own safe command lands before the armature opens
(:meth:`pmdc_ident.node_logic.driver.Driver.begin_stop`).
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from pmdc_ident.backends.base import Telemetry
from pmdc_ident.backends.status import Level
from pmdc_ident.core.enums import ExitCode, LogLevel
from pmdc_ident.node_logic.driver import Driver
from pmdc_ident.nodes.parameters import declare
from pmdc_ident.nodes.qos import COMMAND_QOS, DIAGNOSTICS_QOS, sample_qos
from pmdc_ident.nodes.runtime import log as node_log
from pmdc_ident.nodes.runtime import run_node
from pmdc_ident.process.diagnostics import LevelLog, hardware_id, status_name
from pmdc_ident.process.parameter_tables import DRIVER

__all__ = ["DriverNode", "main"]

NODE_NAME = "driver_node"
FINAL_SAMPLES_S = 0.05  # published after the safe mode is applied on the way out
FINAL_ACK_S = 0.5  # at most this long for the readers to acknowledge them
_LEVEL = {
    Level.OK: DiagnosticStatus.OK,
    Level.WARN: DiagnosticStatus.WARN,
    Level.ERROR: DiagnosticStatus.ERROR,
}


class DriverNode(Node):
    """Wires a :class:`Driver` to ROS; see the module docs for the graph."""

    def __init__(self, *, clock_s: Any = time.monotonic, **node_kwargs: Any) -> None:
        super().__init__(NODE_NAME, **node_kwargs)
        self._clock_s = clock_s
        self.finished = False  # a signal arrived
        self.exit_code: int = ExitCode.OK
        self._driver: Driver | None = None
        cfg = declare(self, DRIVER, lambda name, value: self.driver.check_value(name, value))
        self._published = 0
        self._diag_count = 0
        self._diag_t: float | None = None  # the rate's window starts at the first sample
        self._last_rate_hz = float(cfg["rate_hz"])  # not judged before a window is full
        qos = sample_qos(float(cfg["rate_hz"]))
        self._pub_current = self.create_publisher(JointState, "current", qos)
        self._pub_encoder = self.create_publisher(JointState, "encoder", qos)
        self._pub_voltage = self.create_publisher(JointState, "voltage_applied", qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        joint = str(cfg["joint_name"])
        self._names = ([joint], [joint, f"{joint}_terminal"])  # voltage_applied's two forms
        self._msg_current = JointState(name=[joint], effort=[0.0])
        self._msg_encoder = JointState(name=[joint], position=[0.0], velocity=[0.0])
        self._msg_voltage = JointState(name=list(self._names[0]), effort=[0.0])
        self._hardware_id = hardware_id(self.get_namespace(), str(cfg["hardware_id"]))
        self._levels = LevelLog("driver status", causes_logged=True)
        self._driver = Driver(cfg, self._log, clock_s)
        self._t0_ns = self.get_clock().now().nanoseconds  # ROS time of backend sample 0
        try:
            self._cmd_sub = self.create_subscription(
                Float64, "voltage_cmd", self._on_voltage_cmd, COMMAND_QOS
            )
            self.create_service(Trigger, "open_armature", self._on_open_armature)
            self.create_service(Trigger, "reset_faults", self._on_reset_faults)
            self.add_post_set_parameters_callback(self._apply_parameters)
            self.create_timer(1.0 / float(cfg["poll_rate_hz"]), self._on_poll)
            self.create_timer(1.0, self._on_diagnostics)
        except BaseException:
            self.close()  # safe and released
            raise
        self.get_logger().info(self.driver.started_line())

    @property
    def driver(self) -> Driver:
        assert self._driver is not None
        return self._driver

    def _log(self, level: LogLevel, text: str) -> None:
        node_log(self, level, text)

    # -- ManagedNode (pmdc_ident.nodes.runtime) ---------------------------------------------
    def request_stop(self) -> None:
        self.finished = True

    def wind_down(self, spin_once: Any) -> None:
        """0 V at once, then serve the nodes that command this driver until they have
        gone (their own safe command applied and confirmed) or ``stop_wait_s`` passed;
        :meth:`close` then applies the safe mode."""
        if self._driver is None:
            return
        commanders = self._cmd_sub.get_publisher_count()
        self._log(LogLevel.INFO, self.driver.begin_stop(self._clock_s(), commanders))
        while not self.driver.stop_complete(self._clock_s(), self._cmd_sub.get_publisher_count()):
            spin_once(0.02)
        if self._cmd_sub.get_publisher_count() > 0:
            self._log(
                LogLevel.WARNING,
                f"a node still commands this driver after {self.driver.stop_wait_s:g} s "
                "(stop_wait_s): stopping anyway",
            )
        # the safe mode now, and a few samples that show it to whoever still listens (a
        # recorder, a probe): the last published state is the one the motor is left in
        self.driver.make_safe()
        end = self._clock_s() + FINAL_SAMPLES_S
        while self._clock_s() < end:
            spin_once(0.01)
        end = time.monotonic() + FINAL_ACK_S  # and let them reach those readers
        for pub in (self._pub_current, self._pub_encoder, self._pub_voltage):
            left = max(0.0, end - time.monotonic())
            pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))

    def close(self) -> list[str]:
        if self._driver is None:
            return ["driver stopped: no backend was started (motor untouched, safe)"]
        return [self._driver.shutdown_safe()]

    # -- callbacks -> driver ----------------------------------------------------------------
    def _apply_parameters(self, params: list[Parameter]) -> None:
        for p in params:
            self.driver.apply_parameter(p.name, p.value)

    def _on_voltage_cmd(self, msg: Float64) -> None:
        self.driver.command(msg.data)

    def _on_open_armature(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        resp.success, resp.message = self.driver.open_armature()
        return resp

    def _on_reset_faults(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        resp.success, resp.message = self.driver.reset_faults()
        return resp

    def _on_poll(self) -> None:
        samples = self.driver.poll()
        if samples is None:  # the link failed: say so at once
            self._on_diagnostics()
            return
        for s in samples:
            self._publish(s)

    # -- driver -> ROS --------------------------------------------------------------------
    def _publish(self, s: Telemetry) -> None:
        # Fields are set in place on three reused messages (publish serialises at once):
        # building new lists and Time objects costs more than the rest of the sample.
        sec, nanosec = divmod(self._t0_ns + round(s.time_s * 1e9), 1_000_000_000)
        cur, enc, vol = self._msg_current, self._msg_encoder, self._msg_voltage
        for msg in (cur, enc, vol):
            msg.header.stamp.sec = sec
            msg.header.stamp.nanosec = nanosec
        cur.effort[0] = s.current_a
        self._pub_current.publish(cur)
        enc.position[0] = s.position_rad
        enc.velocity[0] = s.speed_rad_s
        self._pub_encoder.publish(enc)
        if math.isnan(s.terminal_voltage_v):
            if len(vol.name) != 1:
                vol.name = list(self._names[0])
                vol.effort = [0.0]
            vol.effort[0] = s.voltage_cmd_v
        else:
            if len(vol.name) != 2:
                vol.name = list(self._names[1])
                vol.effort = [0.0, 0.0]
            vol.effort[0] = s.voltage_cmd_v
            vol.effort[1] = s.terminal_voltage_v
        self._pub_voltage.publish(vol)
        self._published += 1

    def _on_diagnostics(self) -> None:
        now = self._clock_s()
        if self._diag_t is not None and now - self._diag_t > 0:
            self._last_rate_hz = (self._published - self._diag_count) / (now - self._diag_t)
        if self._published or self._diag_t is not None:
            self._diag_t, self._diag_count = now, self._published
        report = self.driver.status(self._last_rate_hz, self._published)
        status = DiagnosticStatus(level=_LEVEL[report.level], message=report.message)
        status.name = status_name(self.get_fully_qualified_name(), "motor driver")
        status.hardware_id = self._hardware_id
        change = self._levels.update(status.level[0], report.message)
        if change is not None:
            self._log(*change)
        status.values = [KeyValue(key=k, value=v) for k, v in report.values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(arr)


#: Fast DDS's publication mode for this process, unless the user chose one: each publish
#: queues the sample for Fast DDS's sending thread, which sends what has queued meanwhile
#: (the four samples of a 250 Hz poll) to each reader in one datagram, where the default
#: (synchronous) mode sent one datagram per sample and reader from inside ``publish``.
#: Reliability, history depth and acknowledgement (``wait_for_all_acked`` on the way out)
#: are the same in both modes; other RMWs ignore the variable. Measured in
#: docs/integration.md ("CPU of the driver").
PUBLICATION_MODE = ("RMW_FASTRTPS_PUBLICATION_MODE", "ASYNCHRONOUS")


def main(args: list[str] | None = None) -> int:
    os.environ.setdefault(*PUBLICATION_MODE)  # before rclpy.init creates the participant
    # the EventsExecutor (run_node's default, as the other nodes): the SingleThreadedExecutor
    # rebuilt its wait set in Python at every wake-up of the 250 Hz poll timer
    return run_node(NODE_NAME, DriverNode, args, realtime=True)


if __name__ == "__main__":
    sys.exit(main())
