"""Launch the pmdc_ident motor driver node with its parameters file.

    ros2 launch pmdc_ident driver.launch.py backend:=sim motor:=seed001_110v rate_hz:=2000.0
    ros2 launch pmdc_ident driver.launch.py namespace:=m1 params_file:=my_driver.yaml

The node reads ``share/pmdc_ident/config/driver.yaml`` (every default, keyed ``/**``
so it reaches the node under any namespace), then ``params_file:=``, then the launch
arguments given (``''`` changes nothing). ``ros2 launch`` exits with status 1 when the
driver ends with a non-zero status. See ``pmdc_ident/process/launching.py``.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction

from launch import LaunchDescription
from pmdc_ident.process.launching import DRIVER_ARGUMENTS, session_actions
from pmdc_ident.process.parameter_tables import DRIVER


def generate_launch_description() -> LaunchDescription:
    config = os.path.join(get_package_share_directory("pmdc_ident"), "config")
    args = [
        DeclareLaunchArgument(a.name, default_value="", description=a.description)
        for a in DRIVER_ARGUMENTS
    ]
    args += [
        DeclareLaunchArgument("namespace", default_value="", description="the node's namespace"),
        DeclareLaunchArgument(
            "params_file",
            default_value="",
            description="a parameters file for the driver, applied over the package's defaults",
        ),
    ]
    driver = OpaqueFunction(
        function=session_actions,
        kwargs={"tables": (DRIVER,), "arguments": DRIVER_ARGUMENTS, "config_dir": config},
    )
    return LaunchDescription([*args, driver])
