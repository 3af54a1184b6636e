"""Test helpers: run the driver node in a child process and talk to it over DDS.

Used by the DDS tests and ``benchmarks/bench_driver_rate.py``; not part of the
installed package. ``python test/helpers/driver_harness.py`` runs the one-step demo
(:func:`run_step_demo`); ``make demo`` runs the whole session.

* :func:`ros_env` - :func:`pmdc_ident.process.bringup.node_env`, the environment that keeps DDS
  on this machine (loopback Fast DDS profile, localhost discovery, a chosen domain id);
* :class:`DriverProcess` - ``python -m pmdc_ident.nodes.driver_node`` as a child,
  stopped with SIGINT, its exit status and stderr kept;
* :class:`DriverClient` - a small node that publishes ``voltage_cmd``, calls
  ``open_armature`` and records ``current``/``encoder``/``voltage_applied`` by stamp;
* :func:`run_step_demo` - the one-step demo.
"""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64
from std_srvs.srv import Trigger

from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.model import simulate
from pmdc_ident.core.motors import load_motor
from pmdc_ident.dataio.bagio import parse_joint_state
from pmdc_ident.nodes.qos import COMMAND_QOS, sample_qos
from pmdc_ident.process.bringup import node_env as ros_env
from pmdc_ident.process.bringup import priority_setter, realtime_thread
from pmdc_ident.process.dds_domain import HELD_ENV, lock_domain

__all__ = [
    "DriverClient",
    "DriverProcess",
    "StepDemoResult",
    "ros_env",
    "run_step_demo",
]


class DemoError(PmdcError):
    """The demo could not reach the driver or the driver misbehaved (one line)."""


def apply_ros_env(domain_id: int | None = None) -> None:
    """Put :func:`ros_env` into ``os.environ`` (before ``rclpy.init`` in this process)."""
    env = ros_env(domain_id)
    env.pop(HELD_ENV, None)  # that is for children: this process holds its own locks
    os.environ.update(env)


def _param_arg(name: str, value: Any) -> str:
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, float):
        text = repr(value)  # always with a '.', so ROS reads a double
    else:
        text = str(value)
    return f"{name}:={text}"


class DriverProcess:
    """The driver node as a child process (a context manager that always stops it)."""

    def __init__(
        self,
        params: Mapping[str, Any] | None = None,
        *,
        domain_id: int | None = None,
        realtime: bool = False,
    ):
        self.params = dict(params or {})
        self.env = ros_env(domain_id)
        self.realtime = realtime  # SCHED_RR where permitted, as bringup runs it
        self.proc: subprocess.Popen[str] | None = None
        self.returncode: int | None = None
        self.stderr = ""
        self.stdout = ""

    def start(self) -> DriverProcess:
        cmd = [sys.executable, "-m", "pmdc_ident.nodes.driver_node", "--ros-args"]
        for name, value in self.params.items():
            cmd += ["-p", _param_arg(name, value)]
        self.proc = subprocess.Popen(
            cmd,
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=priority_setter(0, self.realtime) if self.realtime else None,
        )
        return self

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def stop(self, sig: int = signal.SIGINT, timeout_s: float = 10.0) -> int:
        """Send ``sig``, wait for the exit; returns the exit status (kills after a timeout)."""
        if self.proc is None:
            return 0
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            out, err = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            out, err = self.proc.communicate()
        self.stdout, self.stderr = out or "", err or ""
        self.returncode = self.proc.returncode
        return self.returncode

    def __enter__(self) -> DriverProcess:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if self.returncode is None:
            self.stop()


@dataclass
class Recording:
    """Samples received on one topic: stamp (ns) and the values of interest."""

    stamps_ns: list[int] = field(default_factory=list)
    values: list[tuple[float, ...]] = field(default_factory=list)
    recv_ns: list[int] = field(default_factory=list)

    def array(self) -> np.ndarray:
        return np.array(self.values, dtype=float).reshape(len(self.values), -1)

    def times_s(self, t0_ns: int | None = None) -> np.ndarray:
        s = np.array(self.stamps_ns, dtype=np.int64)
        return (s - (s[0] if t0_ns is None else t0_ns)) * 1e-9 if s.size else np.zeros(0)


class DriverClient(Node):
    """Commands the driver and records what it publishes."""

    def __init__(self, rate_hz: float = 1000.0, name: str = "driver_client") -> None:
        super().__init__(name)
        qos = sample_qos(rate_hz)
        self.current = Recording()
        self.encoder = Recording()
        self.voltage = Recording()
        self.last_send_ns = 0  # ROS time of the last voltage_cmd sent
        self._pub = self.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
        # raw CDR decoded by the package's parse_joint_state (as the nodes do): rclpy's
        # message objects cost this test process more CPU than the rest of its work
        for topic, rec, kind in (
            ("current", self.current, "c"),
            ("encoder", self.encoder, "e"),
            ("voltage_applied", self.voltage, "v"),
        ):
            self.create_subscription(JointState, topic, self._rec(rec, kind), qos, raw=True)
        self._open = self.create_client(Trigger, "open_armature")
        self.executor_ = EventsExecutor(context=self.context)
        self.executor_.add_node(self)

    def spin_once(self, timeout_s: float) -> None:
        self.executor_.spin_once(timeout_sec=timeout_s)

    def catch_up(self, timeout_s: float = 20.0, slack_s: float = 0.003) -> None:
        """Spin until every topic has delivered the samples stamped up to ROS time now
        (a wait, not a check: 5 s were too few for the monitor's fixture at load 25)."""
        target = self.get_clock().now().nanoseconds - int(slack_s * 1e9)
        end = time.monotonic() + timeout_s
        recs = (self.current, self.encoder, self.voltage)
        while time.monotonic() < end:
            if all(r.stamps_ns and r.stamps_ns[-1] >= target for r in recs):
                return
            self.spin_once(0.01)
        msg = f"the driver's samples did not catch up within {timeout_s:g} s"
        raise DemoError(msg)

    def _rec(self, rec: Recording, kind: str) -> Callable[[bytes], None]:
        def cb(raw: bytes) -> None:
            ns, position, velocity, effort0, effort1 = parse_joint_state(raw)
            rec.stamps_ns.append(ns)
            rec.recv_ns.append(time.time_ns())
            if kind == "c":
                rec.values.append((effort0,))
            elif kind == "e":
                rec.values.append((position, velocity))
            else:  # voltage_applied: [command] or [command, measured terminal voltage]
                rec.values.append((effort0,) if math.isnan(effort1) else (effort0, effort1))

        return cb

    def send(self, volts: float) -> None:
        self._pub.publish(Float64(data=float(volts)))
        self.last_send_ns = self.get_clock().now().nanoseconds

    def spin_for(
        self, seconds: float, every_s: float = 0.0, action: Callable[[], None] | None = None
    ):
        """Spin ``seconds``; call ``action`` every ``every_s`` (e.g. to repeat a command)."""
        end = time.monotonic() + seconds
        next_action = time.monotonic()
        while (now := time.monotonic()) < end:
            if action is not None and now >= next_action:
                action()
                next_action += every_s
            timeout = max(0.0, min(end, next_action if action else end) - time.monotonic())
            self.spin_once(min(timeout, 0.05))

    def spin_until(
        self,
        done: Callable[[], bool],
        timeout_s: float,
        every_s: float = 0.0,
        action: Callable[[], None] | None = None,
    ) -> bool:
        """Spin until ``done()`` (checked every 0.05 s) or ``timeout_s``; ``action`` as
        in :meth:`spin_for`. A busy host slows the processes, not what they must do."""
        end = time.monotonic() + timeout_s
        while not done() and time.monotonic() < end:
            self.spin_for(0.05, every_s, action)
        return done()

    def wait_for_driver(
        self, timeout_s: float = 15.0, alive: Callable[[], bool] | None = None
    ) -> None:
        """Until the driver's samples arrive and it sees our command publisher.

        ``alive`` (e.g. :meth:`DriverProcess.alive`) ends the wait early when the
        driver process has exited.
        """
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            self.spin_once(0.05)
            if self.encoder.stamps_ns and self._pub.get_subscription_count() > 0:
                return
            if alive is not None and not alive():
                msg = "the driver process exited before publishing"
                raise DemoError(msg)
        msg = f"no samples from the driver within {timeout_s:g} s (is it running?)"
        raise DemoError(msg)

    def open_armature(self, timeout_s: float = 5.0) -> str:
        return self.trigger("open_armature", timeout_s)

    def trigger(self, service: str, timeout_s: float = 5.0) -> str:
        """Call one of the driver's std_srvs/Trigger services; returns its message."""
        cli = self._open if service == "open_armature" else self.create_client(Trigger, service)
        if not cli.wait_for_service(timeout_sec=timeout_s):
            msg = f"{service} service not available"
            raise DemoError(msg)
        fut = cli.call_async(Trigger.Request())
        end = time.monotonic() + timeout_s
        while not fut.done() and time.monotonic() < end:
            self.spin_once(0.05)
        if not fut.done() or fut.result() is None or not fut.result().success:
            # which of the three: a flake under load (no answer) is not a refusal
            why = (
                f"no answer within {timeout_s:g} s"
                if not fut.done()
                else "no response"
                if fut.result() is None
                else f"refused: {fut.result().message}"
            )
            msg = f"{service} call failed ({why})"
            raise DemoError(msg)
        return fut.result().message

    def destroy_node(self) -> None:
        self.executor_.remove_node(self)
        self.executor_.shutdown()
        super().destroy_node()

    def clear(self) -> None:
        for rec in (self.current, self.encoder, self.voltage):
            rec.stamps_ns.clear()
            rec.values.clear()
            rec.recv_ns.clear()


@dataclass(frozen=True)
class StepDemoResult:
    """What the step demo measured (SI units) and the driver's exit."""

    t_s: np.ndarray  # since the step reached the motor
    voltage_v: np.ndarray  # command applied (NaN = open)
    current_a: np.ndarray
    speed_rad_s: np.ndarray
    steady_current_a: float  # mean over the last 0.2 s of the step
    steady_speed_rad_s: float
    predicted_current_a: float  # the motor model under the same step
    predicted_speed_rad_s: float
    driver_exit: int
    driver_final_line: str


def _aligned(client: DriverClient) -> tuple[np.ndarray, ...]:
    """Samples present on all three topics, matched by stamp, in stamp order."""
    c = dict(zip(client.current.stamps_ns, client.current.values, strict=True))
    e = dict(zip(client.encoder.stamps_ns, client.encoder.values, strict=True))
    v = dict(zip(client.voltage.stamps_ns, client.voltage.values, strict=True))
    stamps = sorted(set(c) & set(e) & set(v))
    arr = np.array([(s, v[s][0], c[s][0], e[s][1]) for s in stamps], dtype=float)
    if arr.size == 0:
        return (np.zeros(0, dtype=np.int64),) + (np.zeros(0),) * 3
    return np.array(stamps, dtype=np.int64), arr[:, 1], arr[:, 2], arr[:, 3]


def run_step_demo(
    *,
    volts: float = 10.0,
    motor: str = "seed000_ebike",
    step_s: float = 2.0,
    rate_hz: float = 1000.0,
    command_hz: float = 100.0,
    domain_id: int | None = None,
    out: Callable[[str], None] = print,
) -> StepDemoResult:
    """Start the driver, apply a voltage step, print a table and the steady state."""
    apply_ros_env(domain_id)
    # the client at the nodes' priority where permitted (see bringup.realtime_thread)
    with lock_domain(int(os.environ["ROS_DOMAIN_ID"]), purpose="step demo"), realtime_thread():
        return _step_demo(volts, motor, step_s, rate_hz, command_hz, out)


def _step_demo(
    volts: float,
    motor: str,
    step_s: float,
    rate_hz: float,
    command_hz: float,
    out: Callable[[str], None],
) -> StepDemoResult:
    spec = load_motor(motor)
    driver = DriverProcess(
        {"motor": motor, "rate_hz": float(rate_hz)},
        domain_id=int(os.environ["ROS_DOMAIN_ID"]),
        realtime=True,
    ).start()
    rclpy.init()
    client = DriverClient(rate_hz)
    try:
        try:
            client.wait_for_driver(alive=driver.alive)
        except DemoError:
            if not driver.alive():
                driver.stop()
                lines = driver.stderr.strip().splitlines() or ["(no output)"]
                msg = f"the driver exited at start (status {driver.returncode}): {lines[-1]}"
                raise DemoError(msg) from None
            raise
        client.clear()
        client.spin_for(step_s, 1.0 / command_hz, lambda: client.send(volts))
        client.catch_up()  # every sample up to now (the command holds: watchdog 0.5 s)
        stamps_step, v_step, i_step, w_step = _aligned(client)
        client.open_armature()
        client.spin_for(0.3)
    finally:
        client.destroy_node()
        rclpy.try_shutdown()
        rc = driver.stop(signal.SIGINT)
    final = next(
        (ln for ln in driver.stderr.splitlines() if "driver stopped" in ln), "(no final line)"
    )
    if rc != 0:
        msg = f"driver exited with status {rc}: {driver.stderr.strip().splitlines()[-1:]}"
        raise DemoError(msg)
    driven = ~np.isnan(v_step)
    if driven.sum() < 0.5 * rate_hz:
        msg = f"only {int(driven.sum())} driven samples received in {step_s:g} s"
        raise DemoError(msg)
    k0 = int(np.argmax(driven))
    t = (stamps_step[k0:] - stamps_step[k0]) * 1e-9
    v, i, w = v_step[k0:], i_step[k0:], w_step[k0:]
    dt = 1.0 / rate_hz
    pred = simulate(spec.model, np.full(t.size, volts), dt)
    tail = t >= t[-1] - 0.2
    res = StepDemoResult(
        t_s=t,
        voltage_v=v,
        current_a=i,
        speed_rad_s=w,
        steady_current_a=float(np.mean(i[tail])),
        steady_speed_rad_s=float(np.mean(w[tail])),
        predicted_current_a=float(np.mean(pred.current[tail])),
        predicted_speed_rad_s=float(np.mean(pred.speed[tail])),
        driver_exit=rc,
        driver_final_line=final,
    )
    _print_demo(res, spec.name, volts, out)
    return res


def _print_demo(res: StepDemoResult, motor: str, volts: float, out: Callable[[str], None]):
    out(f"voltage step {volts:g} V on motor {motor} through the driver node (sim backend)")
    out(f"{'t (s)':>8} {'V (V)':>8} {'I (A)':>9} {'w (rad/s)':>10}")
    marks = [0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5, 0.75, 1.0, 1.5]
    marks += [res.t_s[-1]]
    for m in marks:
        if m > res.t_s[-1] + 1e-9:
            continue
        k = int(np.argmin(np.abs(res.t_s - m)))
        out(
            f"{res.t_s[k]:8.3f} {res.voltage_v[k]:8.2f} {res.current_a[k]:9.3f} "
            f"{res.speed_rad_s[k]:10.2f}"
        )
    rel_w = (res.steady_speed_rad_s - res.predicted_speed_rad_s) / res.predicted_speed_rad_s
    out(
        f"steady state (last 0.2 s): current {res.steady_current_a:.3f} A "
        f"(model {res.predicted_current_a:.3f} A), speed {res.steady_speed_rad_s:.2f} rad/s "
        f"(model {res.predicted_speed_rad_s:.2f} rad/s, {100 * rel_w:+.2f} %)"
    )
    out(f"armature opened; driver stopped with status {res.driver_exit}: {res.driver_final_line}")


if __name__ == "__main__":
    apply_ros_env(None)
    sys.exit(0 if run_step_demo().driver_exit == 0 else 1)
