"""Launch one identification session: driver, recorder and identification nodes.

    ros2 launch pmdc_ident session.launch.py motor:=seed000_ebike backend:=sim
    ros2 launch pmdc_ident session.launch.py backend:=serial port:=/dev/ttyACM0 \
        motor:=/path/to/nominal.yaml output_dir:=$HOME/pmdc_sessions
    ros2 launch pmdc_ident session.launch.py params_file:=my_rig.yaml namespace:=left_wheel
    ros2 launch pmdc_ident session.launch.py data_timeout_s:=3.0 rate_hz:=500.0

The same graph as the ``bringup`` command (which needs no ``ros2 launch``). Every
node reads its defaults from ``share/pmdc_ident/config/`` (generated from the node's
parameter table, keyed ``/**`` so they reach the nodes under any namespace), then
``params_file:=`` (one file for the three nodes), then the launch arguments given here
(an argument left at ``''`` changes nothing; ``ros2 launch ... --show-args`` lists them
with the value the file gives). ``exit_when_done`` defaults to ``true`` here: the
session ends when its identification node exits, which stops this session's recorder
(bag closed) and driver (0 V while the identification node still commands it, then
the armature open), and nothing else of an including launch, so several sessions run
side by side (``two_motors.launch.py``). ``ros2 launch`` exits with status 1 when a
session did not complete (refused, aborted, interrupted), after every session is over.
For a larger stack that asks for runs on demand, use ``exit_when_done:=false
autostart:=false`` and call the ``run_session`` service; the result stays latched on
``identified_parameters``. See ``pmdc_ident/process/launching.py`` and
``docs/integration.md``.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction

from launch import LaunchDescription
from pmdc_ident.process.launching import LAUNCH_DEFAULTS, SESSION_ARGUMENTS, session_actions
from pmdc_ident.process.parameter_tables import DRIVER, IDENTIFICATION, RECORDER


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory("pmdc_ident"), "config")
    args = [
        DeclareLaunchArgument(a.name, default_value="", description=a.description)
        for a in SESSION_ARGUMENTS
    ]
    args += [
        DeclareLaunchArgument(
            "exit_when_done",
            default_value=LAUNCH_DEFAULTS["exit_when_done"],
            description="end the session (and its nodes) after one run",
        ),
        DeclareLaunchArgument("namespace", default_value="", description="the nodes' namespace"),
        DeclareLaunchArgument(
            "params_file",
            default_value="",
            description="a parameters file for the session's nodes (keyed /** or by node "
            "name), applied over the package's defaults",
        ),
    ]
    nodes = OpaqueFunction(
        function=session_actions,
        kwargs={
            "tables": (DRIVER, RECORDER, IDENTIFICATION),
            "arguments": SESSION_ARGUMENTS,
            "config_dir": config,
        },
    )
    return LaunchDescription([*args, nodes])
