"""The recorder keeps every driver sample of a session whose start marker comes late.

The ``segment`` topic is reliable: a marker datagram lost on a loaded host is sent again
when the identification node's writer next sends a heartbeat (Fast DDS: every 3 s by
default), so the session's start marker can reach the recorder seconds after the
samples it starts at. The recorder holds the samples that arrive while no bag is open in
a ring; a ring shorter than that delay lost the session's first samples (a CI run at
load 1: 49 driver samples missing at 0.0 s of an emulated-board session).

The node runs in this process on its own DDS domain, fed through its callbacks with CDR
bytes as DDS hands them over (no spin): the ring's length is what is checked, not DDS.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

rclpy = pytest.importorskip("rclpy")

from rclpy.context import Context  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosbags.typesys import Stores, get_typestore  # noqa: E402

from pmdc_ident.core.markers import Marker, MarkerEvent  # noqa: E402
from pmdc_ident.nodes.qos import SAMPLE_BUFFER_S  # noqa: E402
from pmdc_ident.nodes.recorder_node import DRIVER_TOPICS, RecorderNode  # noqa: E402

RATE_HZ = 1000.0
T0_NS = 1_700_000_000 * 1_000_000_000


_TS = get_typestore(Stores.ROS2_JAZZY)


def _joint_state_cdr() -> bytes:
    """One driver sample (a JointState of one joint) as CDR; the stamp is patched in."""
    t = _TS.types
    one = np.array([0.5])
    msg = t["sensor_msgs/msg/JointState"](
        header=t["std_msgs/msg/Header"](
            stamp=t["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id=""
        ),
        name=["m"],
        position=one,
        velocity=one,
        effort=one,
    )
    return bytes(_TS.serialize_cdr(msg, "sensor_msgs/msg/JointState"))


def _stamped(raw: bytes, ns: int) -> bytes:
    sec, nsec = divmod(ns, 1_000_000_000)
    return raw[:4] + sec.to_bytes(4, "little") + nsec.to_bytes(4, "little") + raw[12:]


def _marker(event: MarkerEvent, t_ns: int) -> bytes:
    text = Marker(event, "", t_ns * 1e-9, session="late_start").to_json()
    msg = _TS.types["std_msgs/msg/String"](data=text)
    return bytes(_TS.serialize_cdr(msg, "std_msgs/msg/String"))


def test_a_start_marker_as_late_as_the_dds_buffer_loses_no_sample(
    tmp_path: Path, ros_domain: int
) -> None:
    delay_s = SAMPLE_BUFFER_S - 1.0  # a marker this late: its samples are still in DDS
    raw = _joint_state_cdr()
    ctx = Context()
    rclpy.init(args=[], context=ctx, domain_id=ros_domain)
    try:
        node = RecorderNode(
            context=ctx,
            parameter_overrides=[
                Parameter("output_dir", value=str(tmp_path)),
                Parameter("rate_hz", value=RATE_HZ),
            ],
        )
        cbs = {t: node._driver_cb(t) for t in DRIVER_TOPICS}
        dt = int(1e9 / RATE_HZ)
        start_ns = T0_NS + 1_000_000_000
        end_ns = start_ns + 2_000_000_000
        late_at = start_ns + int(delay_s * 1e9)
        after = late_at + 1_000_000_000  # the end marker (late too) and the hold passed
        k = 0
        while T0_NS + k * dt < after:
            ns = T0_NS + k * dt
            if ns == late_at:
                node._on_segment(_marker(MarkerEvent.SESSION_START, start_ns))
            if ns == late_at + 10 * dt:
                node._on_segment(_marker(MarkerEvent.SESSION_END, end_ns))
            for t in DRIVER_TOPICS:
                cbs[t](_stamped(raw, ns))
            k += 1
        assert node.writer is None, "the bag was not closed at the session's end"
        bags = list(node.bags)
        node.destroy_node()
    finally:
        rclpy.shutdown(context=ctx)
    assert len(bags) == 1
    meta = yaml.safe_load((Path(bags[0]) / "metadata.yaml").read_text())
    said = json.loads(
        meta["rosbag2_bagfile_information"]["custom_data"]["pmdc_ident.driver_samples"]
    )
    assert said["missing_max"] == 0, said
    assert said["topics"]["encoder"]["expected"] == 2000, said
