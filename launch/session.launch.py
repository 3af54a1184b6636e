"""Launch one identification session: driver, recorder and identification nodes.

    ros2 launch pmdc_ident session.launch.py motor:=seed000_ebike backend:=sim
    ros2 launch pmdc_ident session.launch.py backend:=serial port:=/dev/ttyACM0 \
        motor:=/path/to/nominal.yaml output_dir:=$HOME/pmdc_sessions
    ros2 launch pmdc_ident session.launch.py export_models:=true   # + MJCF, URDF, gains

The same graph as the ``bringup`` command (which needs no ``ros2 launch``): the
parameters files in ``share/pmdc_ident/config/`` give the defaults (keyed ``/**``,
so they reach the nodes under any namespace), the launch arguments override the
most used ones; their defaults are the nodes', from their parameter tables
(``pmdc_ident/nodes/parameter_tables.py``), except ``exit_when_done``: with
``exit_when_done:=true`` (the launch's default) the launch ends when the session is
over; the driver makes the motor safe and the recorder closes its bag on the way out.
For a larger stack that asks for runs on demand, use ``exit_when_done:=false
autostart:=false`` and call the ``run_session`` service; the result stays latched on
``identified_parameters``.
"""

from __future__ import annotations

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.event_handlers import OnProcessExit
from launch.events import Shutdown
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterValue

from launch import LaunchDescription
from pmdc_ident.nodes.parameter_tables import (
    DRIVER,
    IDENTIFICATION,
    RECORDER,
    ParameterTable,
)


def generate_launch_description() -> LaunchDescription:
    share = get_package_share_directory("pmdc_ident")
    config = os.path.join(share, "config")
    arg = LaunchConfiguration

    def declare(name: str, table: ParameterTable) -> DeclareLaunchArgument:
        p = table[name]
        default = str(p.default).lower() if isinstance(p.default, bool) else str(p.default)
        return DeclareLaunchArgument(name, default_value=default, description=p.description)

    args = [
        declare("backend", DRIVER),
        declare("port", DRIVER),
        declare("motor", DRIVER),  # the driver's motor, and the nominal motor of the plan
        declare("output_dir", RECORDER),  # the bags, and the results beside them
        declare("safe_mode", IDENTIFICATION),
        declare("autostart", IDENTIFICATION),
        declare("export_models", IDENTIFICATION),  # MJCF, URDF, ... beside the bag
        DeclareLaunchArgument(
            "exit_when_done", default_value="true", description="end the launch after one run"
        ),
        DeclareLaunchArgument("namespace", default_value="", description="node namespace"),
    ]
    driver = Node(
        package="pmdc_ident",
        executable="driver_node",
        name=DRIVER.node,
        namespace=arg("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            os.path.join(config, DRIVER.config),
            {"backend": arg("backend"), "port": arg("port"), "motor": arg("motor")},
        ],
    )
    recorder = Node(
        package="pmdc_ident",
        executable="recorder_node",
        name=RECORDER.node,
        namespace=arg("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[os.path.join(config, RECORDER.config), {"output_dir": arg("output_dir")}],
    )
    identification = Node(
        package="pmdc_ident",
        executable="identification_node",
        name=IDENTIFICATION.node,
        namespace=arg("namespace"),
        output="screen",
        emulate_tty=True,
        parameters=[
            os.path.join(config, IDENTIFICATION.config),
            {
                "motor": arg("motor"),
                "output_dir": arg("output_dir"),
                "safe_mode": arg("safe_mode"),
                "autostart": ParameterValue(arg("autostart"), value_type=bool),
                "exit_when_done": ParameterValue(arg("exit_when_done"), value_type=bool),
                "export_models": ParameterValue(arg("export_models"), value_type=bool),
            },
        ],
    )
    # identification ends (session over, or aborted): stop the others, which makes the
    # motor safe (driver) and closes the bag (recorder)
    stop_all = RegisterEventHandler(
        OnProcessExit(target_action=identification, on_exit=[EmitEvent(event=Shutdown())])
    )
    return LaunchDescription([*args, driver, recorder, identification, stop_all])
