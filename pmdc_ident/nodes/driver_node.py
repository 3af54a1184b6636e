"""The motor driver node: a thin ROS 2 layer over a motor backend (simulated or serial).

Graph (names relative, so namespaces and remaps work):

=====================  ===============================  =========================================
name                   type                             meaning
=====================  ===============================  =========================================
``voltage_cmd``        std_msgs/msg/Float64 (sub)       commanded armature voltage, V
``open_armature``      std_srvs/srv/Trigger (service)   open the winding (coast-down); the next
                                                        valid ``voltage_cmd`` closes it again
``reset_faults``       std_srvs/srv/Trigger (service)   clear a latched over-current/speed trip
``current``            sensor_msgs/msg/JointState       ``name ['armature']``, ``effort`` [A]
``encoder``            sensor_msgs/msg/JointState       ``name ['shaft']``, ``position`` [rad],
                                                        ``velocity`` [rad/s]
``voltage_applied``    sensor_msgs/msg/JointState       ``name ['armature'(, 'terminal')]``,
                                                        ``effort`` [command V, NaN while open
                                                        (, measured terminal V)]
``/diagnostics``       diagnostic_msgs/DiagnosticArray  1 Hz status of the driver
=====================  ===============================  =========================================

One message of each sample topic per backend sample, all three with the same
``header.stamp``: the backend's sample time since its start plus the ROS time
at which it started, so stamps are comparable to ROS time and exactly on the
sample grid (a recorder aligns the topics by stamp).

QoS: :mod:`pmdc_ident.nodes.qos` (sample topics RELIABLE, KEEP_LAST ten seconds of
samples, VOLATILE, so a reader stalled on a loaded machine has its missed samples
re-sent instead of lost; ``voltage_cmd`` RELIABLE KEEP_LAST(10), the ROS default a
controller publishes with; ``/diagnostics`` RELIABLE KEEP_LAST(10)).

No algorithm lives here: the plant is :class:`pmdc_ident.backends.sim.SimBackend`,
the trips and the watchdog are :class:`pmdc_ident.core.safety.SafetyMonitor`.
The motor is made safe on every way out (Ctrl-C, SIGTERM, exception, shutdown).
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from pmdc_ident.backends.base import Backend, BackendError, Telemetry
from pmdc_ident.core.enums import Fault, SafeMode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.motors import Limits, MotorSpec, SensorSpec, load_motor
from pmdc_ident.core.safety import SafetyConfig, SafetyMonitor
from pmdc_ident.nodes.qos import COMMAND_QOS, DIAGNOSTICS_QOS, sample_qos

__all__ = ["PARAMETERS", "DriverConfigError", "DriverNode", "main"]

NODE_NAME = "driver_node"


class DriverConfigError(PmdcError):
    """A driver parameter is invalid or the backend cannot be started (one line)."""


@dataclass(frozen=True)
class ParamDef:
    """A driver parameter: default (its type is the parameter's type), text and range."""

    default: Any
    description: str
    lower: float | None = None
    upper: float | None = None
    runtime: bool = False  # may be changed while the node runs


PARAMETERS: dict[str, ParamDef] = {
    "backend": ParamDef("sim", "motor backend: 'sim' (simulated plant) or 'serial' (board)"),
    "motor": ParamDef("seed000_ebike", "built-in motor name or path to a motor YAML file"),
    "rate_hz": ParamDef(1000.0, "sample rate of the driver, Hz", 1.0, 20000.0),
    "poll_rate_hz": ParamDef(
        250.0, "how often the backend is polled and due samples published, Hz", 10.0, 2000.0
    ),
    "voltage_limit_v": ParamDef(
        0.0,
        "commands are clamped to +-this, V (0 = the motor's limit, never above it)",
        0.0,
        10000.0,
        runtime=True,
    ),
    "current_limit_a": ParamDef(
        0.0,
        "trip to safe (latched) above this |current|, A (0 = the motor's limit)",
        0.0,
        100000.0,
        runtime=True,
    ),
    "speed_limit_rad_s": ParamDef(
        0.0,
        "trip to safe (latched) above this |speed|, rad/s (0 = the motor's limit)",
        0.0,
        100000.0,
        runtime=True,
    ),
    "watchdog_s": ParamDef(
        0.5,
        "open the armature if no voltage_cmd came for this long, s (0 = off)",
        0.0,
        60.0,
        runtime=True,
    ),
    "safe_mode": ParamDef(
        "open", "safe state: 'open' (disconnect the winding) or 'zero' (0 V, brakes)"
    ),
    "seed": ParamDef(0, "seed of the simulated measurement noise", 0, 2**31 - 1),
    "current_noise_a": ParamDef(
        -1.0, "sim current noise std, A (negative = the motor file's value)", -1.0, 1000.0
    ),
    "speed_noise_rad_s": ParamDef(
        -1.0, "sim speed noise std, rad/s (negative = the motor file's value)", -1.0, 10000.0
    ),
    "encoder_counts_per_rev": ParamDef(
        -1.0, "sim encoder counts per turn (0 = exact, negative = the motor file's)", -1.0, 1e9
    ),
    "port": ParamDef("/dev/ttyACM0", "serial port of the driver board (backend 'serial')"),
    "baud": ParamDef(115200, "baud rate of the serial port (backend 'serial')", 1200, 10000000),
}

BACKENDS = ("sim", "serial")
SAFE_MODES = tuple(m.value for m in SafeMode)


def _descriptor(name: str, p: ParamDef) -> ParameterDescriptor:
    d = ParameterDescriptor(description=p.description, read_only=not p.runtime)
    if p.lower is not None and p.upper is not None:
        if isinstance(p.default, float):
            d.floating_point_range = [
                FloatingPointRange(from_value=float(p.lower), to_value=float(p.upper), step=0.0)
            ]
        elif isinstance(p.default, int):
            d.integer_range = [
                IntegerRange(from_value=int(p.lower), to_value=int(p.upper), step=1)
            ]
    return d


class DriverNode(Node):
    """Owns one motor backend; converts between ROS messages and backend calls."""

    def __init__(self, *, clock_s: Any = time.monotonic, **node_kwargs: Any) -> None:
        super().__init__(NODE_NAME, **node_kwargs)
        self._clock_s = clock_s
        self._backend: Backend | None = None
        self._declare()
        cfg = {name: self.get_parameter(name).value for name in PARAMETERS}
        self._spec = self._load_motor(cfg["motor"])
        self._check_start(cfg)
        self._voltage_limit_v = self._effective_voltage_limit(cfg["voltage_limit_v"])
        self._safety = SafetyMonitor(
            SafetyConfig(
                current_max_a=cfg["current_limit_a"] or self._spec.limits.current_max_a,
                speed_max_rad_s=cfg["speed_limit_rad_s"] or self._spec.limits.speed_max_rad_s,
                data_timeout_s=0.0,  # the driver publishes; the session watches the data
                watchdog_s=cfg["watchdog_s"],
                non_finite_trips=False,  # a sensor may report 'not measured'
            )
        )
        self._backend_name = cfg["backend"]
        self._rate_hz = float(cfg["rate_hz"])
        self._driving = False  # a user command is being applied (the watchdog guards it)
        self._clamped = False
        self._published = 0
        self._diag_count = 0
        self._diag_t = self._clock_s()
        self._last_rate_hz = 0.0
        self._stalls_seen = 0
        self._last_sample_v = math.nan  # command of the last published sample
        self._link_error = ""

        qos = sample_qos(self._rate_hz)
        self._pub_current = self.create_publisher(JointState, "current", qos)
        self._pub_encoder = self.create_publisher(JointState, "encoder", qos)
        self._pub_voltage = self.create_publisher(JointState, "voltage_applied", qos)
        self._pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", DIAGNOSTICS_QOS)
        self._msg_current = JointState(name=["armature"], effort=[0.0])
        self._msg_encoder = JointState(name=["shaft"], position=[0.0], velocity=[0.0])
        self._msg_voltage = JointState(name=["armature"], effort=[0.0])

        backend = self._make_backend(cfg)
        try:
            backend.start()
        except BaseException as exc:
            try:
                backend.close()  # leave a half-opened port released and the motor safe
            except Exception:  # noqa: BLE001 - the start error is the one to report
                pass
            if isinstance(exc, PmdcError | OSError):
                msg = f"cannot start the {cfg['backend']} backend: {exc}"
                raise DriverConfigError(msg) from None
            raise
        self._backend = backend
        self._t0_ns = self.get_clock().now().nanoseconds  # ROS time of backend sample 0
        try:
            self._wire(cfg)
        except BaseException:
            self.shutdown_safe()  # e.g. Ctrl-C during start-up: safe and released
            raise

    def _wire(self, cfg: dict[str, Any]) -> None:
        self.create_subscription(Float64, "voltage_cmd", self._on_voltage_cmd, COMMAND_QOS)
        self.create_service(Trigger, "open_armature", self._on_open_armature)
        self.create_service(Trigger, "reset_faults", self._on_reset_faults)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(1.0 / float(cfg["poll_rate_hz"]), self._on_poll)
        self.create_timer(1.0, self._on_diagnostics)
        self.get_logger().info(
            f"driver started: backend {self._backend_name}, motor {self._spec.name}, "
            f"{self._rate_hz:g} Hz, voltage limit {self._voltage_limit_v:g} V, "
            f"safe mode {self._backend_safe_mode().value}, armature open"
        )

    # -- set-up -------------------------------------------------------------------------
    def _declare(self) -> None:
        for name, p in PARAMETERS.items():
            try:
                self.declare_parameter(name, p.default, _descriptor(name, p))
            except Exception as exc:  # rclpy raises several types for a bad override
                text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                if "expecting type" in text:
                    kind = type(p.default).__name__
                    hint = " (write e.g. 1000.0)" if kind == "float" else ""
                    text = f"must be of type {kind}{hint}"
                msg = f"parameter {name}: {text} ({p.description})"
                raise DriverConfigError(msg) from None

    def _load_motor(self, motor: str) -> MotorSpec:
        try:
            return load_motor(motor)
        except PmdcError as exc:
            msg = f"parameter motor: {exc}"
            raise DriverConfigError(msg) from None

    def _check_start(self, cfg: dict[str, Any]) -> None:
        if cfg["backend"] not in BACKENDS:
            msg = f"parameter backend must be one of {', '.join(BACKENDS)}, got {cfg['backend']!r}"
            raise DriverConfigError(msg)
        reason = self._check_runtime("safe_mode", cfg["safe_mode"]) or self._check_runtime(
            "voltage_limit_v", cfg["voltage_limit_v"]
        )
        if reason:
            raise DriverConfigError(reason)

    def _check_runtime(self, name: str, value: Any) -> str:
        """Why a value of a runtime parameter is refused ('' if it is fine)."""
        if name == "safe_mode" and value not in SAFE_MODES:
            return f"parameter safe_mode must be one of {', '.join(SAFE_MODES)}, got {value!r}"
        if name == "voltage_limit_v" and value > self._spec.limits.voltage_max_v:
            return (
                f"parameter voltage_limit_v {value:g} V is above the limit of motor "
                f"{self._spec.name} ({self._spec.limits.voltage_max_v:g} V)"
            )
        return ""

    def _effective_voltage_limit(self, value: float) -> float:
        return float(value) if value > 0.0 else self._spec.limits.voltage_max_v

    def _make_backend(self, cfg: dict[str, Any]) -> Backend:
        dt_s = 1.0 / float(cfg["rate_hz"])
        safe_mode = SafeMode(cfg["safe_mode"])
        # The backend trips at these itself (per sample, like board firmware); the
        # node's SafetyMonitor latches the trip and applies runtime changes.
        limits = Limits(
            voltage_max_v=self._spec.limits.voltage_max_v,
            current_max_a=self._safety.config.current_max_a,
            speed_max_rad_s=self._safety.config.speed_max_rad_s,
        )
        if cfg["backend"] == "sim":
            from pmdc_ident.backends.sim import SimBackend

            s = self._spec.sensors
            sensors = SensorSpec(
                current_noise_a=_override(cfg["current_noise_a"], s.current_noise_a),
                speed_noise_rad_s=_override(cfg["speed_noise_rad_s"], s.speed_noise_rad_s),
                encoder_counts_per_rev=_override(
                    cfg["encoder_counts_per_rev"], s.encoder_counts_per_rev
                ),
            )
            return SimBackend(
                self._spec,
                dt_s,
                sensors=sensors,
                limits=limits,
                safe_mode=safe_mode,
                seed=int(cfg["seed"]),
            )
        try:
            from pmdc_ident.backends.serial_board import SerialBackend
        except ImportError as exc:
            msg = f"backend 'serial' is not available ({exc})"
            raise DriverConfigError(msg) from None
        try:
            return SerialBackend(
                cfg["port"], int(cfg["baud"]), limits, dt_s, safe_mode, self.get_logger().warning
            )
        except (OSError, PmdcError) as exc:
            msg = f"cannot open the driver board on {cfg['port']}: {exc}"
            raise DriverConfigError(msg) from None

    def _backend_safe_mode(self) -> SafeMode:
        return SafeMode(self.get_parameter("safe_mode").value)

    # -- parameters at runtime --------------------------------------------------------------
    def _validate_parameters(self, params: list[Parameter]) -> SetParametersResult:
        for p in params:
            reason = self._check_runtime(p.name, p.value)
            if reason:
                return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        for p in params:
            if p.name == "voltage_limit_v":
                self._voltage_limit_v = self._effective_voltage_limit(p.value)
            elif p.name == "current_limit_a":
                self._safety.update(current_max_a=p.value or self._spec.limits.current_max_a)
            elif p.name == "speed_limit_rad_s":
                self._safety.update(speed_max_rad_s=p.value or self._spec.limits.speed_max_rad_s)
            elif p.name == "watchdog_s":
                self._safety.update(watchdog_s=p.value)
            self.get_logger().info(f"parameter {p.name} set to {p.value!r}")

    # -- commands -------------------------------------------------------------------------
    @property
    def backend(self) -> Backend:
        assert self._backend is not None
        return self._backend

    def _on_voltage_cmd(self, msg: Float64) -> None:
        v = float(msg.data)
        log = self.get_logger()
        if not math.isfinite(v):
            self._make_safe()
            log.warning(
                f"voltage_cmd {v} refused (not finite): motor made safe", throttle_duration_sec=1.0
            )
            return
        if self._safety.tripped:
            log.warning(
                f"voltage_cmd refused: {self._safety.message()}; call reset_faults",
                throttle_duration_sec=1.0,
            )
            return
        limit = self._voltage_limit_v
        self._clamped = abs(v) > limit
        if self._clamped:
            log.warning(f"voltage_cmd {v:g} V clamped to +-{limit:g} V", throttle_duration_sec=1.0)
            v = math.copysign(limit, v)
        try:
            self.backend.command_voltage(v)
        except BackendError as exc:
            self._make_safe()
            log.error(f"{exc}; motor made safe", throttle_duration_sec=1.0)
            return
        self._driving = True
        self._safety.command_received(self._clock_s())

    def _on_open_armature(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        try:
            self.backend.open_armature()
        except BackendError as exc:
            self._make_safe()
            resp.success, resp.message = False, f"{exc}; motor made safe"
            self.get_logger().error(resp.message)
            return resp
        self._driving = False
        resp.success = True
        resp.message = "armature open (coasting); the next voltage_cmd closes it"
        self.get_logger().info(resp.message)
        return resp

    def _on_reset_faults(self, _req: Trigger.Request, resp: Trigger.Response) -> Any:
        was = self._safety.message() or "no latched fault"
        self._safety.reset()
        resp.success = True
        resp.message = f"cleared: {was}"
        self.get_logger().info(resp.message)
        return resp

    def _make_safe(self) -> None:
        self._driving = False
        if self._backend is not None:
            self._backend.make_safe()

    # -- samples ------------------------------------------------------------------------------
    def _on_poll(self) -> None:
        try:
            samples = self.backend.poll()
        except BackendError as exc:  # link lost (serial): safe, report, keep running
            self._make_safe()
            self._link_error = str(exc)
            self.get_logger().error(f"backend: {exc}")
            self._on_diagnostics()
            return
        stalls = getattr(self.backend, "stalls", 0)  # sim backend: host stalls so far
        if stalls != self._stalls_seen:
            self._stalls_seen = stalls
            skipped = getattr(self.backend, "skipped_samples", 0)
            self.get_logger().warning(
                f"host stall: samples skipped (not published), {skipped} so far; "
                "the simulated motor kept running and stamps stay on the grid"
            )
        for s in samples:
            trip = self._safety.check(s.time_s, s.current_a, s.speed_rad_s)
            if trip is not None:
                self._make_safe()
                self.get_logger().error(f"{self._safety.latched[trip]}: motor made safe")
            self._publish(s)
        if self._safety.watchdog_expired(self._clock_s(), self._driving):
            self.backend.open_armature()
            self._driving = False
            timeout = self._safety.config.watchdog_s
            self.get_logger().warning(
                f"watchdog: no voltage_cmd for {timeout:g} s, armature opened"
            )

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
                vol.name = ["armature"]
                vol.effort = [0.0]
            vol.effort[0] = s.voltage_cmd_v
        else:
            if len(vol.name) != 2:
                vol.name = ["armature", "terminal"]
                vol.effort = [0.0, 0.0]
            vol.effort[0] = s.voltage_cmd_v
            vol.effort[1] = s.terminal_voltage_v
        self._pub_voltage.publish(vol)
        self._last_sample_v = s.voltage_cmd_v
        self._published += 1

    # -- diagnostics -----------------------------------------------------------------------
    def faults(self) -> Fault:
        f = self._safety.faults
        if self._clamped:
            f |= Fault.CLAMPED
        return f

    def state_text(self) -> str:
        """The armature state: the backend's current command where it exposes one
        (sim), else the command of the last published sample (serial)."""
        cmd = getattr(self.backend, "command_v", self._last_sample_v)
        return _armature_text(cmd)

    def _on_diagnostics(self) -> None:
        now = self._clock_s()
        span = now - self._diag_t
        if span > 0:
            self._last_rate_hz = (self._published - self._diag_count) / span
        self._diag_t, self._diag_count = now, self._published
        faults = self.faults()
        status = DiagnosticStatus()
        status.name = f"{self.get_fully_qualified_name()}: motor driver"
        status.hardware_id = f"{self._backend_name}:{self._spec.name}"
        if faults & (Fault.OVER_CURRENT | Fault.OVER_SPEED):
            status.level, status.message = DiagnosticStatus.ERROR, self._safety.message()
        elif faults or self._last_rate_hz < 0.9 * self._rate_hz:
            status.level = DiagnosticStatus.WARN
            status.message = f"faults: {_fault_names(faults)}" if faults else "sample rate low"
        else:
            status.level, status.message = DiagnosticStatus.OK, "running"
        link = getattr(self.backend, "link_stats", None)  # serial backend only
        if link is not None and link.state.value != "streaming":
            msg = self._link_error or link.last_error or "serial link down"
            status.level, status.message = DiagnosticStatus.ERROR, msg
        values = {
            "backend": self._backend_name,
            "motor": self._spec.name,
            "sample rate set (Hz)": f"{self._rate_hz:g}",
            "sample rate delivered (Hz)": f"{self._last_rate_hz:.1f}",
            "samples published": str(self._published),
            "faults": _fault_names(faults),
            "armature": self.state_text(),
            "voltage limit (V)": f"{self._voltage_limit_v:g}",
            "watchdog": "tripped" if self._safety.watchdog_tripped else "ok",
            "watchdog timeout (s)": f"{self._safety.config.watchdog_s:g}",
            "skipped samples (host stalls)": str(getattr(self.backend, "skipped_samples", 0)),
        }
        if link is not None:
            values.update({f"link {k}": v for k, v in link.as_strings().items()})
        status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self.get_clock().now().to_msg()
        self._pub_diag.publish(arr)

    # -- shutdown ----------------------------------------------------------------------------
    def shutdown_safe(self) -> str:
        """Make the motor safe and release the backend; returns the final state line."""
        if self._backend is None:
            return "driver stopped: no backend was started (motor untouched, safe)"
        try:
            self._backend.make_safe()
            if hasattr(self._backend, "command_v"):
                state = self.state_text()
            else:  # what make_safe commanded (no sample of it may arrive any more)
                safe = self._backend_safe_mode() is SafeMode.OPEN
                state = _armature_text(math.nan if safe else 0.0)
            self._backend.close()
        except Exception as exc:  # noqa: BLE001 - report, never raise on the way out
            return f"driver stopped: backend error while making safe ({exc})"
        return f"driver stopped: motor safe ({state}, safe mode {self._backend_safe_mode().value})"


def _armature_text(command_v: float) -> str:
    return "armature open" if math.isnan(command_v) else f"{command_v:g} V applied"


def _override(value: float, default: float) -> float:
    return default if value < 0 else float(value)


def _fault_names(f: Fault) -> str:
    if not f:
        return "none"
    return ",".join(m.name for m in Fault if m and m in f and m.name)


def main(args: list[str] | None = None) -> int:
    rclpy.init(args=args)
    node: DriverNode | None = None
    status = 0
    try:
        node = DriverNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except PmdcError as exc:
        print(f"{NODE_NAME}: {exc}", file=sys.stderr, flush=True)
        status = 2
    except Exception as exc:  # unexpected: still leave the motor safe, then report
        if not rclpy.ok():
            # a signal shut the context down while the executor waited or while the node
            # was being built (its backend is then already safe and closed): normal exit
            pass
        else:
            print(f"{NODE_NAME}: internal error: {exc!r}", file=sys.stderr, flush=True)
            status = 1
    finally:
        if node is not None:
            final = node.shutdown_safe()
            print(f"{NODE_NAME}: {final}", file=sys.stderr, flush=True)
            node.destroy_node()
        elif status == 0:  # interrupted before the node existed (or while it was built)
            print(f"{NODE_NAME}: stopped during start-up: motor safe", file=sys.stderr)
        rclpy.try_shutdown()
    return status


if __name__ == "__main__":
    sys.exit(main())
