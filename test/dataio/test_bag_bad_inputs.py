"""Bags that are not ours, broken or odd: one clear line and exit 2 from identify and export."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_USER_ERROR, main
from pmdc_ident.dataio.bagio import TOPIC_TYPES, BagWriter, _joint_state, write_bag
from pmdc_ident.dataio.csvio import read_csv

TABLE = FIXTURES / "seed000_table4.csv"
DRIVER = {"/encoder": TOPIC_TYPES["encoder"], "/voltage_applied": TOPIC_TYPES["voltage_applied"]}


def _driver_bag(path: Path, n: int, position, velocity, stamp=lambda k: k * 10**6) -> Path:
    with BagWriter(path, DRIVER) as w:
        for k in range(n):
            enc = {}
            if position is not None:
                enc["position"] = [position(k)]
            if velocity is not None:
                enc["velocity"] = [velocity(k)]
            w.write_msg("/encoder", k * 10**6, _joint_state(w.typestore, stamp(k), ["s"], **enc))
            volt = _joint_state(w.typestore, stamp(k), ["a"], effort=[1.0])
            w.write_msg("/voltage_applied", k * 10**6, volt)
    return path


def _make(case: str, w: Path) -> Path:
    good = write_bag(read_csv(TABLE), w / "good", session="s")
    mcap = next(good.glob("*.mcap"))
    match case:
        case "an empty .mcap":
            (w / "e.mcap").write_bytes(b"")
            return w / "e.mcap"
        case "random bytes as .mcap":
            (w / "r.mcap").write_bytes(np.random.default_rng(0).bytes(5000))
            return w / "r.mcap"
        case "an empty folder":
            (w / "d").mkdir()
            return w / "d"
        case "corrupt metadata.yaml":
            (good / "metadata.yaml").write_text("rosbag2_bagfile_information: [1,2\n")
            return good
        case "metadata.yaml without its .mcap":
            mcap.unlink()
            return good
        case "a bag of other topics":
            with BagWriter(w / "o", {"/chatter": "std_msgs/msg/String"}) as bw:
                msg = bw.typestore.types["std_msgs/msg/String"]
                for k in range(5):
                    bw.write_msg("/chatter", k * 1000, msg(data="hi"))
            return w / "o"
        case "JointStates with empty arrays":
            return _driver_bag(w / "j", 5, None, None)
        case "every stamp equal":
            return _driver_bag(w / "s", 5, float, float, stamp=lambda k: 0)
        case "1e300 in a bag":
            return _driver_bag(w / "h", 50, lambda k: k * 1e300, lambda k: 1e300)
        case "encoder topic of another type":
            with BagWriter(w / "t", {**DRIVER, "/encoder": "std_msgs/msg/String"}) as bw:
                msg = bw.typestore.types["std_msgs/msg/String"]
                for k in range(5):
                    bw.write_msg("/encoder", k * 10**6, msg(data="x"))
                    volt = _joint_state(bw.typestore, k * 10**6, ["a"], effort=[1.0])
                    bw.write_msg("/voltage_applied", k * 10**6, volt)
            return w / "t"
    raise AssertionError(case)


CASES = {
    "an empty .mcap": "empty",
    "random bytes as .mcap": "not a readable rosbag2/MCAP bag",
    "an empty folder": "without metadata.yaml",
    "corrupt metadata.yaml": "metadata.yaml",
    "metadata.yaml without its .mcap": "missing",
    "a bag of other topics": "no 'encoder' topic in the bag (topics: /chatter)",
    "JointStates with empty arrays": "neither position nor speed",
    "every stamp equal": "fewer than 2 driver samples",
    "1e300 in a bag": "beyond any motor test",
    "encoder topic of another type": "pmdc_ident reads sensor_msgs/msg/JointState there",
}


@pytest.mark.parametrize("case", sorted(CASES))
@pytest.mark.parametrize("command", ["identify", "export"])
def test_bad_bag_is_one_line_and_exit_2(case, command, tmp_path, capsys):
    bag = _make(case, tmp_path)
    argv = [command, str(bag), "--quiet"]
    if command == "export":
        argv = [command, str(bag), "--csv", str(tmp_path / "out.csv")]
    rc = main(argv)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, err
    assert len(lines) == 1 and lines[0].startswith(f"pmdc-ident {command}: error:"), err
    assert CASES[case] in lines[0], err
    assert not (tmp_path / "out.csv").exists()


def test_a_bag_folder_copied_whole_still_reads(tmp_path, capsys):
    good = write_bag(read_csv(TABLE), tmp_path / "good", session="s")
    shutil.copytree(good, tmp_path / "copy")
    assert main(["export", str(tmp_path / "copy"), "--csv", str(tmp_path / "o.csv")]) == 0
    assert read_csv(tmp_path / "o.csv").labels == read_csv(TABLE).labels
