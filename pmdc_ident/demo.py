"""Foundation-stage demo (``make demo``): a voltage step through the driver node over DDS.

Starts the driver node (sim backend) in a child process, publishes a 10 V step on
``voltage_cmd`` at 100 Hz for 2 s, records ``current`` and ``encoder``, prints a
short table and the steady state against the motor model, then opens the
armature and stops the driver with SIGINT, checking that it exited 0.

ROS is imported only when the demo runs (this module stays importable without
ROS; the ROS code lives in :mod:`pmdc_ident.nodes.driver_harness`).
"""

from __future__ import annotations

import sys
from typing import Any

from pmdc_ident.core.errors import PmdcError

__all__ = ["main", "run_step_demo"]


def run_step_demo(**kwargs: Any) -> Any:
    """See :func:`pmdc_ident.nodes.driver_harness.run_step_demo` (same keywords)."""
    from pmdc_ident.nodes.driver_harness import apply_ros_env

    apply_ros_env(kwargs.get("domain_id"))  # before any DDS participant exists
    from pmdc_ident.nodes.driver_harness import run_step_demo as _run

    return _run(**kwargs)


def main(argv: list[str] | None = None) -> int:
    del argv
    try:
        res = run_step_demo()
    except PmdcError as exc:
        print(f"demo: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("demo: interrupted", file=sys.stderr)
        return 130
    return 0 if res.driver_exit == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
