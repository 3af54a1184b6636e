"""The QoS profiles of the session graph, in one place (driver, identification, recorder).

- Driver samples (``current``, ``encoder``, ``voltage_applied``): :func:`sample_qos`,
  RELIABLE, KEEP_LAST :data:`SAMPLE_BUFFER_S` seconds of samples, VOLATILE, on the
  publisher and on every subscriber. Every sample counts: a bag or a fit must not
  lose one silently.
- ``voltage_cmd``: :data:`COMMAND_QOS`, RELIABLE KEEP_LAST(10), the ROS default a
  controller publishes with (a reliable subscription would not match best effort).
- ``segment`` markers: :data:`SEGMENT_QOS`, RELIABLE KEEP_LAST(1000) TRANSIENT_LOCAL,
  so a recorder that joins late still gets the session's start marker.
- ``progress``, ``status``, results, ``recorder_status``: :data:`LATCHED_QOS`,
  RELIABLE KEEP_LAST(1) TRANSIENT_LOCAL: the last state, for late joiners.
- ``/diagnostics``: :data:`DIAGNOSTICS_QOS`, RELIABLE KEEP_LAST(10), the usual profile.

Why the sample depth is the same long buffer on both ends: a RELIABLE KEEP_LAST
writer can re-send a sample a reader missed only while it is still in the writer's
history. On a loaded machine a reader's receive thread can be descheduled for a
second or more; the kernel then drops datagrams from its full socket buffer, and
the repair (heartbeat, negative acknowledgement, re-send) comes only after Fast
DDS's heartbeat period (3 s by default). With one second of history in the driver
(the old depth) those samples were overwritten before they could be re-sent: lost
for good, a fifth of a session under load. Ten seconds on the writer covers the
repair cycle and such stalls; ten seconds on the reader let its executor fall
behind as long without dropping.
"""

from __future__ import annotations

import math

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = [
    "COMMAND_QOS",
    "DIAGNOSTICS_QOS",
    "LATCHED_QOS",
    "SAMPLE_BUFFER_S",
    "SEGMENT_QOS",
    "sample_qos",
]

# Seconds of driver samples buffered on each side of a sample topic. A process on
# a busy 2-core machine was seen to stall for up to ~2 s; 10 s leaves a margin.
SAMPLE_BUFFER_S = 10.0


def sample_qos(rate_hz: float, seconds: float = SAMPLE_BUFFER_S) -> QoSProfile:
    """Driver sample topics: RELIABLE, KEEP_LAST ``seconds`` of samples, VOLATILE."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=max(10, int(math.ceil(max(rate_hz, 1.0) * seconds))),
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


COMMAND_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
)
DIAGNOSTICS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=10, reliability=ReliabilityPolicy.RELIABLE
)
SEGMENT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1000,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
