#!/usr/bin/env python3
"""Another node of a robot's stack consuming a pmdc_ident result (docs/integration.md).

    python3 examples/result_listener.py                          # root namespace
    python3 examples/result_listener.py --namespace left_wheel   # one wheel of a robot
    python3 examples/result_listener.py --run                    # ask for a session first

It needs rclpy and the standard message packages only, not pmdc_ident: that is how a
controller package of your own would consume the result. It subscribes to
``identified_parameters`` (JSON, reliable + transient-local: a node started after the
result was published still gets it) and to ``identified_parameters/R`` (the same
number as a ``std_msgs/Float64MultiArray``), checks ``schema_version``, and prints the
model a controller would use, each value with its 95 % interval. With ``--run`` it first
calls the identification node's ``run_session`` service (a node launched with
``autostart:=false exit_when_done:=false``). Exit status 0 with a result, 1 when none
came within ``--timeout``, 2 for a document of another schema version.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import Float64MultiArray, String
from std_srvs.srv import Trigger

SCHEMA_VERSION = 1  # the result document this consumer was written for
LATCHED = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)


def describe(doc: dict[str, Any]) -> list[str]:
    """The lines this example prints for a result document (raises ValueError for a
    document of a schema version it does not know)."""
    version = doc.get("schema_version")
    if version != SCHEMA_VERSION:
        msg = f"result schema_version {version!r}, this consumer reads {SCHEMA_VERSION}"
        raise ValueError(msg)
    lines = [f"model {doc['model']} identified from {', '.join(doc['sources'])}"]
    for name, p in doc["parameters"].items():
        ci = p["ci95"]
        interval = f"[{ci[0]:.5g}, {ci[1]:.5g}]" if ci else "(no interval)"
        note = "" if p["identifiable"] else f"  NOT MEASURED: {p['reason']}"
        lines.append(f"  {name:<28} {p['value']:>12.6g} {p['unit']:<10} {interval}{note}")
    return lines


class ResultListener(Node):
    def __init__(self, namespace: str) -> None:
        super().__init__("result_listener", namespace=namespace)
        self.doc: dict[str, Any] | None = None
        self.r_array: list[float] | None = None
        self.r_label = ""
        self.create_subscription(String, "identified_parameters", self._on_result, LATCHED)
        self.create_subscription(Float64MultiArray, "identified_parameters/R", self._on_r, LATCHED)
        self.run_client = self.create_client(Trigger, "run_session")

    def _on_result(self, msg: String) -> None:
        self.doc = json.loads(msg.data)

    def _on_r(self, msg: Float64MultiArray) -> None:
        self.r_array = list(msg.data)
        self.r_label = msg.layout.dim[0].label if msg.layout.dim else ""


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--namespace", default="", help="the identification node's namespace")
    ap.add_argument("--run", action="store_true", help="call run_session first")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds to wait")
    args = ap.parse_args(argv)
    rclpy.init()
    node = ResultListener(args.namespace)
    end = time.monotonic() + args.timeout
    try:
        if args.run:
            if not node.run_client.wait_for_service(timeout_sec=args.timeout):
                print("no run_session service", file=sys.stderr)
                return 1
            future = node.run_client.call_async(Trigger.Request())
            rclpy.spin_until_future_complete(node, future, timeout_sec=args.timeout)
            answer = future.result()
            print(f"run_session: {answer.success} ({answer.message})" if answer else "no answer")
        while (node.doc is None or node.r_array is None) and time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.1)
        if node.doc is None:
            print(f"no result within {args.timeout:g} s", file=sys.stderr)
            return 1
        try:
            lines = describe(node.doc)
        except ValueError as exc:
            print(exc, file=sys.stderr)
            return 2
        print("\n".join(lines))
        if node.r_array is not None:
            print(f"identified_parameters/R: {node.r_array} ({node.r_label})")
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    sys.exit(main())
