"""Launch the pmdc_ident motor driver node with its parameters file.

    ros2 launch pmdc_ident driver.launch.py backend:=sim motor:=seed001_110v rate_hz:=2000.0

The parameters file (``share/pmdc_ident/config/driver.yaml``, or ``params_file:=``)
gives the defaults; the launch arguments override the three most used ones.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("pmdc_ident")
    default_params = os.path.join(share, "config", "driver.yaml")
    args = [
        DeclareLaunchArgument(
            "params_file", default_value=default_params, description="driver parameters file"
        ),
        DeclareLaunchArgument("backend", default_value="sim", description="'sim' or 'serial'"),
        DeclareLaunchArgument(
            "motor", default_value="seed000_ebike", description="built-in motor or YAML path"
        ),
        DeclareLaunchArgument("rate_hz", default_value="1000.0", description="sample rate, Hz"),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace"),
    ]
    driver = Node(
        package="pmdc_ident",
        executable="driver_node",
        name="driver_node",
        namespace=LaunchConfiguration("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            LaunchConfiguration("params_file"),
            {
                "backend": LaunchConfiguration("backend"),
                "motor": LaunchConfiguration("motor"),
                "rate_hz": ParameterValue(LaunchConfiguration("rate_hz"), value_type=float),
            },
        ],
    )
    return LaunchDescription([*args, driver])
