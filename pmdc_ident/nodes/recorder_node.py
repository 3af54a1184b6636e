"""The recorder node: every identification session into its own rosbag2/MCAP bag.

It subscribes to the driver's sample topics *raw* (CDR bytes, no Python message
objects) and writes them unchanged, so it keeps up with 1 kHz. A bag
``<output_dir>/<session>/`` (``metadata.yaml`` + one ``.mcap``) is opened when the
identification node's ``session_start`` marker arrives; driver samples are kept in
a short ring so none stamped at or after the session start is lost while the
marker travels. The bag holds the driver samples with ``start <= stamp < end``
(``margin_s`` widens that), every marker, the commands, progress and status, and
is closed when all driver topics have passed the session's end, on Ctrl-C or
SIGTERM (metadata written, readable by rosbags and mcap_ros2).

Publishes ``recorder_status`` (std_msgs/String JSON, reliable, transient-local):
heartbeat at 5 Hz with the state, session, bag path and samples written.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, String

from pmdc_ident.core.enums import ExitCode
from pmdc_ident.core.errors import PmdcError
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.dataio.bagio import TOPIC_TYPES, BagWriter, header_stamp_ns
from pmdc_ident.dataio.completeness import Completeness, completeness
from pmdc_ident.nodes.parameters import declare
from pmdc_ident.nodes.qos import COMMAND_QOS, LATCHED_QOS, SEGMENT_QOS, sample_qos
from pmdc_ident.nodes.runtime import run_node
from pmdc_ident.process.parameter_tables import RECORDER

__all__ = ["RecorderNode", "main"]

NODE_NAME = "recorder_node"
DRIVER_TOPICS = ("current", "encoder", "voltage_applied")
# topic -> (type in the bag, rclpy type, QoS); driver topics are added with the rate's QoS
OTHER_TOPICS: dict[str, tuple[str, Any, QoSProfile]] = {
    "voltage_cmd": (TOPIC_TYPES["voltage_cmd"], Float64, COMMAND_QOS),
    "segment": (TOPIC_TYPES["segment"], String, SEGMENT_QOS),
    "progress": ("std_msgs/msg/String", String, LATCHED_QOS),
    "status": ("std_msgs/msg/String", String, LATCHED_QOS),
}


class RecorderNode(Node):
    def __init__(self, **kwargs: Any) -> None:
        super().__init__(NODE_NAME, **kwargs)
        values = declare(self, RECORDER)
        self.output_dir = Path(values["output_dir"]).expanduser().absolute()  # bags named anywhere
        rate = float(values["rate_hz"]) or 1000.0
        self.margin_ns = int(float(values["margin_s"]) * 1e9)
        self.half_dt_ns = int(0.5e9 / rate)
        self.hold_ns = int(float(values["hold_s"]) * 1e9)
        hold_s = float(values["hold_s"])
        ring_n = int(3 * rate * max(float(values["ring_s"]), 2 * hold_s, 0.5))
        self.ring: deque[tuple[str, int, bytes, int]] = deque(maxlen=ring_n)
        self.writer: BagWriter | None = None
        self.session = ""
        self.start_ns = 0
        self.end_ns: int | None = None
        self.last_ns = dict.fromkeys(DRIVER_TOPICS, -1)
        self._last_arrival = -math.inf  # monotonic time the last driver sample arrived
        self._lag_base_ns = math.inf  # smallest arrival - stamp seen
        self._lag_ns = dict.fromkeys(DRIVER_TOPICS, math.inf)  # of each topic's newest sample
        self._written: dict[str, list[int]] = {t: [] for t in DRIVER_TOPICS}  # stamps, ns
        self.samples = 0
        self.bags: list[str] = []
        self.finished = False  # a signal arrived: drain, close, exit
        self.exit_code: int = ExitCode.OK
        self.last_missing = 0  # driver samples missing from the last bag closed
        from rosbags.typesys import Stores, get_typestore

        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        types = {t: "sensor_msgs/msg/JointState" for t in DRIVER_TOPICS}
        types.update({t: v[0] for t, v in OTHER_TOPICS.items()})
        self._name: dict[str, str] = {}  # relative topic -> resolved name in the bag
        qos = sample_qos(rate)
        for topic in DRIVER_TOPICS:
            sub = self.create_subscription(
                JointState, topic, self._driver_cb(topic), qos, raw=True
            )
            self._name[topic] = sub.topic_name
        for topic, (_, msg_type, tqos) in OTHER_TOPICS.items():
            cb = self._on_segment if topic == "segment" else self._other_cb(topic)
            sub = self.create_subscription(msg_type, topic, cb, tqos, raw=True)
            self._name[topic] = sub.topic_name
        self._topics = {self._name[t]: types[t] for t in types}
        self.pub_status = self.create_publisher(String, "recorder_status", LATCHED_QOS)
        self.create_timer(0.2, self._heartbeat)
        self._heartbeat()
        self.get_logger().info(f"recorder ready: bags go to {self.output_dir}")

    # -- callbacks ----------------------------------------------------------------------------
    def _driver_cb(self, topic: str) -> Any:
        def cb(raw: bytes) -> None:
            ns = header_stamp_ns(raw)
            first = self.last_ns[topic] < 0
            self.last_ns[topic] = ns
            self._last_arrival = time.monotonic()
            raw_lag = time.time_ns() - ns  # arrival - stamp (a board's clock may be offset)
            self._lag_base_ns = min(self._lag_base_ns, raw_lag)
            self._lag_ns[topic] = raw_lag - self._lag_base_ns
            self.ring.append((topic, ns, raw, time.time_ns()))
            if first and min(self.last_ns.values()) >= 0:
                self._heartbeat()  # receiving on all topics: a session may start now
            if self.writer is not None:
                self._drain(ns - self.hold_ns)
                end = self.end_ns
                if end is not None and min(self.last_ns.values()) >= (
                    end + self.margin_ns + self.hold_ns
                ):
                    self._drain_rest_and_close("session ended")

        return cb

    def _in_window(self, ns: int) -> bool:
        lo = self.start_ns - self.margin_ns - self.half_dt_ns
        hi = None if self.end_ns is None else self.end_ns + self.margin_ns - self.half_dt_ns
        return ns >= lo and (hi is None or ns < hi)

    def _drain(self, before_ns: int | None) -> None:
        """Write the held driver samples older than ``before_ns`` (all: None) in the window.

        Samples are held ``hold_s`` before they are written, so the ones stamped after
        the session's end (whose marker travels on another topic) stay out of the bag.
        """
        w = self.writer
        ring = self.ring
        while ring and (before_ns is None or ring[0][1] < before_ns):
            topic, ns, raw, log_ns = ring.popleft()
            if w is not None and self._in_window(ns):
                self._write_sample(w, topic, ns, raw, log_ns)

    def _write_sample(self, w: BagWriter, topic: str, ns: int, raw: bytes, log_ns: int) -> None:
        w.write_raw(self._name[topic], log_ns, raw)
        self._written[topic].append(ns)
        if topic == "encoder":
            self.samples += 1

    def _drain_rest_and_close(self, why: str) -> None:
        """Write every held sample inside the window (the ring is in arrival order, not
        stamp order, across topics), keep the later ones for a next session, close."""
        w = self.writer
        if w is not None:
            keep: deque[tuple[str, int, bytes, int]] = deque(maxlen=self.ring.maxlen)
            for topic, ns, raw, log_ns in self.ring:
                if self._in_window(ns):
                    self._write_sample(w, topic, ns, raw, log_ns)
                elif self.end_ns is not None and ns >= self.end_ns:
                    keep.append((topic, ns, raw, log_ns))
            self.ring = keep
        self._close(why)

    def _other_cb(self, topic: str) -> Any:
        def cb(raw: bytes) -> None:
            if self.writer is not None:
                self.writer.write_raw(self._name[topic], time.time_ns(), raw)

        return cb

    def _on_segment(self, raw: bytes) -> None:
        text = self._typestore.deserialize_cdr(raw, "std_msgs/msg/String").data
        try:
            m = Marker.from_json(text)
        except PmdcError:
            return
        if m.event is MarkerEvent.SESSION_START and m.session != self.session:
            oldest = self.ring[0][1] if self.ring else None
            if oldest is not None and round(m.t_s * 1e9) < oldest - 1_000_000_000:
                return  # a stale (transient-local) marker of a session long gone
            self._open(m)
        if self.writer is not None and m.session == self.session:
            self.writer.write_raw(self._name["segment"], time.time_ns(), raw)
            if m.event is MarkerEvent.SESSION_END:
                self.end_ns = round(m.t_s * 1e9)

    # -- bag ----------------------------------------------------------------------------------
    def _open(self, m: Marker) -> None:
        if self.writer is not None:
            self._drain_rest_and_close(f"new session {m.session} started")
        name = m.session or f"session_{int(time.time())}"
        path = self.output_dir / name
        k = 1
        while path.exists():
            k += 1
            path = self.output_dir / f"{name}_{k}"
        self.output_dir.mkdir(parents=True, exist_ok=True)
        self.writer = BagWriter(path, self._topics).open()
        self.session, self.start_ns, self.end_ns, self.samples = (
            m.session,
            round(m.t_s * 1e9),
            None,
            0,
        )
        self._written = {t: [] for t in DRIVER_TOPICS}
        # held samples from before the start marker arrived are written by _drain
        self.get_logger().info(f"recording session {m.session} into {path}")
        self._heartbeat()

    def _close(self, why: str) -> None:
        w = self.writer
        if w is None:
            return
        self.writer = None
        found = self._completeness()
        w.set_custom_data("pmdc_ident.driver_samples", json.dumps(found.to_dict()))
        w.close()
        self.bags.append(str(w.path))
        self.last_missing = found.missing
        log = self.get_logger().warning if found.missing else self.get_logger().info
        log(
            f"bag closed ({why}): {w.path} with {self.samples} driver samples, "
            + ", ".join(f"{t} {n}" for t, n in w.counts.items())
            + f"; {found.line()}"
        )
        self._heartbeat(closed=str(w.path))

    def _completeness(self) -> Completeness:
        """The session's driver samples written vs the stamp grid (interrupted: up to the last)."""
        stamps = {t: np.asarray(v, dtype=np.int64) for t, v in self._written.items()}
        enc = np.unique(stamps["encoder"])
        dt_ns = int(np.median(np.diff(enc))) if enc.size > 2 else self.half_dt_ns * 2
        end = self.end_ns
        if end is None:  # interrupted: the session ran up to the newest sample written
            end = max((int(v.max()) for v in stamps.values() if v.size), default=self.start_ns)
            end += dt_ns
        return completeness(stamps, self.start_ns, end, dt_ns)

    def _heartbeat(self, closed: str = "") -> None:
        if self.writer is not None:
            self.writer.flush()  # a killed recorder loses at most the last 0.5 s
        if self.end_ns is not None and self.writer is not None:
            # The driver stopped: no sample arrived for a while (a recorder working
            # through a backlog still receives, so it is not closed early).
            if time.monotonic() - self._last_arrival > self.hold_ns * 1e-9 + 2.0:
                self._drain_rest_and_close("session ended (driver samples stopped)")
                return
        d = {
            "state": "recording" if self.writer is not None else "idle",
            "session": self.session,
            "path": str(self.writer.path) if self.writer is not None else closed,
            "samples": self.samples,
            "bags": self.bags[-5:],
            # newest driver stamp received per topic (-1: none yet): the identification
            # node starts a session only once all three arrive here
            "receiving": dict(self.last_ns),
            "missing_last_bag": self.last_missing,
        }
        self.pub_status.publish(String(data=json.dumps(d)))

    def caught_up(self) -> bool:
        """Every driver sample of the open bag that was published before now is taken.

        True when the session's end passed on every topic, when the newest sample of
        every topic arrived within 0.1 s of its stamp (no backlog queued in DDS), or
        when nothing arrived for 0.5 s (the driver is gone).
        """
        if self.writer is None or time.monotonic() - self._last_arrival > 0.5:
            return True
        if self.end_ns is not None and min(self.last_ns.values()) >= self.end_ns + self.margin_ns:
            return True
        return max(self._lag_ns.values()) < 100_000_000

    # -- ManagedNode (pmdc_ident.nodes.runtime) ---------------------------------------------
    def request_stop(self) -> None:
        self.finished = True

    def wind_down(self, spin_once: Any) -> None:
        """Stopped (Ctrl-C, SIGTERM): first take the samples still queued for us, so a
        recorder that fell behind on a loaded machine writes them before closing."""
        deadline = time.monotonic() + 8.0  # bringup waits 10 s before SIGTERM
        while not self.caught_up() and time.monotonic() < deadline:
            spin_once(0.05)

    def close(self) -> list[str]:
        if self.writer is not None:
            self._drain_rest_and_close("shutdown")
        return [f"bag {b}" for b in self.bags]


def main(args: list[str] | None = None) -> int:
    return run_node(NODE_NAME, RecorderNode, args, realtime=True)


if __name__ == "__main__":
    sys.exit(main())
