"""Bring-up helpers without starting any node: the child environment and the ROS arguments."""

from __future__ import annotations

from pathlib import Path

import yaml
from helpers.paths import REPO

from pmdc_ident.process.bringup import _ros_args, main, node_env, parameter_table


def test_every_child_gets_loopback_dds_and_its_own_domain():
    env = node_env(64, base={"ROS_STATIC_PEERS": "10.0.0.7", "PATH": "/usr/bin"})
    profile = REPO / "config" / "fastdds_localhost.xml"
    assert env["FASTDDS_DEFAULT_PROFILES_FILE"] == str(profile)
    assert env["FASTRTPS_DEFAULT_PROFILES_FILE"] == str(profile)  # Fast DDS 2.14 reads this
    assert env["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    assert env["ROS_DOMAIN_ID"] == "64"
    assert "ROS_STATIC_PEERS" not in env and env["PATH"] == "/usr/bin"


def test_parameters_become_ros_args_that_yaml_reads_back():
    args = _ros_args(
        Path("/x/identification.yaml"),
        {"safe_mode": "open", "fix": ["L=0.0003"], "exit_when_done": True, "tau_m_s": 0.05},
    )
    assert args[:3] == ["--ros-args", "--params-file", "/x/identification.yaml"]
    pairs = dict(a.split(":=", 1) for a in args[3:] if a != "-p")
    assert {k: yaml.safe_load(v) for k, v in pairs.items()} == {
        "safe_mode": "open",
        "fix": ["L=0.0003"],
        "exit_when_done": True,
        "tau_m_s": 0.05,
    }


def test_a_bad_param_option_is_one_line_and_status_2(capsys):
    assert main(["-p", "identification-safe_mode=open"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "bringup: error: bad --param 'identification-safe_mode=open' (NODE:NAME=VALUE)"


def test_parameter_table_marks_what_is_not_identifiable():
    table = parameter_table(
        {
            "parameters": {
                "R": {"value": 1.375, "ci95": [1.37, 1.38], "unit": "ohm", "identifiable": True},
                "L": {"value": 3e-4, "ci95": None, "unit": "H", "identifiable": False},
            }
        }
    )
    lines = table.splitlines()
    assert "[1.37, 1.38]" in lines[1] and "ohm" in lines[1]
    assert "not identifiable" in lines[2]
