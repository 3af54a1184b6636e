"""Driver sample rate over DDS: delivered fraction, stamp jitter and publish lag.

The driver node (sim backend, seed-000 motor, 5 V applied) runs in one process at
1 kHz and at 5 kHz for 10 s each; this process subscribes to ``encoder`` (raw
CDR, EventsExecutor, so the subscriber itself is cheap) and measures:

* delivered: distinct samples received / (duration * rate) over a 10 s stamp window;
* stamp jitter: std and max |diff - 1/rate| of consecutive received stamps (a lost
  sample shows as one whole period), and the worst distance from the grid;
* publish lag: receive time - stamp, p50 / p99 (includes the poll period, 4 ms);
* driver CPU: user+system time of the driver process / wall time.

Reference in the same run: a naive driver (a ROS timer at the sample rate that
publishes one sample per tick stamped with ``now()``), the design the exact grid
replaces; its stamps jitter with the host timer, and its delivered rate is
whatever the timer manages.

    .venv/bin/python benchmarks/bench_driver_rate.py [--seconds 10] [--domain ID]
"""

from __future__ import annotations

import argparse
import os
import struct
import subprocess
import sys
import time
from dataclasses import dataclass

import numpy as np

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
sys.path.insert(0, os.path.join(REPO, "test"))  # the driver test helpers

from helpers.driver_harness import DriverProcess, apply_ros_env, ros_env  # noqa: E402

from pmdc_ident.process.dds_domain import allocate_domain, lock_domain  # noqa: E402

NAIVE = r"""
import sys, rclpy
from rclpy.executors import ExternalShutdownException
from sensor_msgs.msg import JointState
from pmdc_ident.nodes.qos import sample_qos
rate = float(sys.argv[1])
rclpy.init()
node = rclpy.create_node("naive_driver")
pub = node.create_publisher(JointState, "encoder", sample_qos(rate))
msg = JointState(name=["shaft"])
def tick():
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.position = [0.0]
    msg.velocity = [0.0]
    pub.publish(msg)
node.create_timer(1.0 / rate, tick)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
finally:
    node.destroy_node()
    rclpy.try_shutdown()
"""


@dataclass
class Figures:
    name: str
    rate_hz: float
    delivered: float
    jitter_std_us: float
    jitter_max_us: float
    off_grid_max_us: float
    lag_p50_ms: float
    lag_p99_ms: float
    driver_cpu: float


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _measure(name: str, pid: int, rate_hz: float, seconds: float, node, executor) -> Figures:

    from sensor_msgs.msg import JointState

    from pmdc_ident.nodes.qos import sample_qos

    stamps: list[int] = []
    recv: list[int] = []

    def on_raw(raw: bytes) -> None:
        sec, nsec = struct.unpack_from("<iI", raw, 4)  # CDR LE header, then header.stamp
        recv.append(time.time_ns())
        stamps.append(sec * 1_000_000_000 + nsec)

    sub = node.create_subscription(JointState, "encoder", on_raw, sample_qos(rate_hz), raw=True)
    t_end = time.monotonic() + seconds + 2.0  # 1 s warm-up, 1 s to drain
    cpu0, wall0 = None, 0.0
    while time.monotonic() < t_end:
        executor.spin_once(timeout_sec=0.05)
        if cpu0 is None and stamps and time.monotonic() > t_end - seconds - 1.0:
            cpu0, wall0 = _cpu_s(pid), time.monotonic()
    cpu = (_cpu_s(pid) - (cpu0 or 0.0)) / max(1e-9, time.monotonic() - wall0)
    node.destroy_subscription(sub)
    s = np.array(stamps, dtype=np.int64)
    r = np.array(recv, dtype=np.int64)
    if s.size < 10:
        msg = f"{name} at {rate_hz:g} Hz: only {s.size} samples received"
        raise SystemExit(msg)
    start = s[0] + 1_000_000_000  # skip the first second
    win = (s >= start) & (s < start + int(seconds * 1e9))
    sw, rw = s[win], r[win]
    uniq = np.unique(sw)
    dt_ns = 1e9 / rate_hz
    d = np.diff(uniq).astype(float)
    dev = d - dt_ns
    off = np.abs(d - np.round(d / dt_ns) * dt_ns)
    lag = (rw - sw) * 1e-6
    return Figures(
        name=name,
        rate_hz=rate_hz,
        delivered=uniq.size / (seconds * rate_hz),
        jitter_std_us=float(np.std(dev) / 1e3),
        jitter_max_us=float(np.max(np.abs(dev)) / 1e3),
        off_grid_max_us=float(np.max(off) / 1e3),
        lag_p50_ms=float(np.percentile(lag, 50)),
        lag_p99_ms=float(np.percentile(lag, 99)),
        driver_cpu=cpu,
    )


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--domain", type=int, default=None, help="default: a free one")
    ap.add_argument("--rates", type=float, nargs="+", default=[1000.0, 5000.0])
    ap.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    args = ap.parse_args()
    # A DDS domain no other suite, benchmark or demo on this machine uses meanwhile.
    held = lock_domain(args.domain) if args.domain is not None else allocate_domain()
    args.domain = held.domain_id
    apply_ros_env(args.domain)
    import rclpy
    from rclpy.experimental import EventsExecutor
    from std_msgs.msg import Float64

    from pmdc_ident.nodes.qos import COMMAND_QOS

    rclpy.init()
    node = rclpy.create_node("bench_driver_rate")
    executor = EventsExecutor()
    executor.add_node(node)
    cmd = node.create_publisher(Float64, "voltage_cmd", COMMAND_QOS)
    results: list[Figures] = []
    try:
        for rate in args.rates:
            params = {"rate_hz": rate, "watchdog_s": 0.0, "poll_rate_hz": 250.0}
            with DriverProcess(params, domain_id=args.domain) as drv:
                t0 = time.monotonic()
                while cmd.get_subscription_count() == 0 and time.monotonic() - t0 < 20:
                    executor.spin_once(timeout_sec=0.05)
                for _ in range(5):
                    cmd.publish(Float64(data=5.0))
                    executor.spin_once(timeout_sec=0.02)
                results.append(_measure("driver", drv.pid, rate, args.seconds, node, executor))
                rc = drv.stop()
                if rc != 0:
                    print(f"driver exited {rc}: {drv.stderr.strip()[-300:]}", file=sys.stderr)
            if not args.no_naive:
                naive = subprocess.Popen(
                    [sys.executable, "-c", NAIVE, str(rate)],
                    env=ros_env(args.domain),
                    cwd=REPO,
                )
                try:
                    results.append(
                        _measure("naive timer", naive.pid, rate, args.seconds, node, executor)
                    )
                finally:
                    naive.send_signal(2)
                    naive.wait(timeout=10)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    load = os.getloadavg()[0]
    print(
        f"driver sample rate over DDS, {args.seconds:g} s windows, loadavg {load:.1f}, "
        f"{os.cpu_count()} cores"
    )
    head = (
        f"{'publisher':<12} {'rate Hz':>8} {'delivered':>9} {'jit std us':>10} "
        f"{'jit max us':>10} {'off-grid us':>11} {'lag p50 ms':>10} {'lag p99 ms':>10} "
        f"{'pub CPU':>7}"
    )
    print(head)
    for f in results:
        print(
            f"{f.name:<12} {f.rate_hz:8.0f} {f.delivered:9.4f} {f.jitter_std_us:10.1f} "
            f"{f.jitter_max_us:10.1f} {f.off_grid_max_us:11.3f} {f.lag_p50_ms:10.2f} "
            f"{f.lag_p99_ms:10.2f} {100 * f.driver_cpu:6.0f}%"
        )
    for rate in args.rates:
        d = [f for f in results if f.rate_hz == rate and f.name == "driver"]
        n = [f for f in results if f.rate_hz == rate and f.name == "naive timer"]
        if d and n:
            print(
                f"{rate:g} Hz reference: naive timer stamp jitter std {n[0].jitter_std_us:.1f} us "
                f"vs driver {d[0].jitter_std_us:.1f} us; delivered {n[0].delivered:.3f} vs "
                f"{d[0].delivered:.3f}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
