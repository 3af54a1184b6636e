"""Driver sample rate over DDS: delivered fraction, stamp jitter and publish lag.

The driver node (sim backend, seed-000 motor, 5 V applied) runs in one process at
1 kHz and at 5 kHz for 10 s each; this process subscribes to ``encoder`` (raw
CDR, EventsExecutor, so the subscriber itself is cheap) and measures:

* delivered: distinct samples received / (duration * rate) over a 10 s stamp window;
* stamp jitter: std and max |diff - 1/rate| of consecutive received stamps (a lost
  sample shows as one whole period), and the worst distance from the grid;
* publish lag: receive time - stamp, p50 / p99 (includes the poll period, 4 ms);
* driver CPU: user+system time of the driver process / wall time.

The driver runs under SCHED_RR where permitted, as bring-up runs it, once per Fast DDS
publication mode (``--modes``): asynchronous, the driver's default, and synchronous,
Fast DDS's own default; the driver CPU ratio of the two is printed per rate (see
docs/integration.md, "CPU of the driver").

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


#: RMW_FASTRTPS_PUBLICATION_MODE values compared; the first is the driver's default
MODES = ("ASYNCHRONOUS", "SYNCHRONOUS")
SHORT = {"ASYNCHRONOUS": "async", "SYNCHRONOUS": "sync"}


READER = r"""
import sys, time, rclpy
from rclpy.experimental import EventsExecutor
from sensor_msgs.msg import JointState
from pmdc_ident.nodes.qos import sample_qos
rclpy.init()
node = rclpy.create_node("reader")
qos = sample_qos(float(sys.argv[1]))
for topic in ("current", "encoder", "voltage_applied"):
    node.create_subscription(JointState, topic, lambda raw: None, qos, raw=True)
executor = EventsExecutor()
executor.add_node(node)
try:
    executor.spin()
except KeyboardInterrupt:
    pass
finally:
    executor.shutdown()
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


def _drivers(args, rate, cmd, node, executor) -> list[Figures]:  # type: ignore[no-untyped-def]
    """The driver at ``rate`` once per publication mode in ``args.modes``."""
    from std_msgs.msg import Float64

    out = []
    params = {"rate_hz": rate, "watchdog_s": 0.0, "poll_rate_hz": 250.0}
    # Where other readers listen, the first driver of a run cost 4-6x the CPU of every
    # later one, in either mode (both orders tried), even with the readers in the graph
    # 15 s before it started: a short warm-up driver runs first, its figures not shown.
    for k, mode in enumerate((args.modes[0], *args.modes)):
        drv = DriverProcess(params, domain_id=args.domain, realtime=True)
        drv.env["RMW_FASTRTPS_PUBLICATION_MODE"] = mode
        with drv:
            t0 = time.monotonic()
            while cmd.get_subscription_count() == 0 and time.monotonic() - t0 < 20:
                executor.spin_once(timeout_sec=0.05)
            for _ in range(5):
                cmd.publish(Float64(data=5.0))
                executor.spin_once(timeout_sec=0.02)
            seconds = args.seconds if k else min(3.0, args.seconds)
            fig = _measure(f"driver {SHORT[mode]}", drv.pid, rate, seconds, node, executor)
            if k:
                out.append(fig)
            rc = drv.stop()
            if rc != 0:
                print(f"driver exited {rc}: {drv.stderr.strip()[-300:]}", file=sys.stderr)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--domain", type=int, default=None, help="default: a free one")
    ap.add_argument("--rates", type=float, nargs="+", default=[1000.0, 5000.0])
    ap.add_argument("--no-naive", action="store_true", help="skip the naive reference")
    ap.add_argument(
        "--readers",
        type=int,
        default=2,
        help="other processes reading all three sample topics, as a session's nodes do",
    )
    ap.add_argument(
        "--modes",
        nargs="+",
        choices=MODES,
        default=list(MODES),
        help="Fast DDS publication modes of the driver (default: both)",
    )
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
            readers = [
                subprocess.Popen(
                    [sys.executable, "-c", READER, str(rate)], env=ros_env(args.domain), cwd=REPO
                )
                for _ in range(args.readers)
            ]
            try:
                t0 = time.monotonic()  # every reader in the graph before a driver starts
                while node.count_subscribers("current") < args.readers:
                    if time.monotonic() - t0 > 30:
                        raise SystemExit(f"{args.readers} readers not seen in 30 s")
                    executor.spin_once(timeout_sec=0.05)
                results += _drivers(args, rate, cmd, node, executor)
            finally:
                for r in readers:
                    r.send_signal(2)
                for r in readers:
                    try:
                        r.wait(timeout=10)
                    except subprocess.TimeoutExpired:
                        r.kill()
                        r.wait()
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
        f"driver sample rate over DDS, {args.seconds:g} s windows, {args.readers} other "
        f"readers of all three topics, loadavg {load:.1f}, {os.cpu_count()} cores"
    )
    head = (
        f"{'publisher':<13} {'rate Hz':>8} {'delivered':>9} {'jit std us':>10} "
        f"{'jit max us':>10} {'off-grid us':>11} {'lag p50 ms':>10} {'lag p99 ms':>10} "
        f"{'pub CPU':>7}"
    )
    print(head)
    for f in results:
        print(
            f"{f.name:<13} {f.rate_hz:8.0f} {f.delivered:9.4f} {f.jitter_std_us:10.1f} "
            f"{f.jitter_max_us:10.1f} {f.off_grid_max_us:11.3f} {f.lag_p50_ms:10.2f} "
            f"{f.lag_p99_ms:10.2f} {100 * f.driver_cpu:6.0f}%"
        )
    for rate in args.rates:
        d = [f for f in results if f.rate_hz == rate and f.name.startswith("driver")]
        n = [f for f in results if f.rate_hz == rate and f.name == "naive timer"]
        if d and n:
            print(
                f"{rate:g} Hz reference: naive timer stamp jitter std {n[0].jitter_std_us:.1f} us "
                f"vs driver {d[0].jitter_std_us:.1f} us; delivered {n[0].delivered:.3f} vs "
                f"{d[0].delivered:.3f}"
            )
        if len(d) == 2:
            print(
                f"{rate:g} Hz driver CPU, {d[1].name} / {d[0].name}: "
                f"{d[1].driver_cpu / max(d[0].driver_cpu, 1e-9):.2f}x"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
