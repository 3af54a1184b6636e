"""The compiled MCAP scan reads exactly what the rosbags reader reads, or steps aside.

Every case compares :func:`read_driver_arrays` (fast path) with the general
``rosbags`` path on the same file: same stamps, same values, same markers.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from pmdc_ident.core._jit import HAVE_NUMBA
from pmdc_ident.core.data import Run, Segment
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.dataio import bagio, mcap_scan
from pmdc_ident.dataio.bagio import (
    JOINT_STATE,
    STRING,
    _joint_state,
    _read_driver_arrays_fast,
    _typestore,
    read_driver_arrays,
    write_bag,
)
from pmdc_ident.dataio.mcap_scan import scan_driver_topics

FIELDS = (
    "current_ns",
    "current_a",
    "encoder_ns",
    "position_rad",
    "speed_rad_s",
    "voltage_ns",
    "voltage_v",
    "terminal_v",
)


def _general(path: Path, monkeypatch: pytest.MonkeyPatch) -> DriverSamples:
    with monkeypatch.context() as m:
        m.setattr(bagio, "_read_driver_arrays_fast", lambda _p: None)
        return read_driver_arrays(path)


def _assert_same(fast: DriverSamples, slow: DriverSamples) -> None:
    for name in FIELDS:
        a, b = getattr(fast, name), getattr(slow, name)
        assert (a is None) == (b is None), name
        if a is not None:
            assert a.dtype == b.dtype, name
            np.testing.assert_array_equal(a, b, err_msg=name)
    assert fast.markers == slow.markers


def _run(n: int = 300) -> Run:
    rng = np.random.default_rng(3)
    t = np.arange(n) * 1e-3
    v = np.where(t < 0.1, 12.0, -6.0)
    v[-20:] = np.nan  # an open armature at the end
    seg = Segment(
        label="step_up",
        t=t,
        voltage=v,
        current=rng.normal(1.0, 0.1, n),
        position=np.cumsum(rng.normal(0.1, 0.01, n)),
        speed=rng.normal(50.0, 1.0, n),
    )
    return Run((seg,), "test")


def test_a_written_bag_reads_the_same_through_both_paths(tmp_path, monkeypatch) -> None:
    bag = write_bag(_run(), tmp_path / "bag")
    fast = _read_driver_arrays_fast(bag)
    assert fast is not None  # the scan handles rosbags' own MCAP files
    _assert_same(fast, _general(bag, monkeypatch))
    assert len(fast.markers) >= 2


def _write_mcap(path: Path, compression: CompressionType, *, namespace: str = "") -> None:
    """A ROS 2 MCAP file as other tools write it: chunk compression, a namespace,
    a terminal voltage, interleaved topics, an unrelated topic, out-of-order log times."""
    ts = _typestore()
    with path.open("wb") as f:
        w = Writer(f, compression=compression, chunk_size=4096)
        w.start(profile="ros2", library="test")
        ids = {}
        for name, typ in ((JOINT_STATE, JOINT_STATE), (STRING, STRING)):
            text = ts.generate_msgdef(typ, ros_version=2)[0]
            ids[name] = w.register_schema(name=name, encoding="ros2msg", data=text.encode())
        topics = {
            "current": JOINT_STATE,
            "encoder": JOINT_STATE,
            "voltage_applied": JOINT_STATE,
            "segment": STRING,
            "other": STRING,
        }
        chan = {
            k: w.register_channel(f"{namespace}/{k}", "cdr", ids[t]) for k, t in topics.items()
        }
        String = ts.types[STRING]

        def put(topic: str, log_ns: int, msg: object) -> None:
            data = bytes(ts.serialize_cdr(msg, topics[topic]))
            w.add_message(chan[topic], log_time=log_ns, data=data, publish_time=log_ns)

        start = Marker(MarkerEvent.SESSION_START, "", 0.0, "s1")
        put("segment", 0, String(data=start.to_json()))
        put("segment", 0, String(data=Marker(MarkerEvent.START, "a", 0.0, "s1").to_json()))
        put("other", 5, String(data="not a marker"))
        for k in range(200):
            s = 1_000_000 * k
            log = s + (3_000_000 if k % 7 == 0 else 0)  # some messages logged late
            put("current", log, _joint_state(ts, s, ["armature"], effort=[0.01 * k]))
            put("encoder", s, _joint_state(ts, s, ["shaft"], position=[k], velocity=[2.0 * k]))
            eff = [float("nan") if k > 190 else 12.0, 11.5]
            put("voltage_applied", s, _joint_state(ts, s, ["armature"], effort=eff))
        put("segment", 200_000_000, String(data=Marker(MarkerEvent.END, "a", 0.2, "s1").to_json()))
        w.finish()


@pytest.mark.parametrize(
    "compression", [CompressionType.NONE, CompressionType.ZSTD, CompressionType.LZ4]
)
def test_chunk_compression_and_namespaces_read_the_same(tmp_path, monkeypatch, compression):
    path = tmp_path / "other_tool.mcap"
    _write_mcap(path, compression, namespace="/robot1/motor")
    fast = _read_driver_arrays_fast(path)
    assert fast is not None
    _assert_same(fast, _general(path, monkeypatch))
    assert fast.terminal_v is not None and len(fast.markers) == 3
    if HAVE_NUMBA:  # a decompressed chunk is scanned as a file is: no second compilation
        assert [str(s[0]) for s in mcap_scan._walk.signatures] == ["array(uint8, 1d, C)"]


def test_a_cut_short_file_is_left_to_the_general_reader(tmp_path) -> None:
    bag = write_bag(_run(), tmp_path / "bag")
    mcap = next(bag.glob("*.mcap"))
    data = mcap.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])  # a recorder killed mid-write
    assert scan_driver_topics([cut]) is None
    assert _read_driver_arrays_fast(cut) is None


def test_other_storage_and_missing_topics_are_left_to_the_general_reader(tmp_path) -> None:
    bag = write_bag(_run(), tmp_path / "bag")
    sqlite = tmp_path / "sqlite_bag"
    shutil.copytree(bag, sqlite)
    meta = sqlite / "metadata.yaml"
    meta.write_text(
        meta.read_text().replace("storage_identifier: mcap", "storage_identifier: sqlite3")
    )
    assert _read_driver_arrays_fast(sqlite) is None
    assert _read_driver_arrays_fast(tmp_path / "nothing_here") is None


def test_a_malformed_joint_state_is_one_data_error(tmp_path) -> None:
    bag = write_bag(_run(), tmp_path / "bag")
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    # the CDR header of a JointState stamped 0.1 s: flip its endianness flag to big-endian
    marker = b"\x00\x01\x00\x00" + (0).to_bytes(4, "little") + (100_000_000).to_bytes(4, "little")
    k = data.find(marker)
    assert k > 0
    data[k + 1] = 0
    mcap.write_bytes(bytes(data))
    with pytest.raises(DataError, match="not a readable rosbag2/MCAP bag"):
        read_driver_arrays(bag)
