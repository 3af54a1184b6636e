"""Launch the pmdc_ident motor driver node with its parameters file.

    ros2 launch pmdc_ident driver.launch.py backend:=sim motor:=seed001_110v rate_hz:=2000.0
    ros2 launch pmdc_ident driver.launch.py namespace:=m1

The parameters file (``share/pmdc_ident/config/driver.yaml``, or ``params_file:=``)
gives the defaults; it is keyed ``/**``, so it reaches the node under any namespace.
The launch arguments override the three most used ones; their defaults are the
node's, from its one parameter table (``pmdc_ident/nodes/parameter_tables.py``).
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription
from pmdc_ident.nodes.parameter_tables import DRIVER


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("pmdc_ident")
    default_params = os.path.join(share, "config", DRIVER.config)
    args = [
        DeclareLaunchArgument(
            "params_file", default_value=default_params, description="driver parameters file"
        ),
        *(
            DeclareLaunchArgument(
                name, default_value=str(DRIVER[name].default), description=DRIVER[name].description
            )
            for name in ("backend", "motor", "rate_hz")
        ),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace"),
    ]
    driver = Node(
        package="pmdc_ident",
        executable="driver_node",
        name=DRIVER.node,
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
