"""Fifteen messages a user could not act on, each now one line that says what to do (issue 28).

Each case: the input as a user brought it, the line the command used to print (its
words must be gone), and the words of the fix the line now carries. One line on
stderr, exit status 2, never a traceback.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import pytest
from helpers.paths import FIXTURES

from pmdc_ident.cli import EXIT_USER_ERROR, main

TABLE = FIXTURES / "seed000_table4.csv"
ROWS = "0,1,0.1,0\n0.001,1,0.2,1\n0.002,1,0.3,2\n0.003,1,0.3,3\n"


def _write(name: str, text: str) -> Callable[[Path], list[str]]:
    def make(d: Path) -> list[str]:
        (d / name).write_text(text)
        return [str(d / name)]

    return make


def _folder_of_mcaps(d: Path) -> list[str]:
    from pmdc_ident.dataio.bagio import write_bag
    from pmdc_ident.dataio.csvio import read_csv

    write_bag(read_csv(TABLE), d / "bag", session="s")
    (d / "two").mkdir()
    for k in (1, 2):
        shutil.copy(next((d / "bag").glob("*.mcap")), d / "two" / f"{k}.mcap")
    return [str(d / "two")]


def _folder_of_csvs(d: Path) -> list[str]:
    (d / "logs").mkdir()
    shutil.copy(TABLE, d / "logs" / "a.csv")
    return [str(d / "logs")]


def _twist_encoder(d: Path) -> list[str]:
    """A bag whose /encoder is a TwistStamped (a mobile base's odometry)."""
    from pmdc_ident.dataio.bagio import TOPIC_TYPES, BagWriter

    topics = {**TOPIC_TYPES, "encoder": "geometry_msgs/msg/TwistStamped"}
    topics.pop("voltage_cmd")
    with BagWriter(d / "twist", topics) as w:
        ts = w.typestore
        T = ts.types
        for k in range(20):
            stamp = T["builtin_interfaces/msg/Time"](sec=0, nanosec=k * 1_000_000)
            header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="")
            v3 = T["geometry_msgs/msg/Vector3"](x=float(k), y=0.0, z=0.0)
            tw = T["geometry_msgs/msg/Twist"](linear=v3, angular=v3)
            w.write_msg("encoder", k, T["geometry_msgs/msg/TwistStamped"](header=header, twist=tw))
    return [str(d / "twist")]


# name: (what the user passes, the command's other words, old words, new words)
CASES: dict[str, tuple] = {
    "a CSV without a header line": (
        _write("r.csv", "0.0,12,0.5,0.0\n0.001,12,0.6,0.1\n"),
        ["check"],
        "repeated column",
        ["no header line", "t,voltage,current,position,speed"],
    ),
    "units in the header names": (
        _write("r.csv", "t [s],voltage [V],current [A],speed [rad/s]\n" + ROWS),
        ["check"],
        None,
        ["--column t='t [s]'", "--column speed='speed [rad/s]'"],
    ),
    "a duplicated row": (
        _write("r.csv", "t,voltage,current,speed\n0,1,0.1,0\n0,1,0.1,0\n0.002,1,0.3,2\n"),
        ["check"],
        "runs on clocks of their own",
        ["duplicated row", "remove it"],
    ),
    "decimal commas": (
        _write("r.csv", "t,voltage,current,speed\n0,1,0,5,0\n"),
        ["check"],
        None,
        ["decimal comma", "0.5"],
    ),
    "a folder of .mcap files": (
        _folder_of_mcaps,
        ["check"],
        "is not a rosbag2 bag",
        ["pass one file", "--batch"],
    ),
    "a folder of CSV files": (
        _folder_of_csvs,
        ["identify", "--quiet"],
        "is not a rosbag2 bag",
        ["a folder of CSV files", "--batch"],
    ),
    "a spreadsheet": (_write("r.xlsx", "PK"), ["check"], None, ["save it as CSV"]),
    "a sqlite3 bag file": (_write("r.db3", "SQLite"), ["check"], None, ["convert it"]),
    "a recording given as the motor file": (
        lambda d: [str(TABLE), "--params", str(TABLE)],
        ["monitor"],
        None,
        ["a recording, not a motor file", "identify --yaml"],
    ),
    "an encoder topic of another type": (
        _twist_encoder,
        ["check"],
        "neither position nor speed",
        ["geometry_msgs/msg/TwistStamped", "sensor_msgs/msg/JointState", "republish"],
    ),
    "an empty speed column": (
        _write("r.csv", "t,voltage,current,speed\n0,1,0.1,\n0.001,1,0.2,\n"),
        ["check"],
        None,
        ["--column speed=none"],
    ),
    "NaN written for a missing current": (
        _write("r.csv", "t,voltage,current,speed\n0,1,0.1,0\n0.001,1,NaN,1\n0.002,1,0.3,2\n"),
        ["check"],
        None,
        ["a missing current measurement", "remove the row"],
    ),
    "clock times in the t column": (
        _write("r.csv", "t,voltage,current,speed\n12:00:00.001,1,0.1,0\n12:00:00.002,1,0.2,1\n"),
        ["check"],
        None,
        ["t must be seconds"],
    ),
    "a phase margin no loop has": (
        lambda d: ["seed000_ebike", "--gains", str(d / "g.yaml"), "--phase-margin-deg", "120"],
        ["export-model"],
        "speed_bandwidth_hz must be",
        ["--phase-margin-deg must be >= 10 and <= 89"],
    ),
    "a negative benchmark seed": (
        lambda d: ["--quick", "--seed", "-1"],
        ["benchmark"],
        "internal error",
        ["--seed must be a whole number >= 0"],
    ),
}


@pytest.mark.parametrize("case", list(CASES), ids=list(CASES))
def test_the_message_says_what_to_do(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    make, command, old, new = CASES[case]
    argv = [command[0], *make(tmp_path), *command[1:]]
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == EXIT_USER_ERROR, err
    assert len(err) == 1 and err[0].startswith(f"pmdc-ident {command[0]}: error:"), err
    if old is not None:
        assert old not in err[0], err[0]
    for words in new:
        assert words in err[0], err[0]


def test_a_clock_jump_is_a_gap_not_a_time_unit(tmp_path, capsys):
    """1000 s of a paused logger outweighed the record in the speed/position check and
    read as '--time-unit us'; it is a gap the fit steps over, said as one."""
    import numpy as np
    from helpers.motor_records import Motor, simulate, steps, write_csv

    rec = simulate(Motor(), steps([6.0, 12.0, -8.0, 10.0], 0.3, 1000.0), 1000.0, seed=3)
    rec.t[700:] += 1000.0
    path = write_csv(tmp_path / "jump.csv", rec)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "--time-unit" not in out
    assert "warning: gaps" in out and np.isfinite(rec.t).all()
