"""Nothing lost under load: the full default session at 1 kHz with two CPU hogs running.

    .venv/bin/python benchmarks/bench_stress.py [--rate5k-s 10] [--no-hogs] [--skip-session]

Starts two CPU-bound hog processes (``while 1: pass``, nice 0) on this machine,
then

1. runs the full default session on the simulated seed-000 motor at 1 kHz
   (driver, recorder and identification nodes as separate processes over DDS on
   loopback, as ``make demo`` does) and prints, per driver topic, the samples of
   the session the driver published, the identification node received and the
   recorder wrote to the bag, with the arrival latency (p50 / p99 / max);
2. runs the driver alone at 5 kHz with one raw subscriber (the recorder's QoS)
   and prints what was delivered.

The nodes run as ``bringup`` starts them (SCHED_RR where the system permits it, else
nice -5); the 5 kHz driver and its subscriber the same way.

"Published" is the session's sample grid less the samples the driver itself
skipped after host stalls (it logs each stall with the running count). "Received"
comes from the node's result (``driver_samples``), "written" from the bag's
``metadata.yaml``; both are also checked against the stamps. The node's latency
is the one it logs for ``encoder`` (arrival - stamp); the recorder's is each bag
message's log time - its stamp. The load average is printed before and after.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "test"))  # the test helpers

from pmdc_ident.dataio.bagio import header_stamp_ns, read_driver_arrays  # noqa: E402
from pmdc_ident.process.bringup import node_env, priority_setter, run_session  # noqa: E402
from pmdc_ident.process.dds_domain import allocate_domain  # noqa: E402

TOPICS = ("current", "encoder", "voltage_applied")
CUSTOM = "pmdc_ident.driver_samples"  # the recorder's entry in metadata.yaml
SKIP_RE = re.compile(r"\[(\d+)\.(\d+)\] \[driver_node\]: host stall: .*?, (\d+) so far")

SUBSCRIBER = r"""
import json, signal, sys, time
import rclpy
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import JointState
from pmdc_ident.dataio.bagio import header_stamp_ns
from pmdc_ident.nodes.qos import sample_qos
rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
stop = []
signal.signal(signal.SIGINT, lambda *a: stop.append(1))
node = rclpy.create_node("stress_subscriber")
got = {t: [] for t in ("current", "encoder", "voltage_applied")}
said = []
def cb(topic):
    def on(raw):
        got[topic].append((header_stamp_ns(raw), time.time_ns()))
        if not said and all(got.values()):
            said.append(1)
            print("receiving", flush=True)
    return on
for t in got:
    node.create_subscription(JointState, t, cb(t), sample_qos(float(sys.argv[1])), raw=True)
ex = EventsExecutor()
ex.add_node(node)
print("ready", flush=True)
while not stop:
    ex.spin_once(timeout_sec=0.05)
stop_ns, end = time.time_ns(), time.monotonic() + 30.0
def behind():
    return any(not v or v[-1][0] < stop_ns for v in got.values())
while behind() and time.monotonic() < end:  # take what was published before the stop
    ex.spin_once(timeout_sec=0.05)
json.dump({"stop_ns": stop_ns, "got": got}, sys.stdout)
"""


def _hogs(n: int) -> list[subprocess.Popen[bytes]]:
    return [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]


def _load() -> str:
    return " ".join(Path("/proc/loadavg").read_text().split()[:3])


def _skipped(driver_log: str, lo_ns: int, hi_ns: int, dt_ns: int) -> int:
    """Samples of [lo, hi) the driver skipped (never published), from its stall lines.

    The sim backend logs each host stall with the running count; the samples it
    skipped are the oldest of its backlog, those stamped up to 0.5 s (the catch-up
    it keeps) before the line.
    """
    prev, total = 0, 0
    for m in SKIP_RE.finditer(driver_log):
        t_ns = int(m.group(1)) * 1_000_000_000 + int(m.group(2).ljust(9, "0")[:9])
        n = int(m.group(3))
        b = t_ns - 500_000_000
        a = b - (n - prev) * dt_ns
        total += max(0, min(b, hi_ns) - max(a, lo_ns)) // dt_ns
        prev = n
    return int(total)


def _account(stamps: dict[str, np.ndarray], lo: int, hi: int, dt: int, skipped: int) -> dict:
    """Per topic: published (grid less the driver's skips), delivered, lost for good.

    A hole on all three topics at once is what a driver skip looks like: it counts as
    lost only beyond the skips the driver logged.
    """
    n = int(round((hi - lo) / dt))
    have = {}
    for t, s in stamps.items():
        k = np.round((np.asarray(s, dtype=np.int64) - lo) / dt).astype(np.int64)
        have[t] = np.unique(k[(k >= 0) & (k < n)])
    all_k = np.arange(n)
    missing = {t: np.setdiff1d(all_k, k) for t, k in have.items()}
    common = missing[TOPICS[0]]
    for t in TOPICS[1:]:
        common = np.intersect1d(common, missing[t])
    extra_common = max(0, common.size - skipped)
    return {
        t: {
            "published": n - skipped,
            "delivered": int(have[t].size),
            "lost": int(missing[t].size - common.size + extra_common),
        }
        for t in TOPICS
    } | {"_": {"expected": n, "all_three_missing": int(common.size), "skipped": skipped}}


def _pct(lat_ms: np.ndarray) -> str:
    if lat_ms.size == 0:
        return f"{'-':>8} {'-':>8} {'-':>8}"
    p50, p99 = np.percentile(lat_ms, [50, 99])
    return f"{p50:8.1f} {p99:8.1f} {lat_ms.max():8.1f}"


def _bag_messages(bag: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per driver topic: stamps and log (arrival) times of the bag's messages, ns."""
    from rosbags.rosbag2 import Reader

    out: dict[str, list[tuple[int, int]]] = {t: [] for t in TOPICS}
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic.rsplit("/", 1)[-1] in out]
        for conn, log_ns, raw in reader.messages(connections=conns):
            out[conn.topic.rsplit("/", 1)[-1]].append((header_stamp_ns(raw), log_ns))
    return {t: tuple(np.array(v, dtype=np.int64).reshape(-1, 2).T) for t, v in out.items()}


def session(domain: int) -> int:
    """The full default session at 1 kHz; prints the table, returns samples lost for good."""
    with tempfile.TemporaryDirectory(prefix="bench_stress_") as tmp:
        t0, c0 = time.monotonic(), os.times()
        res = run_session(
            output_dir=Path(tmp) / "out",
            motor="seed000_ebike",
            domain_id=domain,
            log_dir=Path(tmp) / "logs",
            timeout_s=900.0,
            # as make demo: a shared machine stalls processes now and then
            identification_params={"safety.data_timeout_s": 1.5},
            driver_params={"watchdog_s": 1.5},
        )
        wall = time.monotonic() - t0
        logs = {k: p.read_text() for k, p in res.logs.items()}
        if res.bag is None or res.result is None:
            tail = "\n".join(logs.get("identification", "").splitlines()[-5:])
            print(f"session failed (identification exit {res.identification_rc}):\n{tail}")
            return -1
        info = yaml.safe_load((res.bag / "metadata.yaml").read_text())
        said = json.loads(info["rosbag2_bagfile_information"]["custom_data"][CUSTOM])["topics"]
        received = res.result["driver_samples"]["topics"]
        msgs = _bag_messages(res.bag)
        ms = read_driver_arrays(res.bag).markers
    lo, hi, dt = round(ms[0].t_s * 1e9), round(ms[-1].t_s * 1e9), 1_000_000
    skipped = _skipped(logs["driver"], lo, hi, dt)
    acc = _account({t: msgs[t][0] for t in TOPICS}, lo, hi, dt, skipped)
    info_ = acc.pop("_")
    lat = re.search(
        r"latency median ([\d.]+) ms, 99th percentile ([\d.]+) ms, max ([\d.]+) ms",
        logs["identification"],
    )
    node_lat = f"{float(lat[1]):8.1f} {float(lat[2]):8.1f} {float(lat[3]):8.1f}" if lat else "-"
    print(
        f"\n1) full default session, seed000_ebike at 1 kHz: {info_['expected']} samples per "
        f"topic on the grid ({info_['expected'] / 1000:.1f} s of driver time), wall {wall:.1f} s"
    )
    print(
        f"   driver skipped after host stalls (its log): {skipped}; missing on all three "
        f"topics of the bag: {info_['all_three_missing']}"
    )
    print(
        f"   {'topic':<16} {'published':>9} {'received':>9} {'written':>9} {'lost':>5}   "
        "recorder latency ms p50/p99/max   node (encoder) latency ms"
    )
    lost_total = 0
    for t in TOPICS:
        a = acc[t]
        rec, wr = received[t]["present"], said[t]["present"]
        assert wr == a["delivered"], (t, wr, a)  # metadata.yaml says what the bag holds
        lost = a["lost"] + max(0, wr - rec)  # the node may not miss what the bag has
        lost_total += lost
        stamps, log_ns = msgs[t]
        keep = (stamps >= lo - dt // 2) & (stamps < hi - dt // 2)
        rec_lat = _pct((log_ns[keep] - stamps[keep]) * 1e-6)
        nl = node_lat if t == "encoder" else ""
        print(f"   {t:<16} {a['published']:>9} {rec:>9} {wr:>9} {lost:>5}   {rec_lat}   {nl}")
    cpu = ", ".join(f"{k} {v:.1f} s" for k, v in res.cpu_s.items() if v is not None)
    c1 = os.times()
    print(f"   CPU time of the nodes: {cpu}; this script {c1.user - c0.user:.1f} s")
    return lost_total


def driver_5k(domain: int, seconds: float) -> None:
    """The driver alone at 5 kHz and one subscriber: what is delivered."""
    from helpers.driver_harness import DriverProcess

    rate, dt = 5000.0, 200_000
    sub = subprocess.Popen(  # as run_session starts the recorder
        [sys.executable, "-c", SUBSCRIBER, str(rate)],
        env=node_env(domain),
        stdout=subprocess.PIPE,
        text=True,
        preexec_fn=priority_setter(-5, realtime=True),
    )
    assert sub.stdout is not None
    sub.stdout.readline()  # "ready"
    params = {"rate_hz": rate, "watchdog_s": 0.0}
    with DriverProcess(params, domain_id=domain, realtime=True) as drv:
        sub.stdout.readline()  # "receiving": every topic matched and flowing
        time.sleep(seconds)  # the measured window itself: a fixed duration by design
        sub.send_signal(signal.SIGINT)  # it takes every sample published before this
        report = json.loads(sub.communicate(timeout=300)[0])
        drv.stop()
    arr = {t: np.array(v, dtype=np.int64).reshape(-1, 2) for t, v in report["got"].items()}
    # the window: from the first stamp every topic has, up to the stop
    lo = max(int(a[:, 0].min()) for a in arr.values() if a.size)
    hi = int(report["stop_ns"]) - 100_000_000
    hi = lo + ((hi - lo) // dt) * dt
    skipped = _skipped(drv.stderr, lo, hi, dt)
    acc = _account({t: a[:, 0] for t, a in arr.items()}, lo, hi, dt, skipped)
    info = acc.pop("_")
    print(
        f"\n2) driver alone at 5 kHz, one raw subscriber (10 s deep, as the recorder): "
        f"{info['expected']} samples per topic in {(hi - lo) * 1e-9:.1f} s"
    )
    print(
        f"   driver skipped after host stalls (its log): {skipped}; missing on all three "
        f"topics: {info['all_three_missing']}"
    )
    print(
        f"   {'topic':<16} {'published':>9} {'delivered':>9} {'lost':>5}   latency ms p50/p99/max"
    )
    for t in TOPICS:
        a, x = acc[t], arr[t]
        keep = (x[:, 0] >= lo - dt // 2) & (x[:, 0] < hi - dt // 2)
        lat = _pct((x[keep, 1] - x[keep, 0]) * 1e-6)
        print(f"   {t:<16} {a['published']:>9} {a['delivered']:>9} {a['lost']:>5}   {lat}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate5k-s", type=float, default=10.0, help="5 kHz run length, s")
    ap.add_argument("--no-hogs", action="store_true", help="without the two CPU hogs")
    ap.add_argument("--skip-session", action="store_true", help="only the 5 kHz run")
    args = ap.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    hogs = [] if args.no_hogs else _hogs(2)
    print(f"bench_stress: {len(hogs)} CPU hog processes; load average before: {_load()}")
    lost = 0
    try:
        with allocate_domain(purpose="bench_stress") as lock:
            if not args.skip_session:
                lost = session(lock.domain_id)
            driver_5k(lock.domain_id, args.rate5k_s)
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    print(f"\nload average after: {_load()} (1, 5, 15 min; 2 cores)")
    if lost:
        print(f"SAMPLES LOST AT 1 kHz: {lost}")
    return 1 if lost else 0


if __name__ == "__main__":
    sys.exit(main())
