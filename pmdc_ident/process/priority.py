"""Scheduling of the nodes that close the loop (no ROS import here).

A motor loop and its recorder must not wait behind a compiler or another program:
the driver, recorder and identification nodes run SCHED_RR at :data:`RT_PRIORITY`
where the system permits it (root, CAP_SYS_NICE or an RLIMIT_RTPRIO; the kernel
still keeps 5 % of each second for other tasks), else at a raised nice where
permitted, else normally. ``bringup`` sets it for its children before they start
(:func:`priority_setter`); a node started by ``ros2 run`` or ``ros2 launch`` sets
it for itself at start-up (:func:`raise_own_priority`, called by
``runtime.run_node``), unless ``PMDC_IDENT_REALTIME=0``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = [
    "NODE_NICE",
    "RT_PRIORITY",
    "priority_setter",
    "raise_own_priority",
    "realtime_thread",
]

# SCHED_RR priority of the session's nodes where the system permits it: low among
# real-time tasks (the kernel's own threads use 50 and more).
RT_PRIORITY = 10


def priority_setter(nice: int, realtime: bool) -> Callable[[], None]:
    """A ``preexec_fn`` giving a child node its scheduling before it starts any thread.

    ``realtime``: SCHED_RR at :data:`RT_PRIORITY` where the system permits it (root,
    CAP_SYS_NICE or an RLIMIT_RTPRIO), so a node closing the loop is never queued
    behind CPU-bound work (the kernel keeps 5 % of each second for other tasks);
    otherwise, and for the others, ``nice`` (a negative value raises the priority)
    where permitted. Nothing is refused: on a plain account the node runs normally.
    """

    def set_priority() -> None:  # runs in the child before exec
        if realtime:
            try:
                os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(RT_PRIORITY))
                return
            except (OSError, AttributeError):
                pass  # not permitted: nice instead
        if nice:
            try:
                os.setpriority(os.PRIO_PROCESS, 0, nice)
            except OSError:
                pass  # not permitted: run at the normal priority

    return set_priority


@contextmanager
def realtime_thread(priority: int = RT_PRIORITY) -> Iterator[bool]:
    """This thread (and the threads it starts meanwhile) at the nodes' SCHED_RR priority.

    For an in-process ROS client that talks to the nodes (the step demo, a test's
    client): enter before ``rclpy.init`` so DDS's threads inherit it. Yields whether
    the system permitted it; the previous scheduling is restored on exit. A higher
    ``priority`` preempts the nodes (a test's stand-in for a board's microcontroller).
    """
    try:
        old = os.sched_getscheduler(0), os.sched_getparam(0)
        os.sched_setscheduler(0, os.SCHED_RR, os.sched_param(priority))
    except (OSError, AttributeError):
        yield False
        return
    try:
        yield True
    finally:
        os.sched_setscheduler(0, old[0], old[1])


NODE_NICE = -5  # where SCHED_RR is not permitted


def raise_own_priority() -> str:
    """This process at the loop's priority unless its parent already chose one, or
    ``PMDC_IDENT_REALTIME=0``; what it runs at, in words (for the start-up log)."""
    try:
        policy = os.sched_getscheduler(0)
    except (OSError, AttributeError):
        return "normal scheduling"
    if os.environ.get("PMDC_IDENT_REALTIME", "1") == "0":
        return "normal scheduling (PMDC_IDENT_REALTIME=0)"
    if policy == os.SCHED_OTHER and os.getpriority(os.PRIO_PROCESS, 0) == 0:
        priority_setter(NODE_NICE, realtime=True)()
        policy = os.sched_getscheduler(0)
    if policy == os.SCHED_RR:
        return f"SCHED_RR priority {os.sched_getparam(0).sched_priority}"
    return f"nice {os.getpriority(os.PRIO_PROCESS, 0)}"
