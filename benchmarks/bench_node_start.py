"""How soon the identification node is up: launch to its 'ready' log line and status.

    .venv/bin/python benchmarks/bench_node_start.py [--repeat 5]

Each run launches ``identification_node`` (``autostart`` off, its own namespace, a DDS
domain no other suite uses) and reads two times: its log line "identification ready"
(stamped right after it published its first status) against the launch, and when a
node in this process receives that status (DDS discovery on top). The naive reference
in the same run: the same node started by an interpreter that imports numba first (as
before numba was imported at the first kernel call). Also used by ``bench_cli.py``.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_READY = re.compile(r"\[(\d+\.\d+)\] \[[^]]*\]: identification ready")
_NODE = "from pmdc_ident.nodes.identification_node import main\nsys.exit(main())\n"
STARTS = {"ours": "import sys\n" + _NODE, "eager numba": "import sys\nimport numba\n" + _NODE}


def _ros_env(env: dict[str, str], domain: int) -> dict[str, str]:
    profiles = str(REPO / "config" / "fastdds_localhost.xml")
    return {
        **env,
        "FASTRTPS_DEFAULT_PROFILES_FILE": profiles,
        "FASTDDS_DEFAULT_PROFILES_FILE": profiles,
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
        "ROS_DOMAIN_ID": str(domain),
    }


def _one(node, code: str, env: dict[str, str], k: int) -> tuple[float, float]:
    """(launch to 'ready', launch to the status received here), seconds."""
    import rclpy
    from std_msgs.msg import String

    from pmdc_ident.nodes.qos import LATCHED_QOS

    got: list[float] = []
    ns = f"/node_start_{os.getpid()}_{k}"
    sub = node.create_subscription(
        String, ns + "/status", lambda _m: got.append(time.perf_counter()), LATCHED_QOS
    )
    t0, e0 = time.perf_counter(), time.time()
    cmd = [sys.executable, "-c", code, "--ros-args", "-r", f"__ns:={ns}"]
    proc = subprocess.Popen(
        [*cmd, "-p", "autostart:=false"],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    while not got and time.perf_counter() - t0 < 30.0:
        rclpy.spin_once(node, timeout_sec=0.005)
    proc.terminate()
    err = proc.communicate(timeout=30)[1].decode(errors="replace")
    node.destroy_subscription(sub)
    m = _READY.search(err)
    ready = float(m.group(1)) - e0 if m else float("nan")
    return ready, (got[0] - t0) if got else float("nan")


def measure_node_start(repeat: int, env: dict[str, str]) -> tuple[list[float], list[float]]:
    """Launch-to-ready seconds of ours and of the eager-numba reference (interleaved)."""
    import rclpy
    from rclpy.node import Node

    from pmdc_ident.process.dds_domain import allocate_domain

    held = allocate_domain(purpose="bench_node_start")
    env = _ros_env(env, held.domain_id)
    os.environ.update({k: v for k, v in env.items() if k.startswith(("FAST", "ROS_"))})
    rclpy.init()
    node = Node("node_start_probe")
    out: dict[str, tuple[list[float], list[float]]] = {k: ([], []) for k in STARTS}
    try:
        for k in range(repeat):
            for name, code in STARTS.items():
                ready, seen = _one(node, code, env, 2 * k + (name != "ours"))
                out[name][0].append(ready)
                out[name][1].append(seen)
    finally:
        node.destroy_node()
        rclpy.shutdown()
    for name, (ready, seen) in out.items():
        print(
            f"  {name:<12} launch to ready {_fmt(ready)} s; status received {_fmt(seen)} s",
            flush=True,
        )
    return out["ours"][0], out["eager numba"][0]


def _fmt(values: list[float]) -> str:
    return f"{statistics.median(values):5.2f} [{min(values):.2f}-{max(values):.2f}]"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    ours, eager = measure_node_start(args.repeat, env)
    ratio = statistics.median(eager) / statistics.median(ours)
    print(f"  ratio {ratio:.2f}x (eager numba / ours, launch to ready)")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
