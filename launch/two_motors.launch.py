"""Two motors of one robot (two wheels) identified side by side in one launch.

    ros2 launch pmdc_ident two_motors.launch.py
    ros2 launch pmdc_ident two_motors.launch.py left_motor:=left.yaml right_motor:=right.yaml

``session.launch.py`` is included once per wheel, each in its own namespace
(``left_wheel``, ``right_wheel``) with its own joint name (``left_wheel_joint``,
``right_wheel_joint``): two drivers, two recorders, two identification nodes, two
bags with their own session ids. Each include sits in a scoped ``GroupAction``, so one
wheel's arguments never leak into the other's. Each session ends on its own; the launch
ends when both are over, with status 1 if either did not complete. The example of
``docs/integration.md``: copy it into your robot's bring-up package and point the
motors at your wheels (``backend:=serial`` and ``port:=`` per wheel).
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, GroupAction, IncludeLaunchDescription
from launch.launch_description_sources import PythonLaunchDescriptionSource
from launch.substitutions import LaunchConfiguration

from launch import LaunchDescription

WHEELS = ("left", "right")


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("pmdc_ident")
    session = os.path.join(share, "launch", "session.launch.py")
    args = [
        DeclareLaunchArgument(
            f"{side}_motor", default_value="", description=f"{side} wheel's motor file"
        )
        for side in WHEELS
    ]
    shared = ("output_dir", "data_timeout_s", "rate_hz", "params_file", "backend")
    args += [
        DeclareLaunchArgument(name, default_value="", description=f"{name} of both sessions")
        for name in shared
    ]
    wheels = [
        GroupAction(
            [
                IncludeLaunchDescription(
                    PythonLaunchDescriptionSource(session),
                    launch_arguments={
                        "namespace": f"{side}_wheel",
                        "joint_name": f"{side}_wheel_joint",
                        "motor": LaunchConfiguration(f"{side}_motor"),
                        **{name: LaunchConfiguration(name) for name in shared},
                    }.items(),
                )
            ],
            scoped=True,
        )
        for side in WHEELS
    ]
    return LaunchDescription([*args, *wheels])
