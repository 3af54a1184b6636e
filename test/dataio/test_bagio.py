"""rosbag2/MCAP reading and writing without ROS: round trips and an independent decoder."""

from __future__ import annotations

import numpy as np
import pytest
from helpers.plans import tiny_run

from pmdc_ident.core.data import Run, Segment
from pmdc_ident.core.errors import DataError
from pmdc_ident.core.markers import Marker, MarkerEvent
from pmdc_ident.core.samples import DriverSamples
from pmdc_ident.dataio import load_data
from pmdc_ident.dataio.bagio import (
    assemble_run,
    header_stamp_ns,
    read_bag,
    write_bag,
)

DT = 1e-3
JS = "sensor_msgs/msg/JointState"


@pytest.fixture(scope="module")
def run() -> Run:
    return tiny_run(seed=3)


def _assert_same(a: Run, b: Run) -> None:
    assert a.labels == b.labels
    for sa, sb in zip(a.segments, b.segments, strict=True):
        np.testing.assert_allclose(sb.t, sa.t, atol=1e-9)
        for name in ("voltage", "current", "position", "speed"):
            x, y = getattr(sa, name), getattr(sb, name)
            assert (x is None) == (y is None), name
            if x is not None:
                np.testing.assert_array_equal(np.isnan(x), np.isnan(y))
                np.testing.assert_allclose(y[~np.isnan(y)], x[~np.isnan(x)], rtol=0, atol=0)


def test_run_to_bag_and_back_is_exact_including_open_armature_samples(run, tmp_path):
    bag = write_bag(run, tmp_path / "bag")
    assert (bag / "metadata.yaml").is_file()
    assert len(list(bag.glob("*.mcap"))) == 1
    back = read_bag(bag)
    _assert_same(run, back)
    coast = back.of_kind(run.segments[-1].kind)[0]
    assert coast.open_mask.sum() == run.segments[-1].open_mask.sum() > 0


def test_load_data_reads_the_bag_directory_and_the_bare_mcap_file(run, tmp_path):
    bag = write_bag(run, tmp_path / "bag")
    _assert_same(run, load_data(bag))
    _assert_same(run, load_data(next(bag.glob("*.mcap"))))


def test_independent_mcap_ros2_decoder_reads_every_sample(run, tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    bag = write_bag(run, tmp_path / "bag")
    counts: dict[str, int] = {}
    currents = []
    with next(bag.glob("*.mcap")).open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "current":
                currents.append(msg.effort[0])
    n = sum(s.n for s in run.segments)
    assert counts["current"] == counts["encoder"] == counts["voltage_applied"] == n
    assert counts["segment"] == 2 * len(run.segments) + 2
    np.testing.assert_array_equal(
        np.array(currents), np.concatenate([s.current for s in run.segments])
    )


def test_segments_restarting_at_zero_are_placed_one_after_another(tmp_path):
    t = np.arange(100) * DT
    seg = dict(voltage=np.ones(100), position=np.linspace(0, 1, 100))
    run = Run((Segment("step_up", t, **seg), Segment("step_down", t, **seg)))
    back = read_bag(write_bag(run, tmp_path / "b"))
    assert back.labels == ("step_up", "step_down")
    assert back.segments[1].t[0] == pytest.approx(back.segments[0].t[-1] + DT, abs=1e-9)
    assert back.segments[0].speed is None and back.segments[0].current is None


def test_assemble_drops_samples_missing_from_one_topic_and_cuts_at_markers():
    ns = np.arange(1000, dtype=np.int64) * 1_000_000 + 5_000_000_000
    cur_ns = np.delete(ns, [500])  # one current sample lost
    markers = [
        Marker(MarkerEvent.SESSION_START, "", 5.1, "s"),
        Marker(MarkerEvent.START, "step_up", 5.1, "s"),
        Marker(MarkerEvent.END, "step_up", 5.6, "s"),
        Marker(MarkerEvent.START, "sweep", 5.6, "s"),
        Marker(MarkerEvent.END, "sweep", 5.9, "s"),
    ]
    arrays = DriverSamples(
        current_ns=cur_ns,
        current_a=np.ones(cur_ns.size),
        encoder_ns=ns,
        position_rad=np.zeros(ns.size),
        speed_rad_s=np.zeros(ns.size),
        voltage_ns=ns,
        voltage_v=np.ones(ns.size),
        terminal_v=None,
        markers=tuple(markers),
    )
    run = assemble_run(arrays)
    assert run.labels == ("step_up", "sweep")
    assert run.segments[0].n == 499  # 100..599 minus the lost sample
    assert run.segments[1].n == 300
    assert run.segments[0].t[0] == pytest.approx(0.0, abs=1e-12)
    assert run.segments[1].t[0] == pytest.approx(0.5, abs=1e-12)


def test_epoch_stamps_survive_the_round_trip_to_the_nanosecond(tmp_path):
    # driver stamps are ROS time (~1.8e9 s): as float64 seconds they would lose ~0.2 us
    from pmdc_ident.dataio.bagio import read_driver_arrays

    t0 = 1_795_252_860.840349952
    t = t0 + np.arange(50) * DT
    run = Run((Segment("step_up", t, voltage=np.ones(50), position=np.zeros(50)),))
    bag = write_bag(run, tmp_path / "b")
    ns = read_driver_arrays(bag).encoder_ns
    assert ns.dtype == np.int64
    np.testing.assert_array_equal(ns, np.round(t * 1e9).astype(np.int64))


def test_header_stamp_is_read_from_raw_cdr():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    from pmdc_ident.dataio.bagio import _joint_state

    raw = ts.serialize_cdr(
        _joint_state(ts, 1_700_000_000_123_456_789, ["a"]), "sensor_msgs/msg/JointState"
    )
    assert header_stamp_ns(raw) == 1_700_000_000_123_456_789


def test_a_missing_or_foreign_bag_is_one_clear_error(tmp_path):
    with pytest.raises(DataError, match="no such bag"):
        read_bag(tmp_path / "nope")
    (tmp_path / "junk.mcap").write_bytes(b"not an mcap file")
    with pytest.raises(DataError, match="not a readable"):
        read_bag(tmp_path / "junk.mcap")


@pytest.mark.parametrize(
    ("name", "fields"),
    [
        (["armature"], {"effort": [1.25]}),
        (["shaft"], {"position": [3.5], "velocity": [-7.0]}),
        (["armature", "terminal"], {"effort": [float("nan"), 11.5]}),
        ([], {}),
    ],
)
def test_raw_joint_state_parser_agrees_with_the_rosbags_decoder(name, fields):
    from rosbags.typesys import Stores, get_typestore

    from pmdc_ident.dataio.bagio import _joint_state, parse_joint_state

    ts = get_typestore(Stores.ROS2_JAZZY)
    raw = ts.serialize_cdr(_joint_state(ts, 12_345_678_901, name, **fields), JS)
    stamp, pos, vel, e0, e1 = parse_joint_state(raw)
    assert stamp == 12_345_678_901
    want = [
        fields.get("position", [np.nan])[0],
        fields.get("velocity", [np.nan])[0],
        fields.get("effort", [np.nan])[0],
        (fields.get("effort", [np.nan, np.nan]) + [np.nan])[1],
    ]
    np.testing.assert_array_equal([pos, vel, e0, e1], want)
